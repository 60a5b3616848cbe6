#!/usr/bin/env python3
"""What the refinement costs (`graphsvc.strategies.refine`): the index, its in-memory form,
and the correction of a path's motion in batch and live, on a built graph.

The path is the longest stretch of consecutive knowledge-base frames (original edges)
from a clip's start, at most `--frames`, its readings the graph's own with 0.3 m/s² of white noise (seed 1).
Prints one JSON object: the index's build (when not cached beside the graph) and load,
the in-memory index's making (the windows as float32 columns), the regression per frame, `refine_motion` over the path and a live
`Refiner` correcting 3 frames at a time (as a live session's synthesizer asks), per
frame. `--orientations`: the path's sensors' orientation cue too (the graph's own,
`graph.edge_up`, with 2° of noise), weighed 1 as the search's default, so the query
carries it and, with a root sensor, the measured segments' orientations are imposed.

Usage: tools/bench_refine.py GRAPH [--frames 3000] [--orientations]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    import numpy as np

    from graphsvc.graph.file import load_graph
    from graphsvc.graph.model import EDGE_ORIGINAL
    from graphsvc.strategies import refine
    from graphsvc.strategies.index import index_path
    from graphsvc.synthesis.path import synthesize_motion, warm_up_synthesis

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph")
    parser.add_argument("--frames", type=int, default=3000)
    parser.add_argument("--orientations", action="store_true")
    args = parser.parse_args()
    graph = load_graph(args.graph, mmap=True)
    cached = index_path(args.graph, "refine").is_file()
    t0 = time.perf_counter()
    arrays = refine.refine_arrays(graph)
    arrays_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    index = refine.refine_index(graph)
    index_s = time.perf_counter() - t0
    refine.warm_up_refine(graph)
    warm_up_synthesis(graph)

    # The longest run of original edges from a clip's first frame, cut to --frames.
    e = np.flatnonzero(np.asarray(graph.edge_kind) == EDGE_ORIGINAL)
    nxt = np.full(graph.num_nodes, -1, dtype=np.int64)
    nxt[np.asarray(graph.edge_src)[e]] = np.asarray(graph.edge_dst)[e]
    into = np.full(graph.num_nodes, -1, dtype=np.int64)
    into[np.asarray(graph.edge_dst)[e]] = e
    nodes = []
    for clip in graph.clips:
        run = [int(clip["first_node"])]
        while len(run) < args.frames and nxt[run[-1]] >= 0:
            run.append(int(nxt[run[-1]]))
        if len(run) > len(nodes):
            nodes = run
    nodes = np.asarray(nodes, dtype=np.int64)
    edges = into[nodes[1:]]
    T = nodes.size
    rng = np.random.default_rng(1)
    acc = np.asarray(graph.edge_acc, dtype=np.float64)[np.concatenate([edges[:1], edges])] + rng.normal(
        0, 0.3, (T, *graph.edge_acc.shape[1:])
    )
    motion = synthesize_motion(graph, nodes, edges, np.zeros(2), 0.0)
    up, weight = None, 0.0
    if args.orientations:
        if graph.edge_up is None:
            raise SystemExit("the graph has no orientation metadata")
        up = np.asarray(graph.edge_up, dtype=np.float64)[np.concatenate([edges[:1], edges])]
        up = up + rng.normal(0, np.radians(2.0) / np.sqrt(2.0), up.shape)
        weight = 1.0
        index.features(weight * refine.ORIENTATION_GAIN)

    r = refine.Refiner(graph, index, weight)
    for t, a in enumerate(acc):
        r.push(a, None if up is None else up[t])
    r.finish()
    t0 = time.perf_counter()
    r.regressed(0, T)
    regress_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    refine.refine_motion(graph, motion, nodes, index, acc, 1.0, up, weight)
    batch_s = time.perf_counter() - t0

    live = refine.Refiner(graph, index, weight)
    for t, a in enumerate(acc):  # (pushing a sample only appends it: the cost is the corrections')
        live.push(a, None if up is None else up[t])
    live.finish()
    t_live = 0.0
    for lo in range(0, T, 3):
        hi = min(lo + 3, T)
        t0 = time.perf_counter()
        live.correct(
            lo,
            motion.rotations[lo:hi],
            motion.translations[lo:hi],
            lambda a, b: nodes[a:b],
            T - 1 if hi - 1 + live.h >= T - 1 else None,
        )
        t_live += time.perf_counter() - t0
    print(
        json.dumps(
            {
                "graph": args.graph,
                "nodes": graph.num_nodes,
                "index_frames": int(arrays["nodes"].size),
                "window_dims": int(arrays["windows"].shape[1]),
                "pose_dims": int(arrays["poses"].shape[1]),
                "orientations": bool(args.orientations),
                "imposed": bool(r.impose),
                "index_cached": cached,
                "index_s": round(arrays_s, 3),
                "in_memory_s": round(index_s, 3),
                "frames": T,
                "regress_ms_per_frame": round(1e3 * regress_s / T, 3),
                "batch_ms_per_frame": round(1e3 * batch_s / T, 3),
                "live_ms_per_frame": round(1e3 * t_live / T, 3),
                "batch_frames_per_s": round(T / batch_s, 1),
            }
        )
    )


if __name__ == "__main__":
    main()
