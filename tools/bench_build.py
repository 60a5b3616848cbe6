#!/usr/bin/env python3
"""Benchmark: motion-graph build (load + build + write) from a motion folder.

Prints one JSON object per run: the variants on the whole folder — plain (contact-change
transitions only), msv, interp, bridges (each alone on top of plain), both (msv and
interp, no bridges) and all (the default build: msv, interp and bridges) — then `all`
on deterministic random subsets of about 10k, 20k and 40k frames. Each run is a
separate process, so peak RSS is that run's own.

Usage: tools/bench_build.py [DATA_DIR] [--jobs 2] [--only VARIANT] [--subsets 10000,20000,40000]

The knowledge base is every clip of DATA_DIR (default ../shared/data/bandai, both
datasets); `bridges` in stages_s is the bridge stage's own time, and the connectivity
report is not part of a build.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

VARIANTS = {
    "plain": (False, False, False),
    "msv": (True, False, False),
    "interp": (False, True, False),
    "bridges": (False, False, True),
    "both": (True, True, False),
    "all": (True, True, True),
}


def run_one(data: str, variant: str, max_frames: int | None, jobs: int) -> dict:
    import numpy as np

    from graphsvc.graph.build import BuildOptions, build_graph, load_knowledge_base
    from graphsvc.graph.file import save_graph
    from graphsvc.motion.library import find_motion_files

    files = find_motion_files([data])
    if max_frames:
        # A fixed shuffle, so subsets mix all contents rather than the first labels.
        order = np.random.default_rng(0).permutation(len(files))
        files = [files[i] for i in order]
    msv, interp, bridges = VARIANTS[variant]
    start = time.perf_counter()
    motions = load_knowledge_base([str(f) for f in files], jobs=jobs, progress=False)
    if max_frames:
        total, keep = 0, []
        for m in motions:
            if total >= max_frames:
                break
            keep.append(m)
            total += m.num_frames
        motions = keep
    graph, report = build_graph(
        motions, BuildOptions(msv=msv, interp=interp, bridges=bridges, jobs=jobs, progress=False)
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.graph"
        save_graph(graph, path)
        size = path.stat().st_size
    seconds = time.perf_counter() - start
    kb_frames = sum(c["frames"] for c in graph.clips)
    return {
        "variant": variant,
        "kb_frames": kb_frames,
        "clips": len(graph.clips),
        "nodes": graph.num_nodes,
        "edges": graph.num_edges,
        "seconds": round(seconds, 2),
        "frames_per_s": round(kb_frames / seconds),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "file_mb": round(size / 2**20, 1),
        "stages_s": {k: round(v, 2) for k, v in report.timings.items()},
        "jobs": jobs,
        "machine": f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}",
    }


def main() -> None:
    default = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai"
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", default=str(default))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--only", choices=sorted(VARIANTS), help="run just this variant on the whole folder")
    parser.add_argument("--subsets", default="10000,20000,40000", help="frame counts for `all` ('' for none)")
    parser.add_argument("--child", nargs=2, metavar=("VARIANT", "FRAMES"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        variant, frames = args.child
        print(json.dumps(run_one(args.data, variant, int(frames) or None, args.jobs)), flush=True)
        return
    if not Path(args.data).exists():
        sys.exit(f"bench_build: data folder {args.data} not found")
    runs = [(args.only, 0)] if args.only else [(v, 0) for v in VARIANTS]
    if not args.only and args.subsets:
        runs += [("all", int(n)) for n in args.subsets.split(",")]
    for variant, frames in runs:
        cmd = [sys.executable, __file__, args.data, "--jobs", str(args.jobs), "--child", variant, str(frames)]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            print(json.dumps({"variant": variant, "kb_frames_limit": frames, "error": out.stderr.strip()[-500:]}))
        else:
            print(out.stdout.strip(), flush=True)


if __name__ == "__main__":
    main()
