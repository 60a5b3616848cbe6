#!/usr/bin/env python3
"""The SHA-256 of every strategy's reconstruction of a fixed set of inputs, to show a
change of the code's structure changed no output byte.

Inputs: the default demo's held-out performance (`graphsvc demo`'s graph and
recording), and five held-out Bandai dataset-2 takes 004 on a graph of dataset 2
without takes 004 (wrists-ankles; default noise, seed 7, the tracker's positions and
heading; hands-feet markers, σ 1 mm, for `ssg`). Each is reconstructed by `graphsvc
synthesize` (the command line, whose flags stay stable) with every built-in strategy
and with `--latency 1` for `viterbi` (the live decoder). Prints one JSON object a
reconstruction ({"case", "strategy", "sha256"}), then {"digest": ...} over them all.

Usage: tools/reconstruction_hashes.py DATA [--work DIR]
  DATA: the shared data folder (../shared/data). --work keeps the graphs and recordings
  between runs (default: a temporary folder).
Compare two checkouts by running each one's copy of this script with the same --work
after the first run built the inputs (the inputs do not depend on the code under test
once made: delete --work to remake them).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

TAKES = (
    "walk_normal_004",
    "run_active_004",
    "wave-left-hand_normal_004",
    "raise-up-both-hands_feminine_004",
    "walk-turn-left_masculine_004",
)
RUNS = {  # name: synthesize flags (after the files)
    "viterbi": ["--strategy", "viterbi", "--weights", "0.5,1,1"],
    "viterbi-live": ["--strategy", "viterbi", "--weights", "0.5,1,1", "--latency", "1"],
    "viterbi-beam": ["--strategy", "viterbi", "--weights", "0.5,1,1", "--beam", "10"],
    "nearest": ["--strategy", "nearest"],
    "olng": ["--strategy", "olng", "--weights", "0.5,1,1"],
}
SSG = ["--strategy", "ssg", "--markers", "hands-feet"]


def graphsvc(*args) -> None:
    exe = Path(sys.executable).with_name("graphsvc")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "graphsvc.cli"]
    subprocess.run(cmd + [str(a) for a in args], check=True, capture_output=True, text=True)


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path, help="the shared data folder (../shared/data)")
    ap.add_argument("--work", type=Path, help="keep graphs and recordings here (default: a temporary folder)")
    args = ap.parse_args()
    tmp = None if args.work else tempfile.TemporaryDirectory(prefix="graphsvc-hashes-")
    work = args.work or Path(tmp.name)
    work.mkdir(parents=True, exist_ok=True)
    d2 = args.data / "bandai" / "dataset-2" / "data"
    cases = []  # (case, graph, recording, marker recording)
    demo = work / "demo"
    if not (demo / "performance.rec").is_file():
        graphsvc("demo", "-o", demo)
    if not (work / "demo.graph").is_file():
        graphsvc("build", demo / "kb", "--layout", "kelly6", "--quiet", "-o", work / "demo.graph")
    if not (work / "demo-markers.rec").is_file():
        graphsvc(
            "simulate",
            demo / "performance.bvh",
            "--markers",
            "hands-feet",
            "--noise",
            "default",
            "--seed",
            "7",
            "-o",
            work / "demo-markers.rec",
        )
    cases.append(("demo", work / "demo.graph", demo / "performance.rec", work / "demo-markers.rec"))
    graph = work / "d2.graph"
    if not graph.is_file():
        graphsvc("build", d2, "--exclude", "*_004.bvh", "--jobs", "2", "--quiet", "-o", graph)
    for take in TAKES:
        clip = d2 / f"dataset-2_{take}.bvh"
        rec, markers = work / f"{take}.rec", work / f"{take}-markers.rec"
        if not rec.is_file():
            graphsvc("simulate", clip, "--layout", "wrists-ankles", "--noise", "default", "--seed", "7", "-o", rec)
        if not markers.is_file():
            graphsvc("simulate", clip, "--markers", "hands-feet", "--noise", "default", "--seed", "7", "-o", markers)
        cases.append((take, graph, rec, markers))
    out = work / "out"
    out.mkdir(exist_ok=True)
    digest = hashlib.sha256()
    for case, g, rec, markers in cases:
        for name, flags in [*RUNS.items(), ("ssg", SSG)]:
            bvh = out / f"{case}.{name}.bvh"
            graphsvc("synthesize", g, markers if name == "ssg" else rec, "-o", bvh, *flags)
            h = sha(bvh)
            digest.update(f"{case}/{name}/{h}\n".encode())
            print(json.dumps({"case": case, "strategy": name, "sha256": h}), flush=True)
    print(json.dumps({"digest": digest.hexdigest()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
