#!/usr/bin/env python3
"""Benchmark: Viterbi search speed and memory.

A generated graph of the largest size of Kelly et al. 2013 (G_E: 100,686 nodes, 317,600 edges: clips as
chains of original edges plus random transitions, random 6-sensor metadata), searched
with 720 samples (24 s at 30 Hz) in modes A (accelerometers), APO (+ position and
heading) and APO+2constraints; a one-hour input (108,000 samples, mode APO); and the
plain numpy full-lattice reference against the numba search on a smaller graph; the
fixed-lag streaming decoder as a server runs it (serial kernels, per-push latency), and
with numba threads (one stream using both cores).
With --graph, modes A and APO also run on that built graph ("built A", "built APO"),
fed a noisy random walk through its own edge readings (tools/bench_service.py's).
The "beam" runs search G_E with the beam (width --beam, default 10) on an input a
graph can explain: a noisy walk through G_E itself, readings and ground track
(`bench_beam.graph_walk`; on the random input no beam can cut safely). "beam A" and
"beam APO" also run the exact search and the exact stream on the same input in the
same process and report whether the beam found the exact search's path
(`same_nodes_as_exact`: the share of samples on it); "beam hour" is a one-hour walk,
beam only. With --data (the Bandai-Namco folder), "beam held-out A" and "beam held-out
APO" run both searches where users run them: a graph of G_E's size built from three
styles of dataset 2 without their takes 004, searched with those takes joined end to
end and simulated with the default noise (`input: held-out`). Searches with positions
pull each path toward them with the default time constant (`--track-pull`). One JSON object per run. Each run is its own process, so peak RSS is its own.

Usage: tools/bench_viterbi.py [--only MODE] [--hour-samples 108000] [--graph FILE] [--data DIR] [--beam 10]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from synthetic_graph import generated_graph  # noqa: E402

from graphsvc.strategies.options import TRACK_PULL_S  # noqa: E402

PULL = TRACK_PULL_S  # searches with positions pull their paths toward them, as users' do by default


def inputs(T: int, sensors: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    acc = rng.normal(0, 9.81, (T, sensors, 3))
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.03, T))
    return acc, position, heading


def problem(mode: str, nodes: int, edges: int, samples: int, graph_path: str | None = None) -> tuple:
    """A run's (graph, acc, position, heading, weights, constraint sets): a generated
    graph and random input, or a built graph and a random walk through its readings."""
    from graphsvc.strategies.options import Weights

    if graph_path:
        from bench_service import random_walk_readings

        from graphsvc.graph.file import load_graph

        g = load_graph(graph_path)
        _, position, heading = inputs(samples, 6)
        acc = random_walk_readings(graph_path, samples, seed=0)
    else:
        g = generated_graph(nodes, edges)
        acc, position, heading = inputs(samples, 6)
    sets = []
    if mode == "A":
        weights, position, heading = Weights(1, 0, 0), None, None
    else:
        weights = Weights(0.5, 1, 1)
    if mode == "APO+2constraints":
        sets = [
            [{"start_s": 2.0, "end_s": 6.0, "require": {"contact": "both"}}],
            [{"start_s": 4.0, "end_s": 12.0, "require": {"label": "b"}}],
        ]
    return g, acc, position, heading, weights, sets


def run(mode: str, nodes: int, edges: int, samples: int, graph_path: str | None = None) -> dict:
    from graphsvc.strategies.viterbi.batch import batch_ring, viterbi_search, warm_up_search

    g, acc, position, heading, weights, sets = problem(mode, nodes, edges, samples, graph_path)
    # Warm-up: numba compilation, and a search long enough to make the timed one's ring,
    # whose memory a process touches for the first time once (45 ms on G_E), as a server
    # or `evaluate` does with its first long search.
    k = min(samples, batch_ring(samples)[0] + 1)
    viterbi_search(
        g,
        acc[:k],
        None if position is None else position[:k],
        None if heading is None else heading[:k],
        weights,
        sets,
        pull_s=PULL,
    )
    warm_up_search(g, threads=True)  # (and the walk-back kernels, which a 3-sample search never reaches)
    t0 = time.perf_counter()
    r = viterbi_search(g, acc, position, heading, weights, sets, pull_s=PULL)
    seconds = time.perf_counter() - t0
    return {
        "mode": mode,
        "nodes": g.num_nodes,
        "edges": g.num_edges,
        "samples": samples,
        "seconds": round(seconds, 3),
        "ms_per_sample": round(1000 * seconds / samples, 3),
        "edge_steps_per_s": round(g.num_edges * (samples - 1) / seconds),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "compression": round(r.compression, 1),
        "peak_entries": r.peak_entries,
        "machine": f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}",
    }


def run_reference(nodes: int, edges: int, samples: int) -> dict:
    from graphsvc.strategies.options import Weights
    from graphsvc.strategies.viterbi.batch import viterbi_search
    from graphsvc.strategies.viterbi.reference import reference_viterbi

    g = generated_graph(nodes, edges)
    acc, position, heading = inputs(samples, 6)
    w = Weights(0.5, 1, 1)
    viterbi_search(g, acc[:3], position[:3], heading[:3], w, pull_s=PULL)
    t0 = time.perf_counter()
    fast = viterbi_search(g, acc, position, heading, w, pull_s=PULL)
    t_fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref_path, _ = reference_viterbi(g, acc, position, heading, w, pull_s=PULL)
    t_ref = time.perf_counter() - t0
    return {
        "mode": "APO numba vs numpy reference",
        "nodes": g.num_nodes,
        "edges": g.num_edges,
        "samples": samples,
        "seconds": round(t_fast, 3),
        "reference_seconds": round(t_ref, 3),
        "speed_ratio": round(t_ref / t_fast, 1),
        "same_path": bool(np.array_equal(fast.node_path, ref_path)),
        "edge_steps_per_s": round(g.num_edges * (samples - 1) / t_fast),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def run_stream(nodes: int, edges: int, samples: int, threads: bool = False) -> dict:
    """The fixed-lag decoder (1 s lag, APO) as a live server runs it: serial kernels,
    one push per sample; per-push latency percentiles. threads: numba threads per step
    instead (one stream with the whole machine)."""
    from graphsvc.strategies.options import Weights
    from graphsvc.strategies.viterbi.batch import warm_up_search
    from graphsvc.strategies.viterbi.stream import FixedLagDecoder

    g = generated_graph(nodes, edges)
    acc, position, heading = inputs(samples, 6)
    w = Weights(0.5, 1, 1)
    warm_up_search(g, threads=threads)
    warm = FixedLagDecoder(g, w, lag=30, threads=threads)
    for t in range(40):
        warm.push(acc[t], position[t], heading[t])
    decoder = FixedLagDecoder(g, w, lag=30, threads=threads)
    times = np.empty(samples)
    for t in range(samples):
        t0 = time.perf_counter()
        decoder.push(acc[t], position[t], heading[t])
        times[t] = time.perf_counter() - t0
    decoder.flush()
    kernels = "threads" if threads else "serial"
    return {
        "mode": f"stream APO, fixed lag 1 s, {kernels}",
        "nodes": g.num_nodes,
        "edges": g.num_edges,
        "samples": samples,
        "seconds": round(float(times.sum()), 3),
        "ms_per_sample": round(1000 * float(times.mean()), 3),
        "p50_ms": round(1000 * float(np.percentile(times, 50)), 3),
        "p99_ms": round(1000 * float(np.percentile(times, 99)), 3),
        "revisions": decoder.revisions,
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def run_beam(mode: str, beam: float, samples: int) -> dict:
    """The beam search on G_E against the exact one, both on a walk through G_E
    (`bench_beam.run`: a batch search with numba threads, then a fixed-lag stream with
    serial kernels, 1 s lag)."""
    import bench_beam

    from graphsvc.strategies.viterbi.batch import warm_up_search

    g = generated_graph(100_686, 317_600)
    warm_up_search(g, threads=True)
    warm_up_search(g, threads=False)
    exact, exact_path = bench_beam.run(g, mode, None, samples, lag=30)
    row, _ = bench_beam.run(g, mode, beam, samples, lag=30, exact_path=exact_path)
    return {
        **row,
        "seconds": row["batch_seconds"],
        "ms_per_sample": round(1000 * row["batch_seconds"] / samples, 3),
        "exact_seconds": exact["batch_seconds"],
        "exact_stream_ms_per_sample": exact["stream_ms_per_sample"],
        "same_cost_as_exact": row["cost"] == exact["cost"],
    }


def run_beam_hour(beam: float, samples: int) -> dict:
    """The beam search (APO, batch, numba threads) over a long walk through G_E: time and
    peak memory (the exact search is not run: it takes minutes)."""
    import bench_beam

    from graphsvc.strategies.options import Weights
    from graphsvc.strategies.viterbi.batch import viterbi_search, warm_up_search

    g = generated_graph(100_686, 317_600)
    _, acc, position, heading = bench_beam.graph_walk(g, samples)
    weights = Weights(0.5, 1, 1)
    warm_up_search(g, threads=True)
    viterbi_search(g, acc[:600], position[:600], heading[:600], weights, beam=beam, pull_s=PULL)  # the beam's tables
    t0 = time.perf_counter()
    r = viterbi_search(g, acc, position, heading, weights, beam=beam, pull_s=PULL)
    seconds = time.perf_counter() - t0
    return {
        "mode": f"APO, long input, beam {beam:g}",
        "beam": beam,
        "input": "graph walk",
        "nodes": g.num_nodes,
        "edges": g.num_edges,
        "samples": samples,
        "seconds": round(seconds, 3),
        "ms_per_sample": round(1000 * seconds / samples, 4),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "compression": round(r.compression, 1),
        "peak_entries": r.peak_entries,
    }


HELD_OUT_STYLES = ("active", "feminine", "normal")
HELD_OUT_CONTENTS = (
    "walk",
    "run",
    "wave-left-hand",
    "walk-turn-left",
    "raise-up-both-hands",
    "walk-turn-right",
    "raise-up-left-hand",
    "wave-both-hands",
    "raise-up-right-hand",
    "wave-right-hand",
)


def held_out_problem(data: str, samples: int):
    """A graph of G_E's size built from Bandai-Namco dataset 2 (the styles
    HELD_OUT_STYLES without their takes 004: about 110k nodes, wrists-ankles), and an
    input no path of it reproduces: those styles' takes 004 joined end to end up to
    `samples` samples (one action after another: walk, run, wave-left-hand, …, the
    styles in turn), simulated with the default noise (positions and heading)."""
    from graphsvc.evaluate.mixed import join_clips
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.motion.library import find_motion_files, load_motion
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.noise import PRESETS
    from graphsvc.sensors.simulate import simulate_recording

    files = find_motion_files([str(Path(data) / "dataset-2" / "data")])
    styled = [f for f in files if f.stem.split("_")[2] in HELD_OUT_STYLES]
    kb = [load_motion(f) for f in styled if not f.stem.endswith("_004")]
    tests = [load_motion(f) for f in styled if f.stem.endswith("_004")]
    g, _ = build_graph(kb, BuildOptions(layout=load_layout("wrists-ankles"), progress=False))
    by_name = {m.name: m for m in tests}
    picked, frames = [], 0
    for i in range(3 * len(HELD_OUT_CONTENTS)):  # one action after another, the styles in turn
        m = by_name.get(f"dataset-2_{HELD_OUT_CONTENTS[i % len(HELD_OUT_CONTENTS)]}_{HELD_OUT_STYLES[i % 3]}_004")
        if m is None:
            continue
        picked.append(m)
        frames += m.num_frames
        if frames >= samples + 30:
            break
    motion, _ = join_clips(picked, g.rate_hz)
    rec = simulate_recording(motion, load_layout("wrists-ankles"), PRESETS["default"], seed=0, rate_hz=g.rate_hz)
    return g, rec.accelerations[:samples], rec.ground_position[:samples], rec.heading[:samples], len(picked)


def run_beam_held_out(mode: str, beam: float, samples: int, data: str) -> dict:
    """The beam against the exact search (batch, numba threads) on `held_out_problem`."""
    from graphsvc.strategies.options import Weights
    from graphsvc.strategies.viterbi.batch import viterbi_search, warm_up_search

    g, acc, position, heading, clips = held_out_problem(data, samples)
    weights = Weights(1, 0, 0) if mode == "A" else Weights(0.5, 1, 1)
    pos, head = (None, None) if mode == "A" else (position, heading)
    warm_up_search(g, threads=True)
    viterbi_search(g, acc, pos, head, weights, pull_s=PULL)  # (the ring's memory, touched once)
    viterbi_search(
        g,
        acc[:600],
        pos if pos is None else pos[:600],
        head if head is None else head[:600],
        weights,
        beam=beam,
        pull_s=PULL,
    )  # the beam's tables
    t0 = time.perf_counter()
    exact = viterbi_search(g, acc, pos, head, weights, pull_s=PULL)
    exact_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = viterbi_search(g, acc, pos, head, weights, beam=beam, pull_s=PULL)
    seconds = time.perf_counter() - t0
    return {
        "mode": f"{mode}, beam {beam:g}",
        "beam": beam,
        "input": "held-out",
        "held_out_clips": clips,
        "nodes": g.num_nodes,
        "edges": g.num_edges,
        "samples": samples,
        "seconds": round(seconds, 3),
        "exact_seconds": round(exact_s, 3),
        "speed_up": round(exact_s / seconds, 2),
        "same_nodes_as_exact": round(float(np.mean(r.node_path == exact.node_path)), 4),
        "cost": r.cost,
        "exact_cost": exact.cost,
        "machine": f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}",
    }


RUNS = {
    "A": lambda a: run("A", 100_686, 317_600, 720),
    "APO": lambda a: run("APO", 100_686, 317_600, 720),
    "APO+2constraints": lambda a: run("APO+2constraints", 100_686, 317_600, 720),
    "hour": lambda a: {**run("APO", 100_686, 317_600, a.hour_samples), "mode": "APO, long input"},
    "reference": lambda a: run_reference(7_577, 9_433, 720),
    "stream": lambda a: run_stream(100_686, 317_600, 720),
    "stream threads": lambda a: run_stream(100_686, 317_600, 720, threads=True),
    "beam A": lambda a: run_beam("A", a.beam, 720),
    "beam APO": lambda a: run_beam("APO", a.beam, 720),
    "beam hour": lambda a: run_beam_hour(a.beam, a.hour_samples),
    "beam held-out A": lambda a: run_beam_held_out("A", a.beam, 720, a.data),
    "beam held-out APO": lambda a: run_beam_held_out("APO", a.beam, 720, a.data),
    "built A": lambda a: {**run("A", 0, 0, 720, a.graph), "mode": "built A", "graph": a.graph},
    "built APO": lambda a: {**run("APO", 0, 0, 720, a.graph), "mode": "built APO", "graph": a.graph},
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", choices=sorted(RUNS))
    parser.add_argument("--hour-samples", type=int, default=108_000)
    parser.add_argument("--graph", help="a built graph file for the 'built A' and 'built APO' runs")
    parser.add_argument("--data", help="the Bandai-Namco folder, for the 'beam held-out' runs")
    parser.add_argument("--beam", type=float, default=10.0, help="the beam runs' width (default 10)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(RUNS[args.child](args)), flush=True)
        return
    names = (
        [args.only]
        if args.only
        else [n for n in RUNS if (args.graph or not n.startswith("built")) and (args.data or "held-out" not in n)]
    )
    if any(n.startswith("built") for n in names) and not args.graph:
        parser.error("the 'built' runs need --graph FILE")
    if any("held-out" in n for n in names) and not args.data:
        parser.error("the 'beam held-out' runs need --data DIR (the Bandai-Namco folder)")
    for name in names:
        cmd = [
            sys.executable,
            __file__,
            "--child",
            name,
            "--hour-samples",
            str(args.hour_samples),
            "--beam",
            str(args.beam),
        ]
        if args.graph:
            cmd += ["--graph", args.graph]
        if args.data:
            cmd += ["--data", args.data]
        out = subprocess.run(cmd, capture_output=True, text=True)
        print(
            out.stdout.strip() if out.returncode == 0 else json.dumps({"run": name, "error": out.stderr[-400:]}),
            flush=True,
        )


if __name__ == "__main__":
    main()
