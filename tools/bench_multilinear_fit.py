#!/usr/bin/env python3
"""Benchmark: the multilinear strategy's per-unit fit alone, on the units of one real
recording, printed as one JSON line.

    tools/bench_multilinear_fit.py GRAPH CLIP --problems FILE [--rounds 2]
    tools/bench_multilinear_fit.py --problems FILE [--rounds 2]

The fit is the slow part of a reconstruction and the search before it takes minutes on
a loaded machine, so the units' fit problems (tensor, measured readings, frames, body,
options: `fit.fit_unit`'s arguments) are captured once from a reconstruction of CLIP
(simulated with the default noise, seed 7, weights 0.5,1,1) and pickled to FILE
(derived from the data: keep it out of the repository); a later run given FILE alone
fits them again. Each round fits every unit once (after one warm-up fit); it prints
the process CPU seconds of each round, their minimum, the residual evaluations the
optimiser counted and each unit's cost (g²) — which must agree between checkouts
whose fit is the same. Compare two checkouts by running each with its own
PYTHONPATH on the same FILE, in turn.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def capture(graph_path: str, clip: str) -> list[tuple]:
    """fit_unit's arguments for every unit of CLIP's reconstruction."""
    import graphsvc.strategies.multilinear.strategy as S
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.library import load_motion
    from graphsvc.motion.resample import resample
    from graphsvc.pipeline import Options, reconstruct
    from graphsvc.sensors.layout import layout_from_dict
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.simulate import simulate_recording
    from graphsvc.strategies.options import parse_weights

    graph = load_graph(graph_path)
    motion = resample(load_motion(clip), float(graph.rate_hz))
    rec = simulate_recording(motion, layout_from_dict(graph.layout), parse_noise("default"), seed=7)
    calls: list[tuple] = []
    fit = S.fit_unit

    def keep(*args):
        calls.append(args)
        return fit(*args)

    S.fit_unit = keep
    try:
        reconstruct(graph, rec, Options(strategy="multilinear", weights=parse_weights("0.5,1,1")))
    finally:
        S.fit_unit = fit
    return calls


def main() -> None:
    from graphsvc.strategies.multilinear.fit import fit_unit

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("graph", nargs="?")
    parser.add_argument("clip", nargs="?")
    parser.add_argument("--problems", required=True, help="pickle of the units' fit problems (written with GRAPH CLIP)")
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    if args.graph and args.clip:
        Path(args.problems).write_bytes(pickle.dumps(capture(args.graph, args.clip)))
    calls = pickle.loads(Path(args.problems).read_bytes())
    fit_unit(*calls[0])  # (warm-up: numba's caches, scipy's imports)
    rounds, fits = [], []
    for _ in range(args.rounds):
        t0 = time.process_time()
        fits = [fit_unit(*a) for a in calls]
        rounds.append(round(time.process_time() - t0, 3))
    print(
        json.dumps(
            {
                "tree": str(Path(str(sys.modules["graphsvc"].__file__)).resolve().parents[1]),
                "units": len(calls),
                "cpu_s": rounds,
                "min_cpu_s": min(rounds),
                "evaluations": int(sum(f.evaluations for f in fits)),
                "mean_cost": round(float(np.mean([f.cost for f in fits])), 6),
                "costs": [round(f.cost, 6) for f in fits],
                "date": time.strftime("%Y-%m-%d"),
            }
        )
    )


if __name__ == "__main__":
    main()
