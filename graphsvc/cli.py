"""The `graphsvc` command: parse arguments, call the library, print what it did.

Errors a user can cause (GraphsvcError, unreadable or unwritable paths) print one
line on stderr and exit 2 with nothing written; --debug shows the traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from graphsvc.flags import (COUNT, PATH, RATE_HZ, SEED, Parser, add_input_file_flags, add_marker_flags,
                            add_search_flags, add_synthesize_flags, options_from_flags, os_message, ranged,
                            synthesize_inputs)  # fmt: skip
from graphsvc.fileio import check_outputs
from graphsvc.errors import GraphsvcError

DESCRIPTION = ("graphsvc reconstructs full-body human motion from sparse measurements — body-worn accelerometers, an "
               "overhead tracker's position and heading, annotations, or a few optical markers — by searching motion "
               "capture: build a motion graph of a knowledge base of clips, then synthesize motion from a recording, "
               "in batch, or live through the gRPC service.")


def _cmd_inspect(args) -> int:
    from graphsvc.describe import describe_paths, format_description

    info = describe_paths(args.paths, progress=False if args.json else None)
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True))
    else:
        print(format_description(info))
    return 0


def _cmd_simulate(args) -> int:
    from graphsvc.errors import InputError
    from graphsvc.motion.library import load_motion
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.recording import export_csv, save_recording

    noise = parse_noise(args.noise)
    if args.position_noise is not None:
        from dataclasses import replace

        noise = replace(noise, position=args.position_noise)
    if (args.layout is None) == (args.markers is None):
        raise InputError("give --layout (accelerometers) or --markers (optical markers), one of them")
    if args.markers is None and (args.keep or args.gaps or args.flicker or args.gap_fraction):
        raise InputError("--keep, --gaps, --flicker and --gap-fraction apply to --markers")
    out = Path(args.output)
    check_outputs([("-o", out, None)], [("the clip", args.clip), ("the joint map", _file_arg(args.mapping)),
                                        ("the marker set", args.markers)])  # fmt: skip
    if out.suffix.lower() not in (".rec", ".csv"):  # what `inspect` and `synthesize` read back by the suffix
        raise InputError(f"{out}: simulate writes .rec (binary) or .csv, not {out.suffix or 'a file without a suffix'}")
    if args.markers is not None:
        from graphsvc.sensors.markers import keep_markers, load_marker_set, parse_names
        from graphsvc.sensors.optical import export_marker_csv
        from graphsvc.sensors.simulate import MarkerPattern, check_pattern, parse_gaps, simulate_marker_recording

        pattern = MarkerPattern(parse_gaps(args.gaps), args.flicker or 0.0, args.gap_fraction or 0.0)
        check_pattern(pattern)
        marker_set = keep_markers(load_marker_set(args.markers), parse_names(args.keep))
        motion = load_motion(args.clip)
        rec = simulate_marker_recording(motion, marker_set, noise, seed=args.seed, rate_hz=args.rate,
                                        mapping=args.mapping, pattern=pattern)  # fmt: skip
        (export_marker_csv if out.suffix.lower() == ".csv" else save_recording)(rec, out)
        print(f"wrote {out}: {rec.num_samples} samples of {len(rec.marker_names)} markers "
              f"({', '.join(rec.marker_names)}) at {rec.rate_hz:g} Hz, seen {100 * rec.meta['seen']:.0f} %, "
              f"marker noise {noise.marker:g} mm")  # fmt: skip
        return 0
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.simulate import simulate_recording

    layout = load_layout(args.layout)
    motion = load_motion(args.clip)
    rec = simulate_recording(motion, layout, noise, seed=args.seed, rate_hz=args.rate, mapping=args.mapping)
    if out.suffix.lower() == ".csv":
        export_csv(rec, out)
    else:
        save_recording(rec, out)
    print(
        f"wrote {out}: {rec.num_samples} samples of {rec.num_sensors} sensors "
        f"({', '.join(rec.sensor_names)}) at {rec.rate_hz:g} Hz, noise {args.noise}"
    )
    return 0


def _cmd_mapping(args) -> int:
    from graphsvc.fileio import write_text_atomic
    from graphsvc.motion.joints import OPTIONAL, guess_mapping
    from graphsvc.motion.library import load_motion

    check_outputs([("-o", args.output, (".json",))], [("the clip", args.clip)])
    motion = load_motion(args.clip)
    mapping, missing = guess_mapping(motion.skeleton)
    text = json.dumps(mapping, indent=1) + "\n"
    if args.output:
        write_text_atomic(args.output, text)
    else:
        print(text, end="")
    required = [c for c in missing if c not in OPTIONAL]
    note = (f"not found: {', '.join(missing)}" + (" — required: map them by hand" if required else
                                                  " (a skeleton may lack these)")) if missing else "every canonical joint found"  # fmt: skip
    print(f"{motion.skeleton.num_joints_excluding_end_sites} joints; {note}" + (f"; wrote {args.output}" if args.output else ""),
          file=sys.stderr)
    return 0 if not required else 2


def _cmd_demo(args) -> int:
    from graphsvc.demo import format_demo_summary, run_demo

    summary = run_demo(Path(args.output), seed=args.seed, layout_name=args.layout, minutes=args.minutes)
    print(format_demo_summary(summary))
    return 0


def _cmd_build(args) -> int:
    from graphsvc.graph.build import BuildOptions, build_graph, load_knowledge_base
    from graphsvc.graph.connectivity import connectivity, format_connectivity
    from graphsvc.graph.file import save_graph
    from graphsvc.graph.model import format_summary, summary
    from graphsvc.motion.joints import load_mapping_file
    from graphsvc.sensors.layout import load_layout

    out = Path(args.output)
    check_outputs([("-o", out, None)], [("a knowledge-base file", k) for k in args.kb] +
                  [("the joint map", _file_arg(args.mapping))])  # fmt: skip
    progress = False if args.quiet else None
    augment = tuple(a for a in (args.augment or "").split(",") if a)
    mapping = load_mapping_file(args.mapping) if args.mapping and args.mapping != "guess" else None
    options = BuildOptions(rate_hz=args.rate, layout=load_layout(args.layout), msv=not args.no_msv,
                           interp=not args.no_interp, bridges=not args.no_bridges, augment=augment, mapping=mapping,
                           jobs=args.jobs, progress=progress)  # fmt: skip
    t0 = time.perf_counter()
    motions = load_knowledge_base(args.kb, exclude=args.exclude or [], augment=augment, jobs=args.jobs, progress=progress)
    load_s = time.perf_counter() - t0
    if args.mapping == "guess" and motions:  # (one topology a knowledge base: its first clip's names)
        from dataclasses import replace

        from graphsvc.motion.joints import guess_mapping

        mapping, missing = guess_mapping(motions[0].skeleton)
        options = replace(options, mapping=mapping)
        print(f"guessed joint map: {json.dumps(mapping)}" + (f" (missing: {', '.join(missing)})" if missing else ""))
    graph, report = build_graph(motions, options)
    t0 = time.perf_counter()
    save_graph(graph, out)
    timings = {"load_s": load_s, **report.timings, "write_s": time.perf_counter() - t0}
    print(f"wrote {out}")
    print(format_summary(summary(graph, out.stat().st_size)))
    t0 = time.perf_counter()
    print(format_connectivity(connectivity(graph)))
    timings["connectivity_s"] = time.perf_counter() - t0
    if report.still_clips:
        print(f"{len(report.still_clips)} clips without foot-contact changes get transition candidates every "
              f"{options.still_clip_step_s:g} s")  # fmt: skip
    print("times: " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in timings.items()) + f" (total {sum(timings.values()):.2f} s)")
    return 0


def _cmd_info(args) -> int:
    from graphsvc.graph.connectivity import connectivity, format_connectivity
    from graphsvc.graph.file import load_graph
    from graphsvc.graph.model import format_summary, summary

    graph = load_graph(args.graph)
    info = summary(graph, Path(args.graph).stat().st_size)
    info["params"] = graph.params
    info["connectivity"] = connectivity(graph)
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True))
    else:
        print(format_summary(info))
        print(format_connectivity(info["connectivity"]))
    return 0


def _cmd_relayout(args) -> int:
    from dataclasses import replace

    from graphsvc.graph.file import load_graph, save_graph
    from graphsvc.graph.metadata import edge_up_vectors, recompute_accelerations
    from graphsvc.sensors.anatomy import ANATOMICAL
    from graphsvc.sensors.layout import load_layout

    out = Path(args.output)
    check_outputs([("-o", out, None)], [("the graph", args.graph), ("the layout file", args.layout)])
    layout = load_layout(args.layout)
    graph = load_graph(args.graph)
    acc = recompute_accelerations(graph, layout)
    params = {**graph.params, "layout": layout.name, "sensor_frames": ANATOMICAL}  # (an older graph's converted)
    save_graph(replace(graph, edge_acc=acc, edge_up=edge_up_vectors(graph, layout), layout=layout.to_dict(),
                       params=params), out)  # fmt: skip
    print(f"wrote {out}: edge metadata for layout {layout.name} ({', '.join(layout.sensor_names)})")
    return 0


def _cmd_synthesize(args) -> int:
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.library import MOTION_OUTPUT_SUFFIXES
    from graphsvc.pipeline import synthesize_files

    out = Path(args.output)
    check_outputs([("-o", out, MOTION_OUTPUT_SUFFIXES), ("--report", args.report, (".json",))],
                  synthesize_inputs(args))  # fmt: skip
    options, notes = options_from_flags(args)
    graph = load_graph(args.graph)
    result = synthesize_files(graph, args.graph, args.recording, out, options, report_path=args.report, scale=args.scale,
                              up=args.up, units=args.units, device_map=args.device_map, calibration=args.calibration, notes=notes)  # fmt: skip
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    r = result.report
    labels = " → ".join(f"{run['label']} {_seconds(run['frames'] / graph.rate_hz)}" for run in r["labels"][:12])
    more = f" … (+{len(r['labels']) - 12})" if len(r["labels"]) > 12 else ""
    print(f"wrote {out}: {result.motion.num_frames} frames at {graph.rate_hz:g} Hz from {r['samples']} samples"
          + (f" (resampled from {r['input_rate_hz']:g} Hz)" if r["resampled"] else ""))  # fmt: skip
    print(f"path: {labels}{more}")
    print(f"warm-up {r['timings_s']['warm_up']:.2f} s, search {r['timings_s']['search']:.2f} s "
          f"({r['samples_per_s']:,.0f} samples/s), "
          f"synthesis {r['timings_s']['synthesis']:.2f} s"
          + (f", compression {r['compression']:g}:1" if "compression" in r else "")
          + (f", {r['revisions']} revisions at lag {r['lag_samples']} samples" if "revisions" in r else "")
          + (f"; ignored: {', '.join(r.get('ignored_inputs', []) + r.get('ignored_options', []))}"
             if r.get("ignored_inputs") or r.get("ignored_options") else ""))  # fmt: skip
    return 0


def _cmd_calibrate(args) -> int:
    from graphsvc.graph.calibration import calibrate
    from graphsvc.sensors.calibration import save_calibration
    from graphsvc.sensors.files import read_recording

    out = Path(args.output)
    check_outputs([("-o", out, (".json",))], [("the recording", args.recording), ("the graph", args.graph),
                                              ("the device map", _file_arg(args.device_map))])  # fmt: skip
    graph = None
    if args.graph:
        from graphsvc.graph.file import load_graph

        graph = load_graph(args.graph)
    rec = read_recording(args.recording, up=args.up, units=args.units)
    if args.device_map:
        from graphsvc.sensors.devices import apply_device_map, device_map

        layout_name = (graph.layout if graph is not None else rec.layout or {}).get("name")
        rec = apply_device_map(rec, device_map(args.device_map, layout_name),
                               order=graph.sensor_names if graph is not None else None)  # fmt: skip
    cal = calibrate(rec, args.pose, graph, args.start, args.end)
    cal["source"] = str(Path(args.recording))
    save_calibration(cal, out)
    a, b = cal["rest_s"]
    print(f"wrote {out}: {len(cal['sensors'])} sensors, pose {args.pose}, rest {a:.2f}–{b:.2f} s, "
          f"{cal['matched_samples']} matched samples")  # fmt: skip
    for name, item in cal["sensors"].items():
        angle = 2.0 * math.degrees(math.acos(min(1.0, abs(item["rotation_wxyz"][0]))))
        print(f"  {name}: mounting {angle:.1f}° ({item['method']}), residual {item['residual_deg']:.1f}°")
    return 0


def _cmd_batch(args) -> int:
    from graphsvc.batch.run import format_summary, run_batch
    from graphsvc.service.server import parse_graph_spec

    graphs = dict(parse_graph_spec(spec) for spec in args.graph or [])
    summary = run_batch(args.manifest, args.out, graphs=graphs, scheduler=args.scheduler, workers=args.workers,
                        retries=args.retries, progress=False if args.quiet else None, timeout_s=args.timeout)  # fmt: skip
    print(format_summary(summary))
    print(f"summary: {Path(args.out) / 'summary.json'}")
    failed = summary["totals"]["failed"]
    if failed:
        print(f"graphsvc: {failed} of {summary['totals']['items']} items failed", file=sys.stderr)
        return 1
    return 0


def _cmd_evaluate(args) -> int:
    from graphsvc.evaluate.run import EvalConfig, run, summary_lines
    from graphsvc.strategies import check_options

    options, notes = options_from_flags(args)
    options = check_options(options)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    config = EvalConfig(kb=tuple(args.kb), test=args.test, graph=args.graph, layout=args.layout, augment=args.augment,
                        noise=args.noise, position_noise=args.position_noise, options=options, seed=args.seed,
                        jobs=args.jobs, mixed=args.mixed, hold_out=args.hold_out, actors=args.actors,
                        mapping=args.mapping, flicker=args.flicker, gap_fraction=args.gap_fraction, json=args.json,
                        keep_motions=args.keep_motions, report_html=args.report_html,
                        progress=False if args.quiet else None)  # fmt: skip
    summary = run(config, note=lambda text: print(f"note: {text}", file=sys.stderr), write_page=_write_page)
    for line in summary_lines(summary, config):
        print(line)
    return 0


def _write_page(path, summary: dict, folder: Path) -> None:
    """The page of an evaluation whose clips are kept in `folder`."""
    from graphsvc.report.html import write_html
    from graphsvc.report.load import evaluation_document

    write_html(path, evaluation_document(summary, folder))


def _cmd_report(args) -> int:
    from graphsvc.report.html import write_html
    from graphsvc.report.load import load_document

    out = Path(args.output)
    check_outputs([("-o", out, (".html", ".htm"))], [("the result", args.result), ("the truth", args.truth)])
    doc = load_document(args.result, truth=args.truth)
    write_html(out, doc)
    print(f"wrote {out}: {len(doc['clips'])} clip{'s' if len(doc['clips']) != 1 else ''}, "
          f"{out.stat().st_size / 1e6:.1f} MB")
    return 0


def _seconds(s: float) -> str:
    """A run's length as the path summary prints it: 0.1 s steps, and a run shorter than
    that (a frame or two) in hundredths, never as 0.0 s."""
    return f"{s:.1f} s" if s >= 0.095 else f"{s:.2f} s"


def _file_arg(value: str | None) -> str | None:
    """An argument that is a file or a built-in name (`--mapping guess`, `--device-map
    xsens`): the file, or None for a name."""
    return None if value in (None, "guess", "xsens") else value


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="graphsvc", description=DESCRIPTION,
                    epilog="Run `graphsvc COMMAND --help` for a command's arguments; the README and docs/ for more.")  # fmt: skip
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error instead of one line")
    parser.add_argument("--version", action="version", version=_version(), help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser, metavar="COMMAND")

    def command(name: str, summary: str, description: str | None = None):
        return sub.add_parser(name, help=summary, description=description or summary[0].upper() + summary[1:] + ".")

    p = command("inspect", "describe motion files, folders and recordings",
                "Describe motion files and folders (searched recursively: per clip frames, rate, joints, duration, "
                "labels; per-folder and overall totals) or recordings (samples, sensors, channels).")  # fmt: skip
    p.add_argument("paths", nargs="+", metavar="PATH", type=PATH,
                   help="a motion file (.bvh, .amc), a folder of them, or a recording (.rec, .csv, .mvnx, .c3d)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(run=_cmd_inspect)

    p = command("simulate", "simulate sensor readings or optical markers of a clip into a recording",
                "Simulate the readings a layout's accelerometers (--layout) or a marker set's optical markers "
                "(--markers) would give for a motion clip, with noise, and write them as a recording.")  # fmt: skip
    p.add_argument("clip", metavar="CLIP", type=PATH, help="the motion file (.bvh, .amc) to simulate")
    p.add_argument("--layout", help="accelerometers: preset (wrists-ankles, kelly6, right-wrist) or layout file")
    add_marker_flags(p)
    p.add_argument("--gaps", metavar="START:LEN,...", help="markers: every marker unseen over these frames of the clip")
    p.add_argument("--flicker", type=float, metavar="P",
                   help="markers: each marker unseen this share of samples, in short dropouts (3 samples on average; "
                        "default 0)")  # fmt: skip
    p.add_argument("--gap-fraction", type=float, metavar="F",
                   help="markers: random gaps of 5–80 samples until this share of samples is in one (default 0)")
    p.add_argument("--noise", default="none", metavar="NOISE",
                   help="PRESET[,key=value...] (presets: none, default, tracker, harsh, real; default none)")
    p.add_argument("--position-noise", type=ranged(float, 0.0, 1e3), metavar="M",
                   help="overhead-tracker noise σ in metres (default: the noise preset's)")
    p.add_argument("--seed", type=SEED, default=0, help="noise seed (default 0)")
    p.add_argument("--rate", type=RATE_HZ, metavar="HZ", help="resample to this rate first (default: the clip's)")
    p.add_argument("--mapping", metavar="FILE|guess", type=PATH,
                   help="joint map JSON for a skeleton graphsvc does not know, or 'guess' (`graphsvc mapping`)")
    p.add_argument("-o", "--output", required=True, metavar="OUT.rec", type=PATH,
                   help="the recording to write: .rec, or .csv (a device CSV, or a marker CSV with --markers)")
    p.set_defaults(run=_cmd_simulate)

    p = command("build", "build a motion graph from a knowledge base",
                "Build the motion graph of a knowledge base of motion clips: transitions at foot contacts, speed "
                "variations, interpolated nodes, bridges between actions, and each edge's sensor readings for a "
                "layout.")  # fmt: skip
    p.add_argument("kb", nargs="+", metavar="KB", type=PATH, help="motion files, folders or globs (.bvh, .amc)")
    p.add_argument("-o", "--output", required=True, metavar="GRAPH", type=PATH, help="the graph file to write")
    p.add_argument("--rate", type=RATE_HZ, default=30.0, metavar="HZ", help="graph rate (default 30)")
    p.add_argument("--layout", default="wrists-ankles", metavar="LAYOUT",
                   help="sensor layout of the edge metadata: preset (wrists-ankles, kelly6, right-wrist) or layout "
                        "file (default wrists-ankles)")  # fmt: skip
    p.add_argument("--no-msv", action="store_true", help="no slow-down nodes or speed-up edges")
    p.add_argument("--no-interp", action="store_true", help="no interpolation nodes")
    p.add_argument("--no-bridges", action="store_true", help="no bridges between actions (blended transitions)")
    p.add_argument("--exclude", action="append", metavar="GLOB", help="leave out matching files (repeatable)")
    p.add_argument("--augment", metavar="KINDS", help="add copies: mirror, reverse (comma-separated; default none)")
    p.add_argument("--mapping", metavar="FILE|guess", type=PATH,
                   help="joint map JSON for skeletons graphsvc does not know, or 'guess' (`graphsvc mapping`)")
    p.add_argument("--jobs", type=COUNT, default=1, metavar="N", help="threads for loading and preparing clips (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_cmd_build)

    p = command("info", "describe a graph file",
                "Describe a graph file: nodes and edges by kind, labels, layout, build parameters, connectivity.")
    p.add_argument("graph", metavar="GRAPH", type=PATH, help="a graph file (`graphsvc build`)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a summary")
    p.set_defaults(run=_cmd_info)

    p = command("relayout", "recompute a graph's sensor metadata for another layout",
                "Recompute a graph's per-edge sensor readings for another layout (or an older graph's for today's "
                "sensor frames), without the knowledge base.")  # fmt: skip
    p.add_argument("graph", metavar="GRAPH", type=PATH, help="the graph file to read")
    p.add_argument("--layout", required=True, metavar="LAYOUT", help="preset (wrists-ankles, kelly6, right-wrist) or layout file")
    p.add_argument("-o", "--output", required=True, metavar="OUT", type=PATH,
                   help="the graph file to write (not the input)")
    p.set_defaults(run=_cmd_relayout)

    p = command("synthesize", "reconstruct motion from a recording by searching a graph",
                "Reconstruct full-body motion from a recording (accelerometers, tracker, orientations, annotations "
                "or optical markers) with a strategy over a graph, and write it as BVH (and a report).")  # fmt: skip
    p.add_argument("graph", metavar="GRAPH", type=PATH, help="a graph file (`graphsvc build`)")
    p.add_argument("recording", metavar="REC", type=PATH,
                   help="recording: .rec, device CSV, Xsens MVNX, C3D or marker CSV")
    p.add_argument("-o", "--output", required=True, metavar="OUT.bvh", type=PATH,
                   help="the motion to write (.bvh; not an input)")
    add_synthesize_flags(p)
    p.add_argument("--report", metavar="OUT.json", type=PATH,
                   help="also write a JSON report: node path, labels, per-term costs, compression, timings")
    p.set_defaults(run=_cmd_synthesize)

    p = command("calibrate", "estimate each sensor's mounting rotation from a calibration take",
                "Estimate each device's mounting rotation onto the layout's sensor frame from a take that holds a "
                "known pose, then moves; `--calibration CAL.json` elsewhere applies it.")  # fmt: skip
    p.add_argument("recording", metavar="REC", type=PATH,
                   help="device recording: stands still in the pose, then moves")
    p.add_argument("--graph", metavar="GRAPH", type=PATH,
                   help="a graph whose readings of similar motion fix the rotation about gravity (default: none, the "
                        "rotation about gravity stays unknown)")  # fmt: skip
    p.add_argument("--pose", required=True, choices=("npose", "tpose", "stand"),
                   help="the pose held at the start (stand: a natural stance, only approximately an N-pose)")
    p.add_argument("--from", dest="start", type=float, metavar="S",
                   help="use the recording from S seconds (default: its start)")
    p.add_argument("--to", dest="end", type=float, metavar="S", help="use the recording up to S seconds (default: its end)")
    add_input_file_flags(p)
    p.add_argument("-o", "--output", required=True, metavar="CAL.json", type=PATH, help="the calibration to write (.json)")
    p.set_defaults(run=_cmd_calibrate)

    p = command("batch", "reconstruct a manifest of recordings on a local or existing Dask cluster",
                "Reconstruct every row of a manifest as `synthesize` would (the same bytes), on a local or an "
                "existing Dask cluster, resumably: a rerun skips what is done.")  # fmt: skip
    p.add_argument("manifest", metavar="MANIFEST", type=PATH,
                   help="CSV (header row) or JSON: recording, graph, strategy, output, [weights, constraints, "
                        "calibration, options]; docs/batch.md")  # fmt: skip
    p.add_argument("--out", required=True, metavar="DIR", type=PATH, help="outputs, the job store and the summary")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="an existing Dask scheduler, e.g. tcp://host:8786 (default: $DASK_SCHEDULER_ADDRESS, else a"
                            " local cluster)")
    where.add_argument("--workers", type=COUNT, metavar="N", help="local cluster workers (default: one a core)")
    p.add_argument("--retries", type=int, default=2, metavar="R",
                   help="further attempts after a failure that is not the input's (a worker died; default 2)")
    p.add_argument("--graph", action="append", metavar="NAME=PATH",
                   help="a graph the manifest names (repeatable; default: the manifest's paths)")
    p.add_argument("--timeout", type=float, default=10.0, metavar="S", help="wait this long for the scheduler (default 10)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=_cmd_batch)

    p = command("evaluate", "leave-one-out evaluation on a knowledge base",
                "Evaluate a strategy on a knowledge base: each test clip's sensors are simulated and reconstructed on "
                "a graph that hides its takes (or its clip, actor or action), and scored against it; or joined "
                "performances of several clips (--mixed). Metrics: docs/evaluation.md.")  # fmt: skip
    p.add_argument("kb", nargs="+", metavar="KB", type=PATH, help="knowledge-base files, folders or globs (.bvh, .amc)")
    p.add_argument("--test", required=True, metavar="GLOB",
                   help="test the KB files whose name matches, e.g. '*_00[14].bvh' (several: comma-separated)")
    p.add_argument("--layout", metavar="LAYOUT", help="sensor layout (default wrists-ankles, or the graph's with --graph)")
    p.add_argument("--graph", metavar="GRAPH", type=PATH,
                   help="a graph built from the same KB, instead of building one (default: build)")
    p.add_argument("--augment", metavar="KINDS",
                   help="build with copies: mirror, reverse (held out with their clip; default none)")
    p.add_argument("--noise", default="default", metavar="NOISE",
                   help="PRESET[,key=value...] (default: the 'default' preset, docs/sensors.md)")
    p.add_argument("--position-noise", type=ranged(float, 0.0, 1e3), metavar="M",
                   help="keep the overhead tracker's positions with this σ in metres (0: exact; default: the noise "
                        "preset's tracker, when it has one)")  # fmt: skip
    add_search_flags(p, constraints=False)
    p.add_argument("--flicker", type=float, metavar="P",
                   help="a strategy reading optical markers: each simulated marker unseen this share of samples, in short "
                        "dropouts (default 0)")
    p.add_argument("--gap-fraction", type=float, metavar="F",
                   help="a strategy reading optical markers: random gaps of 5–80 samples (every marker unseen) until this "
                        "share of samples (default 0)")
    p.add_argument("--seed", type=SEED, default=0, help="noise seed (each clip's is derived from it and its name; default 0)")
    p.add_argument("--jobs", type=COUNT, default=1, metavar="N",
                   help="evaluate N clips at once in worker processes (and build with N threads; default 1)")
    p.add_argument("--mixed", type=int, metavar="N",
                   help="score performances of N test clips with N different labels joined end to end (one performer "
                        "each; their clips hidden together) instead of each clip alone")
    p.add_argument("--hold-out", default="takes", choices=("clip", "takes", "actor", "content"),
                   help="what a test clip hides from the graph: its performance (clip), every take of its content × "
                        "style (takes, the default), every clip of its performer (actor) or of its content label "
                        "(content); docs/evaluation.md")
    p.add_argument("--actors", metavar="FILE", type=PATH,
                   help="actor map for --hold-out actor: JSON {clip name or glob: actor} (default: from the clips' "
                        "names, where they say)")  # fmt: skip
    p.add_argument("--mapping", metavar="FILE|guess", type=PATH,
                   help="the test clips' joint map when their skeleton is not the graph's (JSON, or 'guess')")
    p.add_argument("--json", metavar="OUT.json", type=PATH, help="write per-clip and mean metrics as JSON")
    p.add_argument("--keep-motions", metavar="DIR", type=PATH,
                   help="keep each clip's reconstruction, truth, input and timeline here (for `graphsvc report`)")
    p.add_argument("--report-html", metavar="OUT.html", type=PATH,
                   help="write the HTML report: metrics table and 3D viewer")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=_cmd_evaluate)

    p = command("report", "a self-contained HTML page of a result",
                "Write one self-contained HTML page of a result: a 3D viewer of the reconstruction (beside the truth), "
                "time-aligned errors, sensor readings, source clips and constraints.")  # fmt: skip
    p.add_argument("result", metavar="RESULT", type=PATH,
                   help="a `synthesize --report` JSON, an `evaluate --json` output with --keep-motions, or a batch folder")
    p.add_argument("-o", "--output", required=True, metavar="OUT.html", type=PATH, help="the page to write (.html)")
    p.add_argument("--truth", metavar="MOTION", type=PATH,
                   help="the true motion (.bvh, .amc) of a synthesize report, shown beside it (default: none)")
    p.set_defaults(run=_cmd_report)

    p = command("mapping", "propose a joint map for a skeleton graphsvc does not know",
                "Propose a joint map (canonical joint → the skeleton's joint) for a skeleton graphsvc does not know, "
                "for `--mapping FILE` elsewhere; exit 2 when a required joint is not found.")  # fmt: skip
    p.add_argument("clip", metavar="CLIP", type=PATH, help="a motion file (.bvh, .amc) with that skeleton")
    p.add_argument("-o", "--output", metavar="MAP.json", type=PATH, help="write the map here (default: print it)")
    p.set_defaults(run=_cmd_mapping)

    p = command("demo", "run the demo on a procedural knowledge base",
                "Generate a procedural knowledge base and a held-out performance, simulate its sensors, build the "
                "graph, reconstruct the performance and print the error, speed and path; writes the files, plots "
                "and report.html into a folder.")  # fmt: skip
    p.add_argument("-o", "--output", default="graphsvc-demo", metavar="DIR", type=PATH,
                   help="the folder to write (default graphsvc-demo)")
    p.add_argument("--seed", type=SEED, default=0, help="the knowledge base's and the noise's seed (default 0)")
    p.add_argument("--layout", default="kelly6", metavar="LAYOUT",
                   help="sensor layout: preset (wrists-ankles, kelly6, right-wrist) or layout file (default kelly6)")
    p.add_argument("--minutes", type=ranged(float, 0.0, 600.0, low_open=True), default=3.0,
                   help="knowledge-base length in minutes (default 3, at most 600)")
    p.set_defaults(run=_cmd_demo)

    from graphsvc.service.cli_commands import add_service_parsers

    add_service_parsers(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("graphsvc")
    except PackageNotFoundError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except BrokenPipeError:
        # The reader went away (`| head`): not an error; silence the final flush too.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (GraphsvcError, OSError) as exc:
        if args.debug:
            raise
        message = str(exc) if isinstance(exc, GraphsvcError) else os_message(exc)
        print(f"graphsvc: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("graphsvc: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
