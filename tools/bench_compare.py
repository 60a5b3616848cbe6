#!/usr/bin/env python3
"""Benchmark: the batch search of two or more checkouts, alternating.

This machine's speed drifts by up to ±50 % within minutes (a shared VM), so a before /
after comparison from two separate benchmark runs says little. This script runs each
checkout's own `viterbi_search` on the same generated G_E-size graph and input (this
checkout's `tools/bench_viterbi.py` `problem`), in turn, in fresh processes, several
rounds, and prints one JSON object per process (`tree`, `mode`, `seconds` per search,
`node_path_sum` and `cost`, which must agree across checkouts whose search is exact),
then one summary object per checkout (`min_s`, `median_s` over every search).

Usage: tools/bench_compare.py CHECKOUT... [--mode A|APO] [--rounds 2] [--searches 4] [--graph FILE]
  e.g. git worktree add /tmp/before HEAD~1 && tools/bench_compare.py /tmp/before .
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import json, sys, time
sys.path.insert(0, {tools!r})
import bench_viterbi as B  # this checkout's problem set-up; it puts this checkout first on the path,
sys.path.insert(0, {tree!r})  # so the checkout measured goes before it
from graphsvc.strategies.viterbi.batch import viterbi_search, warm_up_search
g, acc, position, heading, weights, _ = B.problem({mode!r}, 100_686, 317_600, 720, {graph!r})
viterbi_search(g, acc[:3], None if position is None else position[:3], None if heading is None else heading[:3],
               weights)
warm_up_search(g)
seconds = []
for _ in range({searches}):
    t0 = time.perf_counter()
    r = viterbi_search(g, acc, position, heading, weights)
    seconds.append(round(time.perf_counter() - t0, 3))
assert sys.modules["graphsvc"].__file__.startswith({tree!r}), sys.modules["graphsvc"].__file__
print(json.dumps({{"seconds": seconds, "node_path_sum": int(r.node_path.sum()), "cost": r.cost}}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trees", nargs="+", help="checkouts (directories holding graphsvc/ and tests/)")
    parser.add_argument("--mode", choices=("A", "APO"), default="A")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--searches", type=int, default=4, help="searches per process")
    parser.add_argument("--graph", help="a built graph file instead of the generated one (bench_viterbi's --graph)")
    args = parser.parse_args()
    trees = [str(Path(t).resolve()) for t in args.trees]
    for tree in trees:
        if not Path(tree, "graphsvc", "search", "viterbi.py").is_file():
            parser.error(f"{tree} is not a graphsvc checkout")
    times: dict[str, list[float]] = {t: [] for t in trees}
    for _ in range(args.rounds):
        for tree in trees:
            code = CHILD.format(
                tree=tree,
                tools=str(Path(__file__).resolve().parent),
                mode=args.mode,
                searches=args.searches,
                graph=args.graph and str(Path(args.graph).resolve()),
            )
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tree)
            if out.returncode != 0:
                print(json.dumps({"tree": tree, "error": out.stderr[-400:]}), flush=True)
                continue
            run = json.loads(out.stdout.strip().splitlines()[-1])
            times[tree] += run["seconds"]
            print(json.dumps({"tree": tree, "mode": args.mode, **run}), flush=True)
    for tree, seconds in times.items():
        if seconds:
            ordered = sorted(seconds)
            print(
                json.dumps(
                    {
                        "tree": tree,
                        "mode": args.mode,
                        "searches": len(ordered),
                        "min_s": ordered[0],
                        "median_s": ordered[len(ordered) // 2],
                    }
                )
            )


if __name__ == "__main__":
    main()
