#!/usr/bin/env python3
"""Benchmark: every strategy's live figures on one (large) graph file, as a server runs
them, printed as one JSON object.

    .venv/bin/python tools/bench_live_scale.py GRAPH --recordings DIR [--markers DIR]
        [--strategies viterbi,olng,ssg] [--seconds 60] [--beam 10] [--no-refine] [--live-paths N] [--skip-load]

GRAPH: a built graph whose knowledge base leaves out the recordings' clips (e.g. every
shared clip but dataset 2's takes 004, `--exclude '*_004.bvh'`); DIR: `.rec`
accelerometer recordings in the graph's layout with ground positions and headings
(`graphsvc simulate CLIP --layout L --noise default`), played joined end to end
(`tools/bench_service.py`'s `joined_recordings`); --markers DIR: marker recordings
(`graphsvc simulate CLIP --markers hands-feet`) for the SSG.

Each part runs in its own process, so its memory is its own:
  load       the server's load (`service.graphs.load_graphs`: the file memory-mapped
             and its checksum verified, every strategy's index made or mapped from its
             cache beside the graph, the kernels warmed up): seconds (`load_s`, and
             the part `verify_s` of checking the file's SHA-256), the process's peak
             RSS and its RSS and PSS after (the mapped graph's and index files' pages
             are shared with every other process that maps them; PSS splits them),
             run twice: `first` (index caches as found) and `again` (caches present:
             what a live worker or a restarted server pays);
  viterbi,   a live session (`pipeline.open_session`, serial kernels, as a live
  olng       worker runs one) fed --seconds of the joined recordings sample by
             sample: each push's wall and CPU time; p50 / p99 / max after the stream's
             first 2 s (`steady_*`), the longest push in them (`start_max_ms`), and
             samples per second of CPU (--no-refine: the Viterbi session without
             the pose refinement, whose brute-force neighbour search grows with the
             knowledge base);
  ssg        the batch reconstruction of each marker recording (`pipeline.reconstruct`)
             after one throwaway run: input seconds per wall second.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))


def _memory_mb() -> dict:
    """This process's peak RSS (`bench_ssg.peak_rss_mb`: its own, not the parent's) and
    its RSS and PSS now (MB, /proc/self/smaps_rollup)."""
    from bench_ssg import peak_rss_mb

    out = {"peak_rss_mb": round(peak_rss_mb())}
    try:
        for line in Path("/proc/self/smaps_rollup").read_text().splitlines():
            key, _, value = line.partition(":")
            if key in ("Rss", "Pss", "Private_Clean", "Private_Dirty"):
                out[key.lower() + "_mb"] = round(int(value.split()[0]) / 1024)
    except OSError:
        pass
    return out


def load_part(graph_path: str) -> dict:
    from graphsvc.graph.file import load_graph
    from graphsvc.pipeline import warm_up
    from graphsvc.store import read_header
    from graphsvc.strategies import available

    t0 = time.perf_counter()
    read_header(graph_path, verify=True)
    verify_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    graph = load_graph(graph_path)
    loaded_s = time.perf_counter() - t0
    per_strategy = {}
    for name in available():
        t = time.perf_counter()
        warm_up(graph, threads=False, strategies=[name])
        warm_up(graph, threads=True, strategies=[name])
        per_strategy[name] = round(time.perf_counter() - t, 2)
    return {
        "nodes": graph.num_nodes,
        "edges": graph.num_edges,
        "load_s": round(loaded_s + sum(per_strategy.values()), 2),
        "graph_file_s": round(loaded_s, 2),
        "verify_s": round(verify_s, 2),
        "warm_up_s": per_strategy,
        **_memory_mb(),
    }


def live_part(
    graph_path: str,
    recordings: list[str],
    strategy: str,
    seconds: float,
    beam: float,
    refine: bool = True,
    live_paths: int | None = None,
) -> dict:
    from bench_service import joined_recordings

    from graphsvc.graph.file import load_graph
    from graphsvc.pipeline import open_session, warm_up
    from graphsvc.strategies.options import Options, SharedOptions

    graph = load_graph(graph_path, verify=False)
    warm_up(graph, threads=False, strategies=[strategy])
    rate = float(graph.rate_hz)
    samples = int(round(seconds * rate))
    shared = SharedOptions(refine=refine)
    if strategy == "viterbi":
        from graphsvc.strategies.viterbi.options import ViterbiOptions

        own = ViterbiOptions(beam=beam) if live_paths is None else ViterbiOptions(beam=beam, live_paths=live_paths)
        options = Options(strategy="viterbi", own=own, shared=shared)
    else:
        options = Options(strategy=strategy, shared=shared)
    acc, pos, head = joined_recordings(recordings, samples + int(3 * rate), seed=0)
    # a throwaway stream through its start: kernels' first calls are no stream's start
    spare = open_session(graph, options, keep_motion=False)
    for k in range(int(3 * rate)):
        spare.push(k / rate, acc[k], None if pos is None else pos[k], None if head is None else head[k])
    del spare
    acc, pos, head = acc[-samples:], None if pos is None else pos[-samples:], None if head is None else head[-samples:]
    session = open_session(graph, options, keep_motion=False)
    wall = np.zeros(samples)
    cpu = np.zeros(samples)
    for k in range(samples):
        t0, c0 = time.perf_counter(), time.process_time()
        session.push(k / rate, acc[k], None if pos is None else pos[k], None if head is None else head[k])
        wall[k], cpu[k] = time.perf_counter() - t0, time.process_time() - c0
    start = int(2 * rate)
    steady = 1e3 * wall[start:]
    return {
        "samples": samples,
        "refine": refine,
        "live_paths": getattr(options.own, "live_paths", None),
        "steady_p50_ms": round(float(np.percentile(steady, 50)), 3),
        "steady_p99_ms": round(float(np.percentile(steady, 99)), 3),
        "steady_max_ms": round(float(steady.max()), 3),
        "steady_mean_ms": round(float(steady.mean()), 3),
        "start_max_ms": round(float(1e3 * wall[:start].max()), 2),
        "samples_per_cpu_s": round(float(samples / max(cpu.sum(), 1e-9)), 1),
        **_memory_mb(),
    }


def ssg_part(graph_path: str, markers: list[str]) -> dict:
    from graphsvc.graph.file import load_graph
    from graphsvc.pipeline import reconstruct
    from graphsvc.sensors.recording import load_recording
    from graphsvc.strategies.options import Options

    graph = load_graph(graph_path, verify=False)
    options = Options(strategy="ssg")
    recs = [load_recording(p) for p in markers]
    reconstruct(graph, recs[0], options)  # index, clouds and kernels: outside the timings
    input_s, wall_s = 0.0, 0.0
    for rec in recs:
        t0 = time.perf_counter()
        r = reconstruct(graph, rec, options)
        wall_s += time.perf_counter() - t0
        input_s += r.report["samples"] / float(graph.rate_hz)
    return {
        "recordings": len(recs),
        "input_s": round(input_s, 1),
        "wall_s": round(wall_s, 2),
        "input_seconds_per_second": round(input_s / wall_s, 2),
        **_memory_mb(),
    }


def _in_process(fn, *args) -> dict:
    with mp.get_context("spawn").Pool(1) as pool:
        return pool.apply(fn, args)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph")
    parser.add_argument("--recordings", required=True, metavar="DIR")
    parser.add_argument("--markers", metavar="DIR")
    parser.add_argument("--strategies", default="viterbi,olng,ssg")
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--beam", type=float, default=10.0)
    parser.add_argument("--skip-load", action="store_true", help="leave out the load part")
    parser.add_argument("--no-refine", action="store_true", help="live sessions without the pose refinement")
    parser.add_argument("--live-paths", type=int, help="the Viterbi session's live paths (default: its own, 4096)")
    args = parser.parse_args()
    recordings = sorted(str(p) for p in Path(args.recordings).glob("*.rec"))
    if not recordings:
        sys.exit(f"bench_live_scale: no .rec recordings in {args.recordings}")
    out: dict = {"graph": args.graph, "file_bytes": Path(args.graph).stat().st_size}
    if not args.skip_load:
        out["load"] = {"first": _in_process(load_part, args.graph), "again": _in_process(load_part, args.graph)}
    for name in args.strategies.split(","):
        if name == "ssg":
            if args.markers:
                marks = sorted(str(p) for p in Path(args.markers).glob("*.rec"))
                out["ssg"] = _in_process(ssg_part, args.graph, marks)
        else:
            out[name] = _in_process(
                live_part, args.graph, recordings, name, args.seconds, args.beam, not args.no_refine, args.live_paths
            )
        print(json.dumps({name: out.get(name)}), file=sys.stderr, flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
