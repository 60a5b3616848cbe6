#!/usr/bin/env python3
"""Benchmark: the Viterbi search on a busy machine.

A batch search (720 samples, mode APO: accelerometers, position and heading) on the
generated G_E graph (tools/synthetic_graph.py; --nodes/--edges for another size), timed
alone and then beside one CPU-bound process per core (a busy loop each, started before
the searches and stopped after them), with the package's default kernels (threads=True:
threaded where faster, under the package's OpenMP settings, graphsvc/numba_env.py) and
with serial kernels (threads=False), the two alternating --repeats times (best of
each). Each load runs in its own process. Prints one JSON object a run, then a
summary: `ratio` = beside the hogs / alone with the default kernels (the
slowdown a user sees), `threaded_vs_serial_loaded` = default kernels / serial kernels,
both beside the hogs (≤ 1: threads never make a busy machine's search slower).

Usage: tools/bench_load.py [--nodes 100686 --edges 317600] [--samples 720] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _hog(stop) -> None:
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def child(args) -> list[dict]:
    import numba
    import numpy as np
    from bench_viterbi import problem

    from graphsvc.strategies.viterbi.batch import viterbi_search, warm_up_search

    g, acc, position, heading, weights, sets = problem("APO", args.nodes, args.edges, args.samples)
    for threads in (True, False):
        warm_up_search(g, threads=threads)
        viterbi_search(g, acc, position, heading, weights, sets, threads=threads)  # (the ring's memory, touched once)
    hogs, stop = [], None
    if args.load == "hogs":
        ctx = multiprocessing.get_context("spawn")
        stop = ctx.Event()
        hogs = [ctx.Process(target=_hog, args=(stop,), daemon=True) for _ in range(os.cpu_count() or 1)]
        for h in hogs:
            h.start()
        time.sleep(1.0)  # (the hogs running before the search starts)
    best = {True: np.inf, False: np.inf}
    try:
        for _ in range(args.repeats):  # the two kinds alternate, so both meet the same load
            for threads in (True, False):
                t0 = time.perf_counter()
                viterbi_search(g, acc, position, heading, weights, sets, threads=threads)
                best[threads] = min(best[threads], time.perf_counter() - t0)
    finally:
        if stop is not None:
            stop.set()
            for h in hogs:
                h.join(5)
    machine = f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}"
    return [
        {
            "kernels": "threaded" if threads else "serial",
            "load": args.load,
            "hogs": len(hogs),
            "nodes": g.num_nodes,
            "edges": g.num_edges,
            "samples": args.samples,
            "seconds": round(best[threads], 3),
            "threading_layer": numba.threading_layer() if threads else "serial",
            "spin_count": os.environ.get("GOMP_SPINCOUNT"),
            "wait_policy": os.environ.get("OMP_WAIT_POLICY"),
            "machine": machine,
        }
        for threads in (True, False)
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=100_686)
    parser.add_argument("--edges", type=int, default=317_600)
    parser.add_argument("--samples", type=int, default=720)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--load", choices=("idle", "hogs"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.load:
        for row in child(args):
            print(json.dumps(row), flush=True)
        return
    seconds = {}
    for load in ("idle", "hogs"):
        cmd = [
            sys.executable,
            __file__,
            "--load",
            load,
            "--nodes",
            str(args.nodes),
            "--edges",
            str(args.edges),
            "--samples",
            str(args.samples),
            "--repeats",
            str(args.repeats),
        ]
        out = subprocess.run(cmd, capture_output=True, text=True)
        if out.returncode != 0:
            print(json.dumps({"load": load, "error": out.stderr[-400:]}), flush=True)
            continue
        for line in out.stdout.strip().splitlines():
            row = json.loads(line)
            seconds[row["kernels"], load] = row["seconds"]
            print(json.dumps(row), flush=True)
    if len(seconds) == 4:
        print(
            json.dumps(
                {
                    "ratio": round(seconds["threaded", "hogs"] / seconds["threaded", "idle"], 2),
                    "threaded_vs_serial_loaded": round(seconds["threaded", "hogs"] / seconds["serial", "hogs"], 2),
                    "serial_ratio": round(seconds["serial", "hogs"] / seconds["serial", "idle"], 2),
                }
            ),
            flush=True,
        )


if __name__ == "__main__":
    main()
