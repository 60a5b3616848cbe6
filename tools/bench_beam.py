"""Benchmark the beam search against the exact one on a built graph, or on the generated
G_E graph of `bench_viterbi.py` without --graph; prints one JSON object per run.

The input is a walk through the graph itself: at each sample a random outgoing edge
(dead ends jump to a random node), the edge's readings plus white noise (0.3 m/s²),
and, for mode APO, the walk's own ground track and heading (its edges' offsets and
turns, integrated as a synthesis integrates them) plus tracker noise (σ 0.1 m, 10°).
So positions agree with the readings, as they do in a real recording; the random
input of `bench_viterbi.py`'s exact runs has no path that explains it, so a beam finds
nothing safe to cut there.

Per beam (none = the exact search): a batch search with numba threads (seconds, cost,
the share of samples on the exact search's node path), and a live stream (fixed lag,
serial kernels, as a server runs one): per-push milliseconds after the first 50
pushes (mean, p50, p99), over the first 10, when every node is still live, and over
all of them (mean). With --gap N, N samples from the middle on have no accelerometer
reading (--gap-all: nothing measured), as in a sensor dropout; the stream's pushes
during the gap and over the 30 samples after it are reported apart, and left out of
the figures after the first 50.

    python tools/bench_beam.py --graph /tmp/bandai2_k6.graph --beams 10,3
    python tools/bench_beam.py --beams 10   # generated G_E (100,686 nodes, 317,600 edges)
    python tools/bench_beam.py --beams 10 --modes APO --gap 30 [--gap-all]
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def graph_walk(
    graph, samples: int, seed: int = 0, noise: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(nodes (T,), acc (T, S, 3) m/s², ground position (T, 2) m, heading (T,) rad): a
    random walk through the graph's edges (`bench_service.random_walk`) with noisy
    readings and a noisy track (noise=False: the same walk, readings and track as they
    are)."""
    from bench_service import random_walk

    from graphsvc.graph.metadata import integrate_path

    rng = np.random.default_rng(seed)
    node, edges = random_walk(graph, samples - 1, rng)
    nodes = np.concatenate([[node], graph.edge_dst[edges]]).astype(np.int64)
    acc = np.empty((samples,) + graph.edge_acc.shape[1:], np.float32)
    acc[0] = graph.edge_acc[graph.incoming[node]] if graph.incoming[node + 1] > graph.incoming[node] else 0.0
    acc[1:] = graph.edge_acc[edges]
    position, heading = integrate_path(np.zeros(2), 0.0, graph.edge_offset[edges], graph.edge_heading[edges])
    if not noise:
        return nodes, acc, position, heading
    acc += rng.normal(0.0, 0.3, acc.shape).astype(np.float32)
    position += rng.normal(0.0, 0.1, position.shape)
    heading += rng.normal(0.0, np.radians(10.0), samples)
    return nodes, acc, position, heading


def benchmark_graph(path: str | None):
    """The graph file at path, or, without one, `bench_viterbi.py`'s generated G_E graph."""
    if path:
        from graphsvc.graph.file import load_graph

        return load_graph(path)
    from synthetic_graph import generated_graph

    return generated_graph(100_686, 317_600)


def run(
    graph, mode: str, beam: float | None, samples: int, lag: int, exact_path=None, gap: int = 0, gap_all: bool = False
) -> tuple[dict, np.ndarray]:
    """One search's row and node path. gap: that many samples from the middle on have no
    accelerometer reading (a sensor dropout; gap_all: no position and heading either)."""
    from graphsvc.strategies.options import Weights
    from graphsvc.strategies.viterbi.batch import viterbi_search
    from graphsvc.strategies.viterbi.stream import FixedLagDecoder

    _, acc, position, heading = graph_walk(graph, samples)
    if mode == "A":
        weights, position, heading = Weights(1, 0, 0), None, None
    else:
        weights = Weights(0.5, 1, 1)
    gap_at = samples // 2
    gap_span = slice(gap_at, gap_at + gap)
    acc[gap_span] = np.nan
    if gap_all and position is not None:
        position[gap_span], heading[gap_span] = np.nan, np.nan
    # a shorter search first: the beam's tables, and the first touch of the ring's memory
    viterbi_search(
        graph,
        acc[:300],
        None if position is None else position[:300],
        None if heading is None else heading[:300],
        weights,
        beam=beam,
    )
    t0 = time.perf_counter()
    result = viterbi_search(graph, acc, position, heading, weights, beam=beam)
    batch_s = time.perf_counter() - t0
    decoder = FixedLagDecoder(graph, weights, lag=lag, threads=False, beam=beam)
    times = np.empty(samples)
    live = np.zeros(samples)
    for t in range(samples):
        t0 = time.perf_counter()
        decoder.push(acc[t], None if position is None else position[t], None if heading is None else heading[t])
        times[t] = time.perf_counter() - t0
        live[t] = decoder.search._n_live if beam is not None else np.isfinite(decoder.search.cost).sum()
    settled = np.arange(samples) >= 50
    settled[gap_span.start : gap_span.stop + 30] = False  # (nothing without a gap)
    steady = times[settled]
    out = {
        "mode": f"{mode}, {'exact' if beam is None else f'beam {beam:g}'}",
        "beam": beam,
        "input": "graph walk",
        "nodes": graph.num_nodes,
        "edges": graph.num_edges,
        "samples": samples,
        "batch_seconds": round(batch_s, 3),
        "cost": result.cost,
        "stream_ms_per_sample": round(1000 * float(steady.mean()), 3),
        "stream_p50_ms": round(1000 * float(np.percentile(steady, 50)), 3),
        "stream_p99_ms": round(1000 * float(np.percentile(steady, 99)), 3),
        "stream_first10_ms": round(1000 * float(times[:10].mean()), 3),
        "stream_all_ms_per_sample": round(1000 * float(times.mean()), 3),
        "live_share_median": round(float(np.median(live[50:])) / graph.num_nodes, 5),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    if gap:
        after = slice(gap_span.stop, gap_span.stop + 30)
        out.update(
            {
                "gap_samples": gap,
                "gap_channels": "all" if gap_all else "accelerometers",
                "gap_ms_per_sample": round(1000 * float(times[gap_span].mean()), 3),
                "gap_max_ms": round(1000 * float(times[gap_span].max()), 3),
                "gap_live_max": int(live[gap_span].max()),
                "after_gap_ms_per_sample": round(1000 * float(times[after].mean()), 3),
            }
        )
    if exact_path is not None:
        out["same_nodes_as_exact"] = round(float(np.mean(result.node_path == exact_path)), 4)
    return out, result.node_path


def main() -> None:
    from graphsvc.strategies.viterbi.batch import warm_up_search

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--graph", help="a built graph file (default: bench_viterbi.py's generated G_E graph)")
    parser.add_argument("--beams", default="10,3", help="beam widths to compare with the exact search")
    parser.add_argument("--samples", type=int, default=720)
    parser.add_argument("--lag", type=int, default=30, help="the stream's fixed lag in samples (default 1 s)")
    parser.add_argument("--modes", default="A,APO")
    parser.add_argument(
        "--gap",
        type=int,
        default=0,
        help="samples without accelerometer readings from the input's middle on (a dropout)",
    )
    parser.add_argument("--gap-all", action="store_true", help="the gap has no position and heading either")
    args = parser.parse_args()
    graph = benchmark_graph(args.graph)
    warm_up_search(graph, threads=True)
    warm_up_search(graph, threads=False)
    for mode in args.modes.split(","):
        row, exact_path = run(graph, mode, None, args.samples, args.lag, gap=args.gap, gap_all=args.gap_all)
        print(json.dumps(row), flush=True)
        for beam in (float(b) for b in args.beams.split(",")):
            row, _ = run(graph, mode, beam, args.samples, args.lag, exact_path, args.gap, args.gap_all)
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
