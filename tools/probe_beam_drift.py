#!/usr/bin/env python3
"""Probe: how far a search's path, root and heading stray from the truth over a long input,
exact search against beams.

The input is `bench_beam.graph_walk`'s noisy walk through a graph (the generated G_E of
`bench_viterbi.py`, or --graph FILE), mode APO (weights 0.5, 1, 1) or A (1, 0, 0:
accelerometers alone), batch with numba threads. Each search's path is integrated from
the first measured position and heading (as synthesis does) and compared with the
walk's noise-free track. One JSON object per search: seconds, cost, mean root error (m)
overall and by quarter of the input, mean heading error (deg), the share of samples on
the walk's nodes, and, for beams, on the exact search's path (when it ran).

    python tools/probe_beam_drift.py --samples 108000 --beams 10   # about 8 minutes
    python tools/probe_beam_drift.py --samples 108000 --beams 10 --mode A
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    import bench_beam

    from graphsvc.graph.metadata import integrate_path
    from graphsvc.strategies.options import TRACK_DRIFT, TRACK_PULL_S, TRACK_SIGMA_M, Weights
    from graphsvc.strategies.viterbi.batch import viterbi_search
    from graphsvc.synthesis.track import TrackModel, fused_track

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", help="a built graph file (default: bench_viterbi.py's generated G_E graph)")
    parser.add_argument("--samples", type=int, default=108_000)
    parser.add_argument("--beams", default="10", help="beam widths, comma-separated")
    parser.add_argument("--mode", choices=("A", "APO"), default="APO")
    parser.add_argument("--no-exact", action="store_true", help="skip the exact search")
    parser.add_argument(
        "--track-pull",
        type=float,
        default=TRACK_PULL_S,
        help=f"the search's pull toward the tracker, s (APO; default {TRACK_PULL_S:g}, 0: placed once)",
    )
    args = parser.parse_args()
    graph = bench_beam.benchmark_graph(args.graph)
    walk_nodes, acc, position, heading = bench_beam.graph_walk(graph, args.samples)
    _, _, true_position, true_heading = bench_beam.graph_walk(graph, args.samples, noise=False)
    weights = Weights(0.5, 1, 1) if args.mode == "APO" else Weights(1, 0, 0)
    measured = (position, heading) if args.mode == "APO" else (None, None)
    # compilation and the beam's tables first, outside the timed searches
    viterbi_search(graph, acc[:600], *(None if m is None else m[:600] for m in measured), weights, beam=1.0)
    searches = ([] if args.no_exact else [None]) + [float(b) for b in args.beams.split(",")]
    exact_path = None
    quarters = np.linspace(0, args.samples, 5).astype(int)
    for beam in searches:
        t0 = time.perf_counter()
        pull = args.track_pull if args.mode == "APO" else 0.0
        r = viterbi_search(graph, acc, *measured, weights, beam=beam, pull_s=pull)
        seconds = time.perf_counter() - t0
        track, turn = integrate_path(
            position[0], heading[0], graph.edge_offset[r.edge_path], graph.edge_heading[r.edge_path]
        )
        if args.mode == "APO":  # (the root a synthesis of this path places: fused with the tracker)
            track = fused_track(
                graph,
                r.node_path,
                r.edge_path,
                position[0],
                heading[0],
                position,
                TrackModel(TRACK_SIGMA_M, TRACK_DRIFT, graph.rate_hz),
            )
        root_err = np.linalg.norm(track - true_position, axis=1)
        heading_err = np.abs((turn - true_heading + np.pi) % (2 * np.pi) - np.pi)
        row = {
            "search": "exact" if beam is None else f"beam {beam:g}",
            "mode": args.mode,
            "track_pull_s": pull,
            "nodes": graph.num_nodes,
            "samples": args.samples,
            "seconds": round(seconds, 1),
            "cost": round(r.cost, 1),
            "root_err_m": round(float(root_err.mean()), 3),
            "root_err_m_by_quarter": [round(float(root_err[a:b].mean()), 3) for a, b in zip(quarters, quarters[1:])],
            "heading_err_deg": round(float(np.degrees(heading_err.mean())), 2),
            "on_walk": round(float(np.mean(r.node_path == walk_nodes)), 4),
        }
        if beam is None:
            exact_path = r.node_path
        elif exact_path is not None:
            row["same_nodes_as_exact"] = round(float(np.mean(r.node_path == exact_path)), 4)
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
