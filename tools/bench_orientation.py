#!/usr/bin/env python3
"""The Viterbi search's speed with and without the sensor-orientation term: recordings
joined end to end (samples with orientations, as `graphsvc simulate --noise real`
writes), searched on a graph with orientation metadata at W_R = 0 and W_R > 0, with
accelerometers alone (A) and with ground position and heading (APO). Prints JSON: per
mode the best of --repeat runs' search seconds and samples/s, and the readings table's
distinct readings and bytes; and OLNG's samples/s with accelerometers at W_R = 0 and
W_R > 0 (its neighbour query on the oriented tree).

Usage: tools/bench_orientation.py GRAPH REC... [--repeat 3] [--r 1]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from graphsvc.graph.file import load_graph
from graphsvc.sensors.grid import readings_at_rate, values_at_rate
from graphsvc.sensors.orientation import sensor_up
from graphsvc.sensors.recording import load_recording
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.batch import viterbi_search, warm_up_search
from graphsvc.strategies.viterbi.tables import search_index


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("graph")
    ap.add_argument("recordings", nargs="+")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--r", type=float, default=1.0, help="the orientation weight of the oriented runs")
    args = ap.parse_args()
    graph = load_graph(args.graph)
    parts = []
    for path in args.recordings:
        rec = load_recording(path)
        acc, position, heading, _ = readings_at_rate(rec, graph.rate_hz)
        parts.append((acc, position, heading, values_at_rate(rec, sensor_up(rec.orientations), graph.rate_hz)))
    acc = np.concatenate([p[0] for p in parts])
    position = np.concatenate([p[1] for p in parts])
    heading = np.concatenate([p[2] for p in parts])
    up = np.concatenate([p[3] for p in parts])
    warm_up_search(graph, threads=True)
    out = {"graph": args.graph, "samples": int(acc.shape[0]), "repeat": args.repeat, "modes": {}}
    for oriented in (False, True):
        t = search_index(graph, oriented).tables["readings_t"]
        out["readings_oriented" if oriented else "readings"] = {
            "distinct": int(t.shape[1]),
            "rows": int(t.shape[0]),
            "bytes": int(t.nbytes),
        }
    # The C_A (+ C_R) pass alone, 16 samples a call as a batch search makes it: ms a sample
    from graphsvc.strategies.viterbi.search import ViterbiSearch

    for oriented in (False, True):
        search = ViterbiSearch(graph, Weights(1.0, 0.0, 0.0, args.r), oriented=oriented)
        n = (acc.shape[0] // 16) * 16
        best = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            for b in range(0, n, 16):
                search.reading_costs(acc[b : b + 16], up=up[b : b + 16])
            best = min(best, time.perf_counter() - t0)
        out["reading_pass_ms_per_sample" + ("_oriented" if oriented else "")] = round(1e3 * best / n, 4)
    for mode, (a, p, o) in {"A": (1.0, 0.0, 0.0), "APO": (0.5, 1.0, 1.0)}.items():
        for r in (0.0, args.r):
            w = Weights(a, p, o, r)
            best = np.inf
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                result = viterbi_search(graph, acc, position if p else None, heading if o else None, w, up=up)
                best = min(best, time.perf_counter() - t0)
            out["modes"][f"{mode} R={r:g}"] = {
                "search_s": round(best, 3),
                "samples_per_s": round(acc.shape[0] / best, 1),
                "cost": result.cost,
            }
    # OLNG, recording by recording through the pipeline: its own samples/s (after warm-up and tree)
    from graphsvc.pipeline import reconstruct
    from graphsvc.strategies.options import Options

    recs = [load_recording(path) for path in args.recordings]
    for r in (0.0, args.r):
        options = Options(strategy="olng", weights=Weights(1.0, 0.0, 0.0, r))
        reconstruct(graph, recs[0], options)  # (warm: the index, its trees, the kernels)
        best = np.inf
        for _ in range(args.repeat):
            reports = [reconstruct(graph, rec, options).report for rec in recs]
            seconds = sum(rep["samples"] / rep["samples_per_s"] for rep in reports)
            best = min(best, seconds)
        out["modes"][f"olng A R={r:g}"] = {"seconds": round(best, 3), "samples_per_s": round(acc.shape[0] / best, 1)}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
