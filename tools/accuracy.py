#!/usr/bin/env python3
"""The accuracy table: `graphsvc evaluate --json` runs on Bandai-Namco dataset 2.

One graph a layout is built from the whole of dataset 2 (`graphsvc build`); every row
is an `evaluate --graph` run whose hold-out protocol hides the test clips' sets:

- hold-out `takes`: the takes 001 and 004 of every content × style as tests (140 clips),
  each hiding every take of its content × style;
- hold-out `actor`: the normal and masculine styles' takes 001 and 004 (40 clips, one
  actor), each hiding every clip of that actor (docs/evaluation.md).

For each: layouts wrists-ankles and kelly6; inputs accelerometers alone (`--noise
default,position=0,heading=none`), + overhead positions (`default,heading=none`, weights
0.5,1,1), + positions and heading (`default`, weights 0.5,1,1: Kelly et al.'s, not
tuned here); every registered strategy that reads accelerometers on the same clips
(the optical-marker strategy has its own figures: tools/bench_ssg.py). Prints one JSON object a
run (its row, the command and the figures, the locomotion and gesture means), then
the table in Markdown.

`--only clip` runs the clip hold-out (the test clip alone hidden) on the takes' tests.

`--preset real` runs the same rows with the `real` sensor noise (real IMUs: more white
noise, the legs' soft tissue, foot-strike jolts; docs/sensors.md) in place of `default`.

Usage: tools/accuracy.py DATA [--jobs 2] [--work DIR] [--only takes|actor|clip] [--layouts L,...]
                         [--inputs acc,pos,pos+heading] [--strategies viterbi,nearest] [--preset real]
                         [--reuse]
DATA: the Bandai-Namco folder (../shared/data/bandai).
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PROTOCOLS = {
    "takes": "*_00[14].bvh",
    "actor": "*_normal_00[14].bvh,*_masculine_00[14].bvh",
    "clip": "*_00[14].bvh",  # (only with --only clip: the least a test can hide)
}
DEFAULT_PROTOCOLS = ("takes", "actor")
INPUTS = {
    "acc": ("accelerometers", ["--noise", "default,position=0,heading=none"]),
    "pos": ("+ overhead positions", ["--noise", "default,heading=none", "--weights", "0.5,1,1"]),
    "pos+heading": ("+ positions and heading", ["--noise", "default", "--weights", "0.5,1,1"]),
}


def graphsvc() -> list[str]:
    exe = Path(sys.executable).with_name("graphsvc")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "graphsvc.cli"]


def run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"failed: {shlex.join(cmd)}\n{done.stderr[-2000:]}")


def main() -> None:
    from graphsvc.strategies import available, get

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="the Bandai-Namco folder (with dataset-2/data)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--work", help="folder for the graphs and JSON runs (default: a temporary one)")
    parser.add_argument("--only", choices=sorted(PROTOCOLS))
    parser.add_argument("--layouts", default="wrists-ankles,kelly6")
    parser.add_argument("--inputs", default=",".join(INPUTS))
    accelerometer_strategies = [n for n in available() if "accelerations" in get(n).needs]  # (ssg: tools/bench_ssg.py)
    parser.add_argument("--strategies", default=",".join(accelerometer_strategies))
    parser.add_argument("--preset", default="default",
                        help="the sensors' noise preset (default; real: tools/fit_real_noise.py's devices)")
    parser.add_argument("--reuse", action="store_true",
                        help="keep a run already in --work that the same command wrote (after a change that cannot"
                             " move it, e.g. one to how positions are used, for the accelerometer-only rows)")
    args = parser.parse_args()
    kb = Path(args.data) / "dataset-2" / "data"
    if not kb.is_dir():
        raise SystemExit(f"{kb} not found (give the Bandai-Namco folder)")
    work = Path(args.work or tempfile.mkdtemp(prefix="graphsvc-accuracy-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for layout in args.layouts.split(","):
        graph = work / f"dataset-2.{layout}.graph"
        if not graph.exists():
            run(graphsvc() + ["build", str(kb), "--layout", layout, "--jobs", str(args.jobs), "--quiet", "-o", str(graph)])
        for protocol in [args.only] if args.only else DEFAULT_PROTOCOLS:
            for key in args.inputs.split(","):
                what, flags = INPUTS[key]
                flags = [f.replace("default", args.preset, 1) if f.startswith("default") else f for f in flags]
                for strategy in args.strategies.split(","):
                    tag = "" if args.preset == "default" else f".{args.preset}"
                    out = work / f"{protocol}.{layout}.{key}.{strategy}{tag}.json"
                    cmd = graphsvc() + ["evaluate", str(kb), "--graph", str(graph), "--test", PROTOCOLS[protocol],
                                        "--hold-out", protocol, *flags, "--strategy", strategy, "--jobs",
                                        str(args.jobs), "--json", str(out), "--quiet"]  # fmt: skip
                    t0 = time.perf_counter()
                    stamp = out.with_suffix(".cmd")  # the command that wrote `out`
                    if not (args.reuse and out.exists() and stamp.exists() and stamp.read_text() == shlex.join(cmd)):
                        run(cmd)
                        stamp.write_text(shlex.join(cmd))
                    result = json.loads(out.read_text())
                    m, groups = result["mean"], result.get("groups", {})
                    row = {"hold_out": protocol, "layout": layout, "inputs": what, "strategy": strategy,
                           "noise": args.preset,
                           "clips": m["clips"], "frames": m["frames"], "joint_err_cm": m["joint_err_cm"],
                           "root_err_cm": m["root_err_cm"], "heading_err_deg": m["heading_err_deg"],
                           "label_acc": m["label_acc"], "samples_per_s": m.get("samples_per_s"),
                           "groups": {g: {k: v[k] for k in ("clips", "joint_err_cm", "root_err_cm", "label_acc")}
                                      for g, v in groups.items()},
                           "seconds": round(time.perf_counter() - t0, 1),
                           "command": shlex.join(["graphsvc", *cmd[len(graphsvc()):]])}  # fmt: skip
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    print()
    print(table(rows))


def _f(x, spec, scale=1.0):
    return "—" if x is None else format(x * scale, spec)


def table(rows: list[dict]) -> str:
    head = ("hold-out", "layout", "inputs", "strategy", "clips", "joint cm", "root cm", "heading °", "label",
            "locomotion joint cm", "gestures joint cm")  # fmt: skip
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in rows:
        g = r["groups"]
        cells = (r["hold_out"], f"`{r['layout']}`", r["inputs"], f"`{r['strategy']}`", str(r["clips"]),
                 _f(r["joint_err_cm"], ".2f"), _f(r["root_err_cm"], ".1f"), _f(r["heading_err_deg"], ".1f"),
                 (_f(r["label_acc"], ".0f", 100.0) + " %") if r["label_acc"] is not None else "n/a",
                 _f(g.get("locomotion", {}).get("joint_err_cm"), ".2f"),
                 _f(g.get("gestures", {}).get("joint_err_cm"), ".2f"))  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
