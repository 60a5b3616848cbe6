#!/usr/bin/env python3
"""Benchmark: the OLNG strategy's per-frame parts on a knowledge base of Tautges et al.'s
size, printed as one JSON line.

    tools/bench_olng.py [DATA] [--k 4096] [--m 32] [--i 256] [--samples 300] [--layout wrists-ankles]

DATA: the Bandai-Namco folder (default ../shared/data/bandai). Every BVH clip under it,
with mirror and reverse augmentation (about 306,000 frames at 30 Hz, one skeleton),
becomes a graph without transitions' extras (`build_graph` with interpolation, speed
variation and bridges off: OLNG reads only the original frames and their readings);
its OLNG index is built (`index_build_s`: the kd-tree), and a noisy walk through one
clip's own readings (σ 0.05 g an axis) is pushed sample by sample through the
strategy's decoder (`strategies.olng.decoder`): per frame the neighbour query
(`nn_ms`, K neighbours), the lattice update (`olng_ms`) and the pose (`optimise_ms`:
PCA, the energy's minimisation, the root and the placement), medians, and their sum's
median and 99th percentile. The first samples, where numba loads its kernels, are
outside the timings.
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
    from graphsvc.sensors.accelerometer import GRAVITY
    from graphsvc.sensors.layout import load_layout
    from graphsvc.strategies.olng.decoder import OlngDecoder
    from graphsvc.strategies.olng.index import OlngIndex, build_arrays
    from graphsvc.strategies.olng.lattice import LatticeOptions
    from graphsvc.strategies.olng.options import OlngOptions
    from graphsvc.strategies.olng.pose import pose_model

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
    graph, _ = build_graph(
        kb,
        BuildOptions(
            layout=load_layout(args.layout),
            msv=False,
            interp=False,
            bridges=False,
            augment=augment,
            jobs=args.jobs,
            progress=False,
        ),
    )
    build_s = time.perf_counter() - t0
    arrays = build_arrays(graph)
    t0 = time.perf_counter()
    index = OlngIndex(graph, arrays)
    index_build_s = time.perf_counter() - t0
    options = OlngOptions(k=args.k, m=args.m, i=args.i)
    LatticeOptions(k=args.k, m=args.m, i=args.i).check(index.frames)
    model = pose_model(graph)
    rng = np.random.default_rng(0)
    run = np.flatnonzero(index.run_of == index.run_of[index.frames // 2])  # one clip's frames
    frames = run[np.arange(args.samples) % run.size]
    readings = index.readings[frames].astype(np.float64) + rng.normal(
        0.0, 0.05, (args.samples, index.readings.shape[1])
    )
    acc = readings.reshape(args.samples, -1, 3) * GRAVITY
    warm = OlngDecoder(graph, index, model, options, 0.0)
    for t in range(3):  # (numba's loading, outside the timings)
        warm.step(acc[t])
    decoder = OlngDecoder(graph, index, model, options, 0.0)
    rows = [decoder.step(acc[t])[4] for t in range(args.samples)]
    nn_ms = np.array([r["nn_ms"] for r in rows])
    olng_ms = np.array([r["olng_ms"] for r in rows])
    optimise_ms = np.array([r["optimise_ms"] for r in rows])
    total = nn_ms + olng_ms + optimise_ms
    print(
        json.dumps(
            {
                "kb_frames": index.frames,
                "graph_build_s": round(build_s, 2),
                "index_build_s": round(index_build_s, 3),
                "k": args.k,
                "m": args.m,
                "i": args.i,
                "samples": args.samples,
                "layout": args.layout,
                "nn_ms": round(float(np.median(nn_ms)), 3),
                "olng_ms": round(float(np.median(olng_ms)), 3),
                "optimise_ms": round(float(np.median(optimise_ms)), 3),
                "total_ms": round(float(np.median(total)), 3),
                "total_p99_ms": round(float(np.percentile(total, 99)), 3),
                "mean_path_length": round(float(np.mean([r["path_length"] for r in rows])), 2),
                "subspace_dims": round(float(np.mean([r["subspace"] for r in rows])), 1),
                "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
                "machine": f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}",
            }
        ),
        flush=True,
    )


if __name__ == "__main__":
    main()
