#!/usr/bin/env python3
"""The accuracy table: `graphsvc evaluate --json` runs on Bandai-Namco dataset 2.

One graph a layout is built from the whole of dataset 2 (as `graphsvc build` builds
it); every row is an `evaluate --graph` run (`graphsvc.evaluate.run`, in this process)
whose hold-out protocol hides the test clips' sets:

- hold-out `takes`: the takes 001 and 004 of every content × style as tests (140 clips),
  each hiding every take of its content × style;
- hold-out `actor`: the normal and masculine styles' takes 001 and 004 (40 clips, one
  actor), each hiding every clip of that actor (docs/evaluation.md).

For each: layouts wrists-ankles and kelly6; inputs accelerometers alone (`--noise
default,position=0,heading=none`), + overhead positions (`default,heading=none`, weights
0.5,1,1), + positions and heading (`default`, weights 0.5,1,1: Kelly et al.'s, not
tuned here); every registered strategy that reads accelerometers on the same clips
(the optical-marker strategy has its own figures: tools/bench_ssg.py). Prints one JSON object a
run (its row, the equivalent `graphsvc evaluate` command and the figures — the `nearest`
rows with the pose-oracle floor, `evaluate --pose-oracle`: per frame the usable graph
pose closest to the truth, the bound of any strategy that retrieves poses —, the
locomotion and gesture means, what a viewer sees: jitter, foot skate and ground
penetration of the output and of the truth), then the table in Markdown, jitter and
skate as multiples of the truth's.

The builds and runs share this process: an evaluation JSON's `peak_rss_mb` is this
process's peak so far (a graph build's included), not one run's as `graphsvc evaluate`
reports it.

`--only clip` runs the clip hold-out (the test clip alone hidden) on the takes' tests.

`--preset real` runs the same rows as real devices are worn: the `real` sensor noise
(more white noise, the legs' soft tissue, foot-strike jolts, the devices' orientation
output with yaw drift and a common heading drift; docs/sensors.md) in place of `default`,
each device strapped on turned by up to 30° (`mount=30`), and a 2 s N-pose put before
every test clip; the devices are calibrated from the recording's first 10 s, the pose
fixing each sensor's tilt and the 8 s of motion after it the rotation about gravity
(`evaluate --calibrate-from-start 10 --pose npose`; the pose is not scored). `--calibration-pose tpose|stand` calibrates
from another pose; `--mount 0 --no-calibration` runs the rows with the layout's own
mounting. `--inputs acc-no-orientation` and `pos+heading-no-orientation` run its rows
with the orientations weighed 0.

Usage: tools/accuracy.py DATA [--jobs 2] [--work DIR] [--only takes|actor|clip] [--layouts L,...]
                         [--inputs acc,pos,pos+heading] [--strategies viterbi,nearest] [--preset real]
                         [--mount DEG] [--calibration-pose npose|tpose|stand] [--no-calibration] [--reuse]
DATA: the Bandai-Namco folder (../shared/data/bandai).
"""

from __future__ import annotations

import argparse
import json
import shlex
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
INPUTS = {  # what the recordings carry: (row text, --noise, --weights or None for the default)
    "acc": ("accelerometers", "default,position=0,heading=none", None),
    "pos": ("+ overhead positions", "default,heading=none", "0.5,1,1"),
    "pos+heading": ("+ positions and heading", "default", "0.5,1,1"),
}
# Rows asked for by name only (`--inputs`): the same inputs with the devices' orientations
# weighed 0, the baseline a `real` preset's orientation rows are compared with.
EXTRA_INPUTS = {
    "acc-no-orientation": ("accelerometers, orientations weighed 0", "default,position=0,heading=none", "1,1,1,0"),
    "pos+heading-no-orientation": ("+ positions and heading, orientations weighed 0", "default", "0.5,1,1,0"),
}


def build(kb: Path, layout: str, jobs: int, out: Path) -> None:
    """`graphsvc build KB --layout LAYOUT --jobs JOBS --quiet -o OUT`."""
    from graphsvc.graph.build import BuildOptions, build_graph, load_knowledge_base
    from graphsvc.graph.file import save_graph
    from graphsvc.sensors.layout import load_layout

    motions = load_knowledge_base([str(kb)], jobs=jobs, progress=False)
    graph, _ = build_graph(motions, BuildOptions(layout=load_layout(layout), jobs=jobs, progress=False))
    save_graph(graph, out)


def evaluate(config, command: str) -> None:
    """`graphsvc.evaluate.run` of `config` (the same run as `command`); SystemExit naming
    the command for an error."""
    from graphsvc.errors import GraphsvcError
    from graphsvc.evaluate.run import run

    try:
        run(config)
    except (GraphsvcError, OSError) as exc:
        raise SystemExit(f"failed: {command}\n{exc}") from None


def main() -> None:
    from graphsvc.errors import GraphsvcError
    from graphsvc.evaluate.run import EvalConfig
    from graphsvc.strategies import available, get
    from graphsvc.strategies.options import Options, parse_weights

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="the Bandai-Namco folder (with dataset-2/data)")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--work", help="folder for the graphs and JSON runs (default: a temporary one)")
    parser.add_argument("--only", choices=sorted(PROTOCOLS))
    parser.add_argument("--layouts", default="wrists-ankles,kelly6")
    parser.add_argument("--inputs", default=",".join(INPUTS))
    # every strategy but those reading markers (ssg: tools/bench_ssg.py); an installed plug-in too
    # (`pip install -e examples/strategy-plugin` adds meanpose, the mean pose: a floor)
    accelerometer_strategies = [n for n in available() if "markers" not in get(n).needs]
    parser.add_argument("--strategies", default=",".join(accelerometer_strategies))
    parser.add_argument(
        "--preset",
        default="default",
        help="the sensors' noise preset (default; real: tools/fit_real_noise.py's devices)",
    )
    parser.add_argument(
        "--mount",
        type=float,
        default=30.0,
        help="with --preset real: each device turned by up to this many degrees (default 30)",
    )
    parser.add_argument(
        "--calibration-pose",
        default="npose",
        choices=("npose", "tpose", "stand"),
        help="with --preset real: the pose put before each clip and calibrated from (default npose)",
    )
    parser.add_argument(
        "--no-calibration",
        action="store_true",
        help="with --preset real: no calibration pose, the recordings read as simulated",
    )
    parser.add_argument(
        "--reuse",
        action="store_true",
        help="keep a run already in --work that the same command wrote (after a change that cannot"
        " move it, e.g. one to how positions are used, for the accelerometer-only rows)",
    )
    args = parser.parse_args()
    unknown = set(args.inputs.split(",")) - set(INPUTS) - set(EXTRA_INPUTS)
    if unknown:
        raise SystemExit(
            f"unknown --inputs {', '.join(sorted(unknown))} (known: {', '.join([*INPUTS, *EXTRA_INPUTS])})"
        )
    kb = Path(args.data) / "dataset-2" / "data"
    if not kb.is_dir():
        raise SystemExit(f"{kb} not found (give the Bandai-Namco folder)")
    work = Path(args.work or tempfile.mkdtemp(prefix="graphsvc-accuracy-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for layout in args.layouts.split(","):
        graph = work / f"dataset-2.{layout}.graph"
        if not graph.exists():
            try:
                build(kb, layout, args.jobs, graph)
            except GraphsvcError as exc:
                raise SystemExit(f"failed: building {graph}\n{exc}") from None
        for protocol in [args.only] if args.only else DEFAULT_PROTOCOLS:
            for key in args.inputs.split(","):
                what, noise, weights = {**INPUTS, **EXTRA_INPUTS}[key]
                noise = noise.replace("default", args.preset, 1)
                calibrate = None
                if args.preset == "real":
                    noise += f",mount={args.mount:g}" if args.mount else ""
                    calibrate = None if args.no_calibration else 10.0
                for strategy in args.strategies.split(","):
                    tag = "" if args.preset == "default" else f".{args.preset}"
                    if args.preset == "real":
                        tag += f".mount{args.mount:g}" + ("" if calibrate is None else f".{args.calibration_pose}")
                    out = work / f"{protocol}.{layout}.{key}.{strategy}{tag}.json"
                    config = EvalConfig(
                        kb=(str(kb),),
                        graph=str(graph),
                        test=PROTOCOLS[protocol],
                        hold_out=protocol,
                        noise=noise,
                        options=Options(strategy=strategy, weights=parse_weights(weights or "1,1,1")),
                        jobs=args.jobs,
                        json=str(out),
                        pose_oracle=strategy == "nearest",
                        calibrate_from_start=calibrate,
                        calibration_pose=args.calibration_pose,
                        progress=False,
                    )
                    command = shlex.join(
                        [
                            "graphsvc",
                            "evaluate",
                            str(kb),
                            "--graph",
                            str(graph),
                            "--test",
                            PROTOCOLS[protocol],
                            "--hold-out",
                            protocol,
                            "--noise",
                            noise,
                            *(["--weights", weights] if weights else []),
                            "--strategy",
                            strategy,
                            "--jobs",
                            str(args.jobs),
                            "--json",
                            str(out),
                            "--quiet",
                            *(["--pose-oracle"] if strategy == "nearest" else []),
                            *(
                                ["--calibrate-from-start", f"{calibrate:g}", "--pose", args.calibration_pose]
                                if calibrate
                                else []
                            ),
                        ]
                    )
                    t0 = time.perf_counter()
                    stamp = out.with_suffix(".cmd")  # the command that wrote `out`
                    if not (args.reuse and out.exists() and stamp.exists() and stamp.read_text() == command):
                        evaluate(config, command)
                        stamp.write_text(command)
                    result = json.loads(out.read_text())
                    m, groups = result["mean"], result.get("groups", {})
                    row = {
                        "hold_out": protocol,
                        "layout": layout,
                        "inputs": what,
                        "strategy": strategy,
                        "noise": args.preset,
                        "clips": m["clips"],
                        "frames": m["frames"],
                        "joint_err_cm": m["joint_err_cm"],
                        "root_err_cm": m["root_err_cm"],
                        "heading_err_deg": m["heading_err_deg"],
                        "label_acc": m["label_acc"],
                        "samples_per_s": m.get("samples_per_s"),
                        "oracle_joint_err_cm": m.get("oracle_joint_err_cm"),
                        "calibration_error_deg": m.get("calibration_error_deg"),
                        **{
                            k: m.get(k)
                            for k in (
                                "jitter_km_s3",
                                "skate_cm_s",
                                "penetration_cm",
                                "truth_jitter_km_s3",
                                "truth_skate_cm_s",
                                "truth_penetration_cm",
                            )
                        },
                        "groups": {
                            g: {k: v[k] for k in ("clips", "joint_err_cm", "root_err_cm", "label_acc")}
                            for g, v in groups.items()
                        },
                        "seconds": round(time.perf_counter() - t0, 1),
                        "command": command,
                    }
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    print()
    print(table(rows))


def _f(x, spec, scale=1.0):
    return "—" if x is None else format(x * scale, spec)


def _ratio(r: dict, key: str):
    value, truth = r.get(key), r.get(f"truth_{key}")
    return None if value is None or not truth else value / truth


def table(rows: list[dict]) -> str:
    head = (
        "hold-out",
        "layout",
        "inputs",
        "strategy",
        "clips",
        "joint cm",
        "oracle cm",
        "root cm",
        "heading °",
        "label",
        "jitter ×truth",
        "skate ×truth",
        "locomotion joint cm",
        "gestures joint cm",
    )
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in rows:
        g = r["groups"]
        cells = (
            r["hold_out"],
            f"`{r['layout']}`",
            r["inputs"],
            f"`{r['strategy']}`",
            str(r["clips"]),
            _f(r["joint_err_cm"], ".2f"),
            _f(r.get("oracle_joint_err_cm"), ".2f"),
            _f(r["root_err_cm"], ".1f"),
            _f(r["heading_err_deg"], ".1f"),
            (_f(r["label_acc"], ".0f", 100.0) + " %") if r["label_acc"] is not None else "n/a",
            _f(_ratio(r, "jitter_km_s3"), ".1f") + "×",
            _f(_ratio(r, "skate_cm_s"), ".2f") + "×",
            _f(g.get("locomotion", {}).get("joint_err_cm"), ".2f"),
            _f(g.get("gestures", {}).get("joint_err_cm"), ".2f"),
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
