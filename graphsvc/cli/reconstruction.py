"""Reconstruction commands: `synthesize`, `calibrate`, `demo`."""

from __future__ import annotations

import sys
from pathlib import Path

from graphsvc.cli.args import command, file_arg, print_notes
from graphsvc.fileio import check_outputs
from graphsvc.flags import (
    LAYOUT_HELP,
    PATH,
    SEED,
    add_input_file_flags,
    add_performer_flags,
    add_pose_flag,
    add_synthesize_flags,
    calibration_choice,
    options_from_flags,
    performer_from_flags,
    ranged,
    synthesize_inputs,
)


def _cmd_synthesize(args) -> int:
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.output import MOTION_OUTPUT_SUFFIXES
    from graphsvc.pipeline import synthesize_files

    out = Path(args.output)
    check_outputs([("-o", out, MOTION_OUTPUT_SUFFIXES), ("--report", args.report, (".json",))], synthesize_inputs(args))
    calibration, start_s, pose = calibration_choice(args)
    options, notes = options_from_flags(args)
    graph = load_graph(args.graph)
    performer = performer_from_flags(args, graph.skeleton, graph.params.get("mapping"))
    try:
        result = synthesize_files(
            graph,
            args.graph,
            args.recording,
            out,
            options,
            report_path=args.report,
            scale=args.scale,
            up=args.up,
            units=args.units,
            device_map=args.device_map,
            calibration=calibration,
            calibrate_from_start=None if start_s is None else (start_s, pose),
            notes=notes,
            performer=performer,
        )
    finally:  # (a note may say why the recording did not fit)
        print_notes(notes)
    r = result.report
    labels = " → ".join(f"{run['label']} {_seconds(run['frames'] / graph.rate_hz)}" for run in r["labels"][:12])
    more = f" … (+{len(r['labels']) - 12})" if len(r["labels"]) > 12 else ""
    print(
        f"wrote {out}: {result.motion.num_frames} frames at {graph.rate_hz:g} Hz from {r['samples']} samples"
        + (f" (resampled from {r['input_rate_hz']:g} Hz)" if r["resampled"] else "")
        + (f", on a performer {r['performer']['height_m']:.2f} m tall" if "performer" in r else "")
    )
    print(f"path: {labels}{more}")
    print(
        f"warm-up {r['timings_s']['warm_up']:.2f} s, search {r['timings_s']['search']:.2f} s "
        f"({r['samples_per_s']:,.0f} samples/s), "
        f"synthesis {r['timings_s']['synthesis']:.2f} s"
        + (f", compression {r['compression']:g}:1" if "compression" in r else "")
        + (f", {r['revisions']} revisions at lag {r['lag_samples']} samples" if "revisions" in r else "")
        + (
            f"; ignored: {', '.join(r.get('ignored_inputs', []) + r.get('ignored_options', []))}"
            if r.get("ignored_inputs") or r.get("ignored_options")
            else ""
        )
    )
    return 0


def _cmd_calibrate(args) -> int:
    from graphsvc.errors import CalibrationQualityError
    from graphsvc.graph.calibration import calibrate
    from graphsvc.sensors.calibration import mounting_angle_deg, save_calibration
    from graphsvc.sensors.files import read_recording

    out = Path(args.output)
    check_outputs(
        [("-o", out, (".json",))],
        [("the recording", args.recording), ("the graph", args.graph), ("the device map", file_arg(args.device_map))],
    )
    graph = None
    if args.graph:
        from graphsvc.graph.file import load_graph

        graph = load_graph(args.graph)
    rec = read_recording(args.recording, up=args.up, units=args.units)
    if args.device_map:
        from graphsvc.sensors.devices import apply_device_map, device_map

        layout_name = (graph.layout if graph is not None else rec.layout or {}).get("name")
        rec = apply_device_map(
            rec,
            device_map(args.device_map, layout_name, rec.sensor_names),
            order=graph.sensor_names if graph is not None else None,
        )
    warning = None
    try:
        cal = calibrate(rec, args.pose, graph, args.start, args.end)
    except CalibrationQualityError as exc:
        if not args.force:
            raise CalibrationQualityError(f"{exc} (--force writes it anyway)", exc.calibration) from None
        cal, warning = exc.calibration, str(exc)
    cal["source"] = str(Path(args.recording))
    save_calibration(cal, out)
    a, b = cal["rest_s"]
    print(
        f"wrote {out}: {len(cal['sensors'])} sensors, pose {args.pose}, rest {a:.2f}–{b:.2f} s, "
        f"{cal['matched_samples']} matched samples"
    )
    for name, item in cal["sensors"].items():
        print(
            f"  {name}: mounting {mounting_angle_deg(item):.1f}° ({item['method']}), residual {item['residual_deg']:.1f}°"
        )
    if warning:
        print(f"graphsvc: warning: {warning}", file=sys.stderr)
    return 0


def _cmd_demo(args) -> int:
    from graphsvc.demo import format_demo_summary, run_demo
    from graphsvc.errors import InputError

    if args.kb == "pybullet" and args.minutes is not None:
        raise InputError("--minutes sets the procedural knowledge base's length; --kb pybullet has its own clips")
    if args.kb != "pybullet" and args.held_out is not None:
        raise InputError("--held-out names a pybullet clip: it applies to --kb pybullet")
    summary = run_demo(
        Path(args.output),
        seed=args.seed,
        layout_name=args.layout,
        minutes=3.0 if args.minutes is None else args.minutes,
        kb_name=args.kb,
        **({} if args.held_out is None else {"held_out": args.held_out}),
    )
    print(format_demo_summary(summary))
    return 0


def _seconds(s: float) -> str:
    """A run's length as the path summary prints it: 0.1 s steps, and a run shorter than
    that (a frame or two) in hundredths, never as 0.0 s."""
    return f"{s:.1f} s" if s >= 0.095 else f"{s:.2f} s"


def add_synthesize(sub) -> None:
    p = command(
        sub,
        "synthesize",
        "reconstruct motion from a recording by searching a graph",
        "Reconstruct full-body motion from a recording (accelerometers, tracker, orientations, annotations "
        "or optical markers) with a strategy over a graph, and write it as BVH or glTF (and a report).",
    )
    p.add_argument("graph", metavar="GRAPH", type=PATH, help="a graph file (`graphsvc build`)")
    p.add_argument(
        "recording", metavar="REC", type=PATH, help="recording: .rec, device CSV, Xsens MVNX, C3D or marker CSV"
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT.bvh",
        type=PATH,
        help="the motion to write: .bvh (--scale units a metre), or .glb / .gltf (a skinned skeleton "
        "with its animation, metres); not an input",
    )
    add_synthesize_flags(p)
    add_performer_flags(p)
    p.add_argument(
        "--report",
        metavar="OUT.json",
        type=PATH,
        help="also write a JSON report: node path, labels, per-term costs, compression, timings",
    )
    p.set_defaults(run=_cmd_synthesize)


def add_calibrate(sub) -> None:
    p = command(
        sub,
        "calibrate",
        "estimate each sensor's mounting rotation from a calibration take",
        "Estimate each device's mounting rotation onto the layout's sensor frame from a take that holds a "
        "known pose, then moves; `--calibration CAL.json` elsewhere applies it.",
    )
    p.add_argument("recording", metavar="REC", type=PATH, help="device recording: stands still in the pose, then moves")
    p.add_argument(
        "--graph",
        metavar="GRAPH",
        type=PATH,
        help="a graph whose readings of similar motion fix the rotation about gravity (default: none, the "
        "rotation about gravity stays unknown)",
    )
    add_pose_flag(p, required=True)
    p.add_argument(
        "--from", dest="start", type=float, metavar="S", help="use the recording from S seconds (default: its start)"
    )
    p.add_argument(
        "--to", dest="end", type=float, metavar="S", help="use the recording up to S seconds (default: its end)"
    )
    add_input_file_flags(p)
    p.add_argument(
        "--force",
        action="store_true",
        help="write the calibration even when it names sensors not to be trusted (a residual over 25°, moved "
        "during the pose, gravity from acceleration and orientation over 10° apart), with a warning "
        "(default: refuse, exit 2)",
    )
    p.add_argument(
        "-o", "--output", required=True, metavar="CAL.json", type=PATH, help="the calibration to write (.json)"
    )
    p.set_defaults(run=_cmd_calibrate)


def add_demo(sub) -> None:
    p = command(
        sub,
        "demo",
        "run the demo on a procedural knowledge base or pybullet's clips",
        "Generate a procedural knowledge base and a held-out performance (or take pybullet's sample clips but "
        "one, --kb pybullet), simulate the performance's sensors, build the graph, reconstruct the "
        "performance and print the error, speed and path; writes the files, plots and report.html into a "
        "folder.",
    )
    p.add_argument(
        "-o",
        "--output",
        default="graphsvc-demo",
        metavar="DIR",
        type=PATH,
        help="the folder to write (default graphsvc-demo)",
    )
    p.add_argument("--seed", type=SEED, default=0, help="the knowledge base's and the noise's seed (default 0)")
    p.add_argument(
        "--layout", default="kelly6", metavar="LAYOUT", help=f"sensor layout: {LAYOUT_HELP} (default kelly6)"
    )
    p.add_argument(
        "--minutes",
        type=ranged(float, 0.0, 600.0, low_open=True),
        default=None,
        help="procedural knowledge-base length in minutes (default 3, at most 600)",
    )
    p.add_argument(
        "--kb",
        choices=("procedural", "pybullet"),
        default="procedural",
        help="the knowledge base: generated (procedural, the default) or the DeepMimic clips that install "
        "with pybullet (pip install 'graphsvc[samples]'), one held out",
    )
    p.add_argument(
        "--held-out",
        metavar="CLIP",
        help="with --kb pybullet: the clip to hold out and reconstruct, as `graphsvc samples` names it "
        "(default turn_left_1)",
    )
    p.set_defaults(run=_cmd_demo)
