#!/usr/bin/env python3
"""Benchmark: the OLNG strategy's per-frame parts on a knowledge base of Tautges et al.'s
size, printed as one JSON line.

    tools/bench_olng.py [DATA] [--k 4096] [--m 32] [--i 256] [--samples 300] [--layout wrists-ankles]

DATA: the Bandai-Namco folder (default ../shared/data/bandai). Every BVH clip under it,
with mirror and reverse augmentation (about 306,000 frames at 30 Hz, one skeleton),
becomes a graph without transitions' extras (`build_graph` with interpolation, speed
variation and bridges off: OLNG reads only the original frames and their readings);
its OLNG index is built (`index_build_s`: the kd-tree), and a noisy walk through one
clip's own readings (σ 0.05 g an axis) is pushed sample by sample: per frame the
neighbour query (`nn_ms`, K neighbours) and the lattice update (`olng_ms`), medians,
and their sum's median and 99th percentile. The pose optimisation is not built yet:
`optimise_ms` is null and `total_ms` covers the parts that exist.
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    from graphsvc.graph.build import BuildOptions, build_graph, load_knowledge_base
    from graphsvc.motion.library import find_motion_files
    from graphsvc.sensors.layout import load_layout
    from graphsvc.strategies.olng.index import OlngIndex, build_arrays
    from graphsvc.strategies.olng.lattice import Lattice, LatticeOptions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared/data/bandai"))
    parser.add_argument("--k", type=int, default=4096)
    parser.add_argument("--m", type=int, default=32)
    parser.add_argument("--i", type=int, default=256)
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--layout", default="wrists-ankles")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    files = [f for f in find_motion_files([args.data]) if f.suffix.lower() == ".bvh"]
    if not files:
        raise SystemExit(f"no BVH clips under {args.data}")
    t0 = time.perf_counter()
    augment = ("mirror", "reverse")
    kb = load_knowledge_base([str(f) for f in files], augment=augment, jobs=args.jobs, progress=False)
    graph, _ = build_graph(kb, BuildOptions(layout=load_layout(args.layout), msv=False, interp=False, bridges=False,
                                            augment=augment, jobs=args.jobs, progress=False))  # fmt: skip
    build_s = time.perf_counter() - t0
    arrays = build_arrays(graph)
    t0 = time.perf_counter()
    index = OlngIndex(graph, arrays)
    index_build_s = time.perf_counter() - t0
    options = LatticeOptions(k=args.k, m=args.m, i=args.i)
    options.check(index.frames)
    lattice = Lattice(index.run_of, options)
    rng = np.random.default_rng(0)
    run = np.flatnonzero(index.run_of == index.run_of[index.frames // 2])  # one clip's frames
    frames = run[np.arange(args.samples) % run.size]
    readings = index.readings[frames].astype(np.float64) + rng.normal(0.0, 0.05, (args.samples, index.readings.shape[1]))
    lattice.push(*_query(index, readings[0], args.k))  # (numba's compilation, outside the timings)
    lattice = Lattice(index.run_of, options)
    nn, olng = [], []
    for t in range(args.samples):
        t1 = time.perf_counter()
        frames_t, dist_t = _query(index, readings[t], args.k)
        t2 = time.perf_counter()
        lattice.push(frames_t, dist_t)
        lattice.best()
        t3 = time.perf_counter()
        nn.append(t2 - t1)
        olng.append(t3 - t2)
    nn_ms, olng_ms = 1000 * np.array(nn), 1000 * np.array(olng)
    total = nn_ms + olng_ms
    print(json.dumps({
        "kb_frames": index.frames, "graph_build_s": round(build_s, 2), "index_build_s": round(index_build_s, 3),
        "k": args.k, "m": args.m, "i": args.i, "samples": args.samples, "layout": args.layout,
        "nn_ms": round(float(np.median(nn_ms)), 3), "olng_ms": round(float(np.median(olng_ms)), 3),
        "optimise_ms": None, "total_ms": round(float(np.median(total)), 3),
        "total_p99_ms": round(float(np.percentile(total, 99)), 3),
        "mean_path_length": round(float(lattice.column()["length"][lattice.best()[0]].mean()), 2),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "machine": f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}",
    }), flush=True)  # fmt: skip


def _query(index, reading, k):
    n = index.query(reading, k)
    return n.frames, n.distances


if __name__ == "__main__":
    main()
