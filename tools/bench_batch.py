#!/usr/bin/env python3
"""Batch throughput: the same items as a plain in-process loop, then through
`graphsvc batch` on a LocalCluster of 1 and of 2 workers. Prints JSON.

    tools/bench_batch.py ../shared/data [--items 48] [--minutes 1] [--workers 1,2] [--beam 10]

The graph: Bandai-Namco dataset 2 without its takes 004 (kelly6, built once into
--cache). The items: `--items` recordings of `--minutes` each, the takes 004 joined end
to end in a shuffled order (a seed an item), simulated with the default noise (ground
position and heading too). Every search runs on serial kernels: one thread a worker,
and the plain loop calls the very function a worker runs (`batch.work.run_item`).
Kernels and the graph are warmed before any clock starts, in the loop's process and
in every worker. Figures: items/s and input hours/s of each run; the scheduling
overhead per item (a run's wall time × workers, less the seconds its items took on
the workers, over the items); each worker's peak RSS.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # the loop's process: serial, as a worker


def build_inputs(data: Path, cache: Path, items: int, minutes: float) -> tuple[Path, list[Path]]:
    import numpy as np

    from graphsvc.evaluate.mixed import join_clips
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.graph.file import save_graph
    from graphsvc.motion.library import find_motion_files, load_motion
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.recording import save_recording
    from graphsvc.sensors.simulate import simulate_recording

    cache.mkdir(parents=True, exist_ok=True)
    layout = load_layout("kelly6")
    files = find_motion_files([str(data / "bandai" / "dataset-2" / "data")])
    graph_path = cache / "d2-kelly6.graph"
    if not graph_path.is_file():
        kb = [load_motion(f) for f in files if not f.stem.endswith("_004")]
        graph, _ = build_graph(kb, BuildOptions(layout=layout, jobs=2, progress=False))
        save_graph(graph, graph_path)
    tests = [load_motion(f) for f in files if f.stem.endswith("_004")]
    recs = []
    for k in range(items):
        path = cache / f"item{k:03d}-{minutes:g}min.rec"
        recs.append(path)
        if path.is_file():
            continue
        rng = np.random.default_rng(k)
        picked, frames = [], 0
        for i in rng.permutation(len(tests)):
            picked.append(tests[i])
            frames += tests[i].num_frames * 30.0 / tests[i].rate_hz
            if frames >= minutes * 60 * 30 + 30:
                break
        motion, _ = join_clips(picked, 30.0)
        rec = simulate_recording(
            motion.slice(0, int(round(minutes * 60 * 30))), layout, parse_noise("default"), seed=k, rate_hz=30.0
        )
        save_recording(rec, path)
    return graph_path, recs


def write_manifest(folder: Path, graph: Path, recs: list[Path], beam: float | None) -> Path:
    import csv

    path = folder / "manifest.csv"
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["recording", "graph", "strategy", "output", "weights", "options"])
        for k, r in enumerate(recs):
            w.writerow(
                [str(r), str(graph), "viterbi", f"item{k:03d}", "0.5,1,1", json.dumps({"beam": beam} if beam else {})]
            )
    return path


def warm_worker(graph: str, checksum: str, strategy: str) -> float:
    from graphsvc.batch.work import warm, worker_graph

    return warm(worker_graph(graph, checksum), (graph, checksum), strategy)


def peak_rss_mb() -> float:
    """This process's peak resident memory (VmHWM: unlike ru_maxrss, not inherited
    from the process that started it)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def plain_loop(manifest: Path, out: Path) -> dict:
    from graphsvc.batch.manifest import plan_item, read_manifest
    from graphsvc.batch.run import version
    from graphsvc.batch.work import run_item

    out.mkdir(exist_ok=True)
    plans = [plan_item(i, manifest.parent, {}, out, version()) for i in read_manifest(manifest)]
    warm_s = warm_worker(plans[0].task["graph"], plans[0].task["graph_checksum"], "viterbi")
    t0 = time.perf_counter()
    results = [run_item(p.task) for p in plans]
    wall = time.perf_counter() - t0
    assert all("error" not in r for r in results), [r for r in results if "error" in r][:1]
    input_s = sum(r["input_s"] for r in results)
    return {
        "workers": 0,
        "items": len(results),
        "wall_s": round(wall, 3),
        "warm_up_s": round(warm_s, 2),
        "items_per_s": round(len(results) / wall, 4),
        "input_hours_per_s": round(input_s / 3600 / wall, 5),
        "item_s_mean": round(sum(r["seconds"] for r in results) / len(results), 4),
        "peak_rss_mb": round(peak_rss_mb(), 1),
    }


def dask_run(manifest: Path, out: Path, workers: int) -> dict:
    from distributed import Client

    from graphsvc.batch.manifest import plan_item, read_manifest
    from graphsvc.batch.run import local_cluster, run_batch, version

    plan = plan_item(read_manifest(manifest)[0], manifest.parent, {}, out, version())
    t0 = time.perf_counter()
    cluster = local_cluster(workers)
    client = Client(cluster, set_as_default=False)
    start_s = time.perf_counter() - t0
    try:
        warm = client.run(warm_worker, plan.task["graph"], plan.task["graph_checksum"], "viterbi")
        t0 = time.perf_counter()
        summary = run_batch(manifest, out, client=client, progress=False)
        wall = time.perf_counter() - t0
        rss = client.run(peak_rss_mb)
    finally:
        client.close()
        cluster.close()
    t = summary["totals"]
    assert t["done"] == t["items"], summary["failures"][:1]
    return {
        "workers": workers,
        "items": t["items"],
        "wall_s": round(wall, 3),
        "cluster_start_s": round(start_s, 2),
        "warm_up_s": round(max(warm.values()), 2),
        "items_per_s": round(t["items"] / wall, 4),
        "input_hours_per_s": round(t["input_hours"] / wall, 5),
        "item_s_mean": round(t["item_seconds"] / t["items"], 4),
        "overhead_per_item_s": round((wall * workers - t["item_seconds"]) / t["items"], 4),
        "peak_rss_mb_per_worker": sorted(round(v, 1) for v in rss.values()),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    p.add_argument("--items", type=int, default=48)
    p.add_argument("--minutes", type=float, default=1.0)
    p.add_argument("--workers", default="1,2")
    p.add_argument("--beam", type=float, default=10.0, help="the search's beam (0: exact)")
    p.add_argument("--cache", default="/tmp/graphsvc-bench-batch", help="graph and recordings, made once")
    args = p.parse_args()
    cache = Path(args.cache)
    t0 = time.perf_counter()
    graph, recs = build_inputs(Path(args.data), cache, args.items, args.minutes)
    prep_s = time.perf_counter() - t0
    run_dir = cache / f"run-{os.getpid()}"
    run_dir.mkdir()
    manifest = write_manifest(run_dir, graph, recs, args.beam or None)
    from graphsvc.graph.file import graph_file_meta

    counts = graph_file_meta(graph)["meta"]["counts"]
    loop = plain_loop(manifest, run_dir / "loop")
    runs = [dask_run(manifest, run_dir / f"dask{w}", int(w)) for w in args.workers.split(",")]
    by_w = {r["workers"]: r for r in runs}
    result = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "processor": platform.processor()},
        "graph": {"path": str(graph), **counts},
        "items": args.items,
        "minutes_each": args.minutes,
        "search": {"strategy": "viterbi", "weights": "0.5,1,1", "beam": args.beam or None},
        "prepare_s": round(prep_s, 1),
        "plain_loop": loop,
        "dask": runs,
    }
    if 1 in by_w:
        result["dask1_vs_loop"] = round(by_w[1]["items_per_s"] / loop["items_per_s"], 4)
    if 1 in by_w and 2 in by_w:
        result["speedup_2_vs_1"] = round(by_w[2]["items_per_s"] / by_w[1]["items_per_s"], 3)
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
