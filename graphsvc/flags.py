"""The reconstruction's command-line flags as a library: the CLI's `synthesize`,
`evaluate`, `client` and `sensor-bridge`, a batch manifest's `options` column and the
service's batches all parse them here, with the same checks and messages.

What every strategy reads has its own flags (`--strategy`, `--weights`, `--latency`,
the heading rule, `--constraints`). The shared options and each registered strategy's
own options are derived from their declarations (`strategies.options.option`): a flag
`--<strategy>-<field>` for each field (`--<field>` for a shared one), a strategy's
`flag_groups` as one comma-separated flag, and the field's declared aliases (today's
names: `--beam`, `--track-pull`, `--markers`, `--keep`, `--ssg-window` …) beside it; a
bool field takes `--x` / `--no-x` and its declared negations (`--olng-basic-steps`).
Values are parsed by type here and checked, with the field named, by the options'
declarations (`strategies.check_options`). A strategy installed as a plug-in gets its
flags with no edit here.

Also the argument types every command uses (`Parser`, one line and exit 2 on a bad
argument; `ranged`, `PATH`) and how an OSError reads.
"""

from __future__ import annotations

import argparse
import math
import re

from graphsvc.motion.proportions import MAX_HEIGHT_M
from graphsvc.sensors.layout import preset_names
from graphsvc.strategies import DEFAULT, available, get, names
from graphsvc.strategies.options import (
    ORIENTATION_WEIGHT,
    Options,
    SharedOptions,
    from_values,
    load_constraints,
    option_specs,
    parse_weights,
)


class Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # a value starting with a minus and a digit is a value, not an option: number lists
        # such as `--weights -1,1,1` reach our own validation (argparse knows only -1, -.5)
        self._negative_number_matcher = re.compile(r"^-\.?\d[\d.,eE+-]*$")

    def error(self, message):  # one line, exit 2, like every other user error
        self.exit(2, f"graphsvc: error: {message} (see --help)\n")


def _number(kind, text: str, low: float, high: float, low_open: bool):
    try:
        value = kind(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
    if not math.isfinite(value) or value > high or (value <= low if low_open else value < low):
        bound = f"> {low:g}" if low_open else f"≥ {low:g}"
        raise argparse.ArgumentTypeError(f"{text!r} must be finite, {bound} and at most {high:g}")
    return value


def ranged(kind, low: float, high: float, low_open: bool = False):
    """An argparse `type`: a finite int or float in [low, high] ((low, high] when
    low_open); anything else is refused with one line, exit 2."""

    def convert(text: str):
        return _number(kind, text, low, high, low_open)

    convert.__name__ = "integer" if kind is int else "number"  # (argparse names the type in its message)
    return convert


def PATH(text: str) -> str:  # noqa: N802 (an argparse type, named as the others)
    """An argparse `type` for a file or folder path: an empty string is refused (it is
    not the current folder), with one line, exit 2."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path is not a file or folder")
    return text


PATH.__name__ = "path"

# What --layout takes, as every command's help says it: the presets from
# `sensors.layout.PRESETS`, so a new preset shows everywhere.
LAYOUT_HELP = f"preset ({preset_names()}) or layout file"

SEED = ranged(int, 0, 2**63 - 1)
RATE_HZ = ranged(float, 0.0, 100_000.0, low_open=True)  # (sensors.recording.MAX_RATE_HZ)
COUNT = ranged(int, 1, 4096)  # threads, workers, streams


def os_message(exc: OSError) -> str:
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"


# ---------------------------------------------------------------- declared options as flags


def _parse_int(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None


def _parse_float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def _parse_names(text: str) -> tuple[str, ...] | None:
    names = tuple(n.strip() for n in str(text).split(",") if n.strip())
    return names or None


_PARSE = {int: _parse_int, float: _parse_float, str: str, tuple: _parse_names}


def _numbers(count: int, metavar: str):
    def convert(text: str):
        try:
            values = [float(v) for v in str(text).split(",")]
        except ValueError:
            values = []
        if len(values) != count:
            words = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six"}
            raise argparse.ArgumentTypeError(f"{text!r} must be {words.get(count, count)} numbers {metavar}")
        return values

    convert.__name__ = "numbers"
    return convert


def _dest(owner: str, field: str) -> str:
    return f"option__{owner}__{field}"


def _add_declared(g, owner: str | None, cls) -> None:
    """Flags for every declared field of `cls` (a strategy's own options, owner its
    name; or the shared ones, owner None) into argument group `g`."""
    for spec in option_specs(cls):
        stem = spec.name.replace("_", "-")
        flags = [f"--{owner}-{stem}" if owner else f"--{stem}", *spec.aliases]
        dest = _dest(owner or "shared", spec.name)
        if spec.kind is bool:
            g.add_argument(*flags, dest=dest, action=argparse.BooleanOptionalAction, default=None, help=spec.help)
            for neg in spec.negated:
                g.add_argument(
                    neg, dest=dest, action="store_const", const=False, help=f"the same as --no-{flags[0][2:]}"
                )
            continue
        g.add_argument(
            *flags,
            dest=dest,
            type=_PARSE[spec.kind],
            default=None,
            choices=spec.choices,
            metavar=None if spec.choices else (spec.metavar or stem.upper()),
            help=spec.help,
        )
    for group, fields in getattr(cls, "flag_groups", {}).items():
        metavar = ",".join(f.split("_", 1)[-1].upper() for f in fields)
        g.add_argument(
            f"--{owner}-{group}",
            dest=_dest(owner, f"group:{group}"),
            type=_numbers(len(fields), metavar),
            default=None,
            metavar=metavar,
            help=f"{', '.join(fields)} at once",
        )


def _given(args, owner: str, cls) -> dict:
    """{field: value} of the flags of `cls` given on the command line (a flag group
    spread over its fields; a field's own flag wins over its group's)."""
    values = {}
    for group, fields in getattr(cls, "flag_groups", {}).items():
        v = getattr(args, _dest(owner, f"group:{group}"), None)
        if v is not None:
            values.update(zip(fields, v))
    for spec in option_specs(cls):
        v = getattr(args, _dest(owner, spec.name), None)
        if v is not None:
            values[spec.name] = v
    return values


# ---------------------------------------------------------------- the search flags


def add_search_flags(p, constraints: bool = True, latency_help: str | None = None) -> None:
    """The flags of a reconstruction (module docstring). latency_help: --latency's help
    where the command streams (a live session's lag is its default there)."""
    p.add_argument(
        "--strategy",
        default=DEFAULT,
        choices=names(),
        help=f"reconstruction strategy (default {DEFAULT}): "
        + "; ".join(f"{n}: {get(n).summary}" for n in available()),
    )
    p.add_argument(
        "--weights",
        default="1,1,1",
        metavar="A,P,O[,R]",
        help="cost weights: accelerometers (per g²), position (per m), heading (per rad), sensor"
        " orientation (per chord², where the recording has orientations); default 1,1,1,"
        f"{ORIENTATION_WEIGHT:g}",
    )
    if constraints:
        p.add_argument(
            "--constraints",
            metavar="FILE",
            type=PATH,
            help="annotation constraint sets (JSON), replacing the recording's (default: the recording's)",
        )
    p.add_argument(
        "--latency",
        type=float,
        metavar="S",
        help=latency_help
        or "fixed-lag decoding with this lag in seconds, as a live stream would (default: whole input)",
    )
    p.add_argument(
        "--heading-from-track",
        action="store_true",
        help="derive heading from the ground positions: direction of travel above --speed-threshold "
        "(default: the recording's heading)",
    )
    p.add_argument(
        "--rest-heading-deg",
        type=float,
        default=0.0,
        metavar="D",
        help="heading when slower than the threshold, degrees about +Y (default 0: facing +Z)",
    )
    p.add_argument(
        "--speed-threshold",
        type=float,
        default=2.0,
        metavar="M/S",
        help="with --heading-from-track: the speed above which heading is the direction of travel (default "
        "2 m/s, Kelly et al.)",
    )
    _add_declared(p.add_argument_group("shared by the strategies that use them"), None, SharedOptions)
    for name in available():
        s = get(name)
        if option_specs(s.options_class):
            _add_declared(p.add_argument_group(f"--strategy {name}"), name, s.options_class)


def options_from_flags(args) -> tuple[Options, list[str]]:
    """(Options, notes) from `add_search_flags`' flags: the chosen strategy's own options,
    the shared ones, and those given for other strategies (kept, and listed as ignored
    in the report); notes: one line for each flag of another strategy that was given.
    InputError (an `OptionError` naming the flag's field) for a value refused."""
    constraints = tuple(load_constraints(args.constraints)) if getattr(args, "constraints", None) else None
    shared = from_values(SharedOptions, _given(args, "shared", SharedOptions))
    settings, notes = {}, []
    for name in available():
        cls = get(name).options_class
        given = _given(args, name, cls)
        if given:
            settings[name] = from_values(cls, given)
            if name != args.strategy:
                notes.append(
                    f"--{name}-… options apply to --strategy {name}; ignored with --strategy {args.strategy} "
                    f"({', '.join(sorted(given))})"
                )
    options = Options(
        strategy=args.strategy,
        weights=parse_weights(args.weights),
        latency_s=args.latency,
        heading_from_track=args.heading_from_track,
        rest_heading_deg=args.rest_heading_deg,
        speed_threshold=args.speed_threshold,
        constraints=constraints,
        shared=shared,
        settings=settings,
    )
    return options, notes


# ---------------------------------------------------------------- reading a recording file


def add_marker_flags(p) -> None:
    """--markers and --keep of `simulate`: the marker set to simulate and the markers kept."""
    p.add_argument(
        "--markers",
        metavar="SET",
        type=PATH,
        help="marker set: hands-feet, left-foot, head-back, vicon, or a marker set file (JSON/TOML)",
    )
    p.add_argument("--keep", metavar="NAMES", help="use only these markers of the set (comma-separated; default: all)")


def add_input_file_flags(p) -> None:
    """--up, --units and --device-map: how to read a recording file where it does not say,
    and how to name a device's sensors as the graph's layout does."""
    add_reading_flags(p)
    add_device_map_flag(p)


def add_reading_flags(p) -> None:
    """--up and --units: how to read a recording file where it does not say."""
    p.add_argument(
        "--up",
        choices=("y", "z"),
        help="the vertical axis: of a marker file (default: the file's; C3D: from the markers' spread, else "
        "Z) or of a device CSV's orientations (default: its # up= comment, else Y)",
    )
    p.add_argument(
        "--units",
        choices=("m", "cm", "mm", "g", "m/s2"),
        help="overriding the file's: a marker file's length unit (m, cm, mm) or a device CSV's acceleration "
        "unit (g, m/s2); default: what the file says",
    )


def add_device_map_flag(p) -> None:
    """--device-map: how to name a device recording's sensors as the graph's layout does."""
    from graphsvc.sensors.devices import DEVICES

    p.add_argument(
        "--device-map",
        metavar="|".join(DEVICES) + "|FILE",
        type=PATH,
        help="rename a device's sensors to the graph layout's: a built-in map for the graph's layout preset "
        "(xsens: Xsens MVN segment or skeleton names, whichever fits more; mvn: MVN skeleton names; "
        "generic: left_wrist, l_knee, pelvis, head and their spellings) or a JSON map file; unmapped "
        "sensors are dropped (default: none)",
    )


def add_calibration_flag(p) -> None:
    """--calibration: a device-frame recording's mounting calibration (`graphsvc calibrate`)."""
    p.add_argument(
        "--calibration",
        metavar="CAL.json",
        type=PATH,
        help="turn a device-frame recording into the layout's sensor frames with this calibration "
        "(`graphsvc calibrate`; default: none)",
    )


CALIBRATION_POSES = ("npose", "tpose", "stand")  # (`sensors.calibration.POSES`, not imported here: numba)


def add_pose_flag(p, required: bool = False, what: str = "the pose held at the start") -> None:
    """--pose: the calibration pose (`graphsvc calibrate`, --calibrate-from-start)."""
    p.add_argument(
        "--pose",
        required=required,
        choices=CALIBRATION_POSES,
        help=f"{what} (stand: a natural stance, only approximately an N-pose)",
    )


def add_calibrate_from_start_flags(p) -> None:
    """--calibrate-from-start S and --pose: calibrate a device-frame recording from its own
    first S seconds against the graph, then use it (`calibration_choice`)."""
    p.add_argument(
        "--calibrate-from-start",
        type=ranged(float, 0.0, 3600.0, low_open=True),
        metavar="S",  # (graph.calibration.MAX_FROM_START_S)
        help="calibrate the devices' mountings from the recording's own first S seconds (the performer "
        "holds --pose, then moves) against the graph, then reconstruct the whole recording, those "
        "seconds included; not with --calibration (default: none)",
    )
    add_pose_flag(p, what="with --calibrate-from-start: the pose held at the recording's start")


def calibration_choice(args) -> tuple[str | None, float | None, str | None]:
    """(--calibration, --calibrate-from-start, --pose) checked together: GraphsvcError for
    both ways at once, or one without the other's pose."""
    from graphsvc.errors import InputError

    cal, start, pose = (
        getattr(args, "calibration", None),
        getattr(args, "calibrate_from_start", None),
        getattr(args, "pose", None),
    )
    if cal and start is not None:
        raise InputError("--calibration and --calibrate-from-start are two ways to calibrate: give one")
    if start is not None and pose is None:
        raise InputError("--calibrate-from-start needs --pose npose|tpose|stand (the pose held at the start)")
    if pose is not None and start is None:
        raise InputError("--pose goes with --calibrate-from-start S")
    return cal, start, pose


def add_performer_flags(p) -> None:
    """--performer and --height (one or the other, `add_mutually_exclusive_group`) and
    --performer-mapping: the proportions a reconstruction is put on
    (`motion.proportions`)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--performer",
        metavar="FILE",
        type=PATH,
        help="put the output on this performer's proportions: a BVH or ASF/AMC of the performer (its "
        "skeleton's segment lengths) or a graphsvc-performer JSON of segment lengths (default: the "
        "knowledge base's)",
    )
    g.add_argument(
        "--height",
        type=ranged(float, 0.0, MAX_HEIGHT_M, low_open=True),
        metavar="M",
        help="put the output on the knowledge base's proportions scaled to a performer this many metres "
        "tall (default: the knowledge base's)",
    )
    p.add_argument(
        "--performer-mapping",
        metavar="FILE|guess",
        type=PATH,
        help="the joint map of a --performer motion whose skeleton has no built-in one (JSON, or 'guess')",
    )


def performer_from_flags(args, kb_skeleton, kb_mapping=None) -> dict | None:
    """The segment lengths `add_performer_flags`' flags ask for on the knowledge base's
    skeleton (`proportions.performer_lengths`), or None when neither was given.
    InputError for --performer-mapping without --performer; FormatError /
    MissingFileError for a bad or absent file."""
    from graphsvc.errors import InputError
    from graphsvc.motion.proportions import performer_lengths

    performer, height = getattr(args, "performer", None), getattr(args, "height", None)
    mapping = getattr(args, "performer_mapping", None)
    if performer is None and height is None:
        if mapping is not None:
            raise InputError("--performer-mapping applies to a --performer motion file")
        return None
    return performer_lengths(kb_skeleton, performer=performer, height=height, mapping=mapping, kb_mapping=kb_mapping)


def add_synthesize_flags(p) -> None:
    """Every flag of `synthesize` but its files: the search flags, how to read the
    recording, the BVH scale (a batch manifest's `options` column takes the same)."""
    add_search_flags(p)
    add_input_file_flags(p)
    add_calibration_flag(p)
    add_calibrate_from_start_flags(p)
    p.add_argument("--scale", type=float, default=100.0, help="BVH units per metre (default 100: centimetres)")


def synthesize_inputs(args) -> list[tuple[str, str | None]]:
    """The files a `synthesize` (or `client synthesize`) reads, as (what, path) pairs for
    `fileio.check_outputs`: no output may replace one of them."""
    from pathlib import Path

    from graphsvc.sensors.devices import DEVICES

    named = lambda v: None if v is None or v in DEVICES else v  # noqa: E731 (a built-in name is no file)
    files = [
        ("the graph", getattr(args, "graph", None)),
        ("the recording", args.recording),
        ("the constraints", getattr(args, "constraints", None)),
        ("the calibration", getattr(args, "calibration", None)),
        ("the device map", named(getattr(args, "device_map", None))),
        ("the performer", getattr(args, "performer", None)),
        (
            "the performer's joint map",
            None if getattr(args, "performer_mapping", None) == "guess" else getattr(args, "performer_mapping", None),
        ),
    ]
    # a strategy's option that names a file (a marker set file, say)
    files += [
        (f"the file of --{k.split('__')[1]}-{k.split('__')[2]}", v)
        for k, v in sorted(vars(args).items())
        if k.startswith("option__") and isinstance(v, str) and Path(v).is_file()
    ]
    return files
