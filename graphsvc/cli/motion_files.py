"""Commands on motion files and recordings: `inspect`, `simulate`, `mapping`, `samples`."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from graphsvc.cli.args import command, file_arg
from graphsvc.fileio import check_outputs
from graphsvc.flags import LAYOUT_HELP, PATH, RATE_HZ, SEED, add_marker_flags, add_reading_flags, ranged


def _cmd_inspect(args) -> int:
    from graphsvc.describe import describe_paths, format_description

    info = describe_paths(args.paths, progress=False if args.json else None, up=args.up, units=args.units)
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
    check_outputs(
        [("-o", out, None)],
        [("the clip", args.clip), ("the joint map", file_arg(args.mapping)), ("the marker set", args.markers)],
    )
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
        rec = simulate_marker_recording(
            motion, marker_set, noise, seed=args.seed, rate_hz=args.rate, mapping=args.mapping, pattern=pattern
        )
        (export_marker_csv if out.suffix.lower() == ".csv" else save_recording)(rec, out)
        print(
            f"wrote {out}: {rec.num_samples} samples of {len(rec.marker_names)} markers "
            f"({', '.join(rec.marker_names)}) at {rec.rate_hz:g} Hz, seen {100 * rec.meta['seen']:.0f} %, "
            f"marker noise {noise.marker:g} mm"
        )
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
    note = (
        (
            f"not found: {', '.join(missing)}"
            + (" — required: map them by hand" if required else " (a skeleton may lack these)")
        )
        if missing
        else "every canonical joint found"
    )
    print(
        f"{motion.skeleton.num_joints_excluding_end_sites} joints; {note}"
        + (f"; wrote {args.output}" if args.output else ""),
        file=sys.stderr,
    )
    return 0 if not required else 2


def add_inspect(sub) -> None:
    p = command(
        sub,
        "inspect",
        "describe motion files, folders and recordings",
        "Describe motion files and folders (searched recursively: per clip frames, rate, joints, duration, "
        "labels; per-folder and overall totals) or recordings (samples, sensors, channels).",
    )
    p.add_argument(
        "paths",
        nargs="+",
        metavar="PATH",
        type=PATH,
        help="a motion file (.bvh, .amc, DeepMimic .txt), a folder of them, or a recording (.rec, .csv, .mvnx, .c3d)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    add_reading_flags(p)
    p.set_defaults(run=_cmd_inspect)


def add_simulate(sub) -> None:
    p = command(
        sub,
        "simulate",
        "simulate sensor readings or optical markers of a clip into a recording",
        "Simulate the readings a layout's accelerometers (--layout) or a marker set's optical markers "
        "(--markers) would give for a motion clip, with noise, and write them as a recording.",
    )
    p.add_argument("clip", metavar="CLIP", type=PATH, help="the motion file (.bvh, .amc, DeepMimic .txt) to simulate")
    p.add_argument("--layout", help=f"accelerometers: {LAYOUT_HELP}")
    add_marker_flags(p)
    p.add_argument("--gaps", metavar="START:LEN,...", help="markers: every marker unseen over these frames of the clip")
    p.add_argument(
        "--flicker",
        type=float,
        metavar="P",
        help="markers: each marker unseen this share of samples, in short dropouts (3 samples on average; default 0)",
    )
    p.add_argument(
        "--gap-fraction",
        type=float,
        metavar="F",
        help="markers: random gaps of 5–80 samples until this share of samples is in one (default 0)",
    )
    p.add_argument(
        "--noise",
        default="none",
        metavar="NOISE",
        help="PRESET[,key=value...] (presets: none, default, tracker, harsh, real; default none)",
    )
    p.add_argument(
        "--position-noise",
        type=ranged(float, 0.0, 1e3),
        metavar="M",
        help="overhead-tracker noise σ in metres (default: the noise preset's)",
    )
    p.add_argument("--seed", type=SEED, default=0, help="noise seed (default 0)")
    p.add_argument("--rate", type=RATE_HZ, metavar="HZ", help="resample to this rate first (default: the clip's)")
    p.add_argument(
        "--mapping",
        metavar="FILE|guess",
        type=PATH,
        help="joint map JSON for a skeleton graphsvc does not know, or 'guess' (`graphsvc mapping`)",
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT.rec",
        type=PATH,
        help="the recording to write: .rec, or .csv (a device CSV, or a marker CSV with --markers)",
    )
    p.set_defaults(run=_cmd_simulate)


def add_mapping(sub) -> None:
    p = command(
        sub,
        "mapping",
        "propose a joint map for a skeleton graphsvc does not know",
        "Propose a joint map (canonical joint → the skeleton's joint) for a skeleton graphsvc does not know, "
        "for `--mapping FILE` elsewhere; exit 2 when a required joint is not found.",
    )
    p.add_argument(
        "clip", metavar="CLIP", type=PATH, help="a motion file (.bvh, .amc, DeepMimic .txt) with that skeleton"
    )
    p.add_argument("-o", "--output", metavar="MAP.json", type=PATH, help="write the map here (default: print it)")
    p.set_defaults(run=_cmd_mapping)


def _cmd_samples(args) -> int:
    from graphsvc.samples import LICENCE_FILE, load_samples, write_samples

    out = Path(args.output)
    motions = load_samples()
    write_samples(out, motions)
    rates = sorted({m.rate_hz for m in motions})
    print(
        f"wrote {out}/: {len(motions)} clips as BVH ({sum(m.duration_s for m in motions):.1f} s at "
        f"{', '.join(f'{r:g}' for r in rates)} Hz, {motions[0].skeleton.num_joints_excluding_end_sites} joints) "
        f"and {LICENCE_FILE} (pybullet's licence)"
    )
    print("  " + ", ".join(m.name for m in motions))
    return 0


def add_samples(sub) -> None:
    p = command(
        sub,
        "samples",
        "write the sample clips that install with pybullet as BVH",
        "Write the DeepMimic humanoid's motion clips that pybullet installs (walk, run, turns, jump, kick, "
        "punch, cartwheel, backflip, dances, crawl, roll, get-ups) as BVH, with pybullet's licence; needs "
        "the optional extra: pip install 'graphsvc[samples]'.",
    )
    p.add_argument(
        "-o",
        "--output",
        default="graphsvc-samples",
        metavar="DIR",
        type=PATH,
        help="the folder to write (default graphsvc-samples)",
    )
    p.set_defaults(run=_cmd_samples)
