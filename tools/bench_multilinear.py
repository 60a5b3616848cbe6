#!/usr/bin/env python3
"""Benchmark: the multilinear strategy's learning, its model's size and a recording's
reconstruction (the search's part and the units' fit), printed as one JSON line.

    tools/bench_multilinear.py GRAPH CLIP [--variance 0.99] [--max-reps 8] [--align linear]

GRAPH: a graph file (e.g. `graphsvc build` of Bandai dataset 2 without takes 004,
wrists-ankles); CLIP: a held-out motion file, simulated with the default noise (seed 7)
and reconstructed once. The frames' index is read from its cache beside GRAPH (made
there if missing: `index_s`); the model is learned in memory every run (`learn_s`,
not cached), its arrays' bytes and its tensors (class, foot, frames, styles ×
repetitions, kept) reported; then the reconstruction's `search_s` (the Viterbi
search's), `fit_s` (the units' fit, blending and root), the units and their mean
evaluations; and the process's peak memory.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.library import load_motion
    from graphsvc.motion.resample import resample
    from graphsvc.pipeline import Options, reconstruct
    from graphsvc.sensors.layout import layout_from_dict
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.simulate import simulate_recording
    from graphsvc.strategies import get
    from graphsvc.strategies.base import prepared_index
    from graphsvc.strategies.multilinear import MultilinearOptions
    from graphsvc.strategies.multilinear.model import learn, tensors_of
    from graphsvc.strategies.options import parse_weights

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph")
    parser.add_argument("clip")
    parser.add_argument("--variance", type=float, default=MultilinearOptions.variance)
    parser.add_argument("--max-reps", type=int, default=MultilinearOptions.max_reps)
    parser.add_argument("--align", default=MultilinearOptions.align)
    args = parser.parse_args()
    own = MultilinearOptions(variance=args.variance, max_reps=args.max_reps, align=args.align)
    graph = load_graph(args.graph)
    strategy = get("multilinear")
    t0 = time.perf_counter()
    index = prepared_index(strategy, graph)
    index_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    arrays = learn(graph, index, np.arange(len(graph.clips)), own)
    learn_s = time.perf_counter() - t0
    tensors = [
        {
            "class": graph.labels[t.label],
            "foot": ("left", "right", "whole")[t.foot],
            "frames": t.frames,
            "rows": f"{t.u_style.shape[0]}x{t.u_rep.shape[0]}",
            "kept": list(t.kept),
        }
        for t in tensors_of(arrays)
    ]
    motion = resample(load_motion(args.clip), float(graph.rate_hz))
    rec = simulate_recording(motion, layout_from_dict(graph.layout), parse_noise("default"), seed=7)
    result = reconstruct(
        graph, rec, Options(strategy="multilinear", weights=parse_weights("0.5,1,1"), settings={"multilinear": own})
    )
    units = result.report["multilinear"]["units"]
    timings = result.report["timings_s"]
    print(
        json.dumps(
            {
                "graph": str(args.graph),
                "nodes": int(graph.num_nodes),
                "clip": motion.name,
                "samples": rec.num_samples,
                "variance": own.variance,
                "max_reps": own.max_reps,
                "align": own.align,
                "index_s": round(index_s, 2),
                "learn_s": round(learn_s, 2),
                "model_mb": round(sum(np.asarray(a).nbytes for a in arrays.values()) / 1e6, 1),
                "tensors": tensors,
                "search_s": timings["search"],
                "fit_s": timings["synthesis"],
                "units": len(units),
                "evaluations_mean": round(float(np.mean([u["evaluations"] for u in units])), 1) if units else 0,
                "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0),
                "machine": platform.machine(),
                "date": time.strftime("%Y-%m-%d"),
            }
        )
    )


if __name__ == "__main__":
    main()
