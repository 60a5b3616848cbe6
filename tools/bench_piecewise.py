#!/usr/bin/env python3
"""Benchmark: the piecewise strategy's learning and its cost a frame, live, printed as
one JSON line.

    tools/bench_piecewise.py GRAPH CLIP [--methods rbf,optimise] [--reduce pca] [--seconds 20]

GRAPH: a graph file (e.g. `graphsvc build` of Bandai dataset 2 without takes 004,
wrists-ankles); CLIP: a held-out motion file simulated with the default noise (seed 7)
as the stream. Per method, a live session (`strategies.open_session`, no lag) is opened
and the model learned (`learn_s`: the first session's model, learned and cached beside
the graph — a second run reads the cache: delete the `*.piecewise*` files beside GRAPH
to time the learning again; one model serves both methods, so the second method's
`learn_s` is only its session's opening), then the stream is pushed sample by sample:
`frame_ms_p50`, `frame_ms_p99` and `frame_ms_max` of one push (the first 10 samples,
where numba loads its kernels, left out), and the process's peak memory.
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

WARM_SAMPLES = 10


def main() -> None:
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.library import load_motion
    from graphsvc.motion.resample import resample
    from graphsvc.pipeline import Options
    from graphsvc.sensors.layout import layout_from_dict
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.simulate import simulate_recording
    from graphsvc.strategies import open_session
    from graphsvc.strategies.piecewise import PiecewiseOptions

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph")
    parser.add_argument("clip")
    parser.add_argument("--methods", default="rbf,optimise")
    parser.add_argument("--reduce", default="pca")
    parser.add_argument("--seconds", type=float, default=20.0, help="stream at most this much of the clip")
    args = parser.parse_args()
    graph = load_graph(args.graph)
    motion = resample(load_motion(args.clip), float(graph.rate_hz))
    rec = simulate_recording(motion, layout_from_dict(graph.layout), parse_noise("default"), seed=7)
    n = min(rec.num_samples, int(args.seconds * graph.rate_hz))
    out = {
        "graph": str(args.graph),
        "nodes": int(graph.num_nodes),
        "clip": motion.name,
        "samples": n,
        "reduce": args.reduce,
        "methods": {},
    }
    for method in args.methods.split(","):
        options = Options(strategy="piecewise", piecewise=PiecewiseOptions(method=method, reduce=args.reduce))
        t0 = time.perf_counter()
        live = open_session(graph, options, rec.sensor_names, keep_motion=False)
        live.push(float(rec.timestamps_s[0]), rec.accelerations[0], rec.ground_position[0], rec.heading[0])
        learn_s = time.perf_counter() - t0
        times = []
        for t in range(1, n):
            t1 = time.perf_counter()
            live.push(float(rec.timestamps_s[t]), rec.accelerations[t], rec.ground_position[t], rec.heading[t])
            times.append((time.perf_counter() - t1) * 1e3)
        live.flush()
        ms = np.asarray(times[WARM_SAMPLES:])
        out["methods"][method] = {
            "learn_s": round(learn_s, 2),
            "frame_ms_p50": round(float(np.median(ms)), 3),
            "frame_ms_p99": round(float(np.percentile(ms, 99)), 3),
            "frame_ms_max": round(float(ms.max()), 3),
        }
    out["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    out["machine"] = {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
