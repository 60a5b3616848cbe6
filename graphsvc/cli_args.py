"""Argument helpers the command line and the service commands share: the parser that
fails in one line, the strategy flags, and how an OSError reads."""

from __future__ import annotations

import argparse
import math
import re

from graphsvc.strategies.options import ORIENTATION_WEIGHT


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

SEED = ranged(int, 0, 2**63 - 1)
RATE_HZ = ranged(float, 0.0, 100_000.0, low_open=True)  # (sensors.recording.MAX_RATE_HZ)
COUNT = ranged(int, 1, 4096)  # threads, workers, streams
PROTO_UINT = ranged(int, 0, 2**32 - 1)  # (a uint32 of the service's options; the strategies check their own range)


def search_options(args):
    """Options from the strategy flags shared by `synthesize`, `evaluate` and `client`."""
    from graphsvc.pipeline import Options, load_constraints, parse_weights

    constraints = tuple(load_constraints(args.constraints)) if getattr(args, "constraints", None) else None
    return Options(strategy=args.strategy, weights=parse_weights(args.weights), latency_s=args.latency,
                   heading_from_track=args.heading_from_track, rest_heading_deg=args.rest_heading_deg,
                   speed_threshold=args.speed_threshold, constraints=constraints, beam=args.beam,
                   olng=olng_options(args), ssg=ssg_options(args),
                   **({} if args.track_pull is None else {"track_pull_s": args.track_pull}))  # fmt: skip


OLNG_WEIGHTS = ("w_prior", "w_contr", "w_pose", "w_motion", "w_smooth")


def parse_olng_weights(text: str) -> dict:
    """'PRIOR,CONTR,POSE,MOTION,SMOOTH' → OlngOptions keyword arguments."""
    from graphsvc.errors import InputError

    try:
        values = [float(v) for v in str(text).split(",")]
    except ValueError:
        raise InputError(f"OLNG weights must be five numbers PRIOR,CONTR,POSE,MOTION,SMOOTH, got {text!r}") from None
    if len(values) != 5:
        raise InputError(f"OLNG weights must be five numbers PRIOR,CONTR,POSE,MOTION,SMOOTH, got {text!r}")
    return dict(zip(OLNG_WEIGHTS, values))


def olng_options(args):
    from graphsvc.strategies.options import OlngOptions

    weights = parse_olng_weights(args.olng_weights) if getattr(args, "olng_weights", None) else {}
    return OlngOptions(k=getattr(args, "olng_k", None), m=32 if getattr(args, "olng_m", None) is None else args.olng_m,
                       i=getattr(args, "olng_i", None), extended=not getattr(args, "olng_basic_steps", False),
                       fix_feet=getattr(args, "olng_fix_feet", False), **weights)  # fmt: skip


def ssg_options(args):
    from graphsvc.sensors.markers import parse_names
    from graphsvc.strategies.options import SsgOptions

    return SsgOptions(markers=getattr(args, "markers", None), keep=parse_names(getattr(args, "keep", None)),
                      window_s=getattr(args, "ssg_window", None), overlap_s=getattr(args, "ssg_overlap", None),
                      k=getattr(args, "ssg_k", None), weight=getattr(args, "ssg_weight", None),
                      offsets=getattr(args, "ssg_offsets", None) or "auto")  # fmt: skip


def add_marker_options(p) -> None:
    """--markers and --keep: the marker set of an optical input and the markers used."""
    p.add_argument("--markers", metavar="SET", type=PATH,
                   help="marker set: hands-feet, left-foot, head-back, vicon, or a marker set file (JSON/TOML)")
    p.add_argument("--keep", metavar="NAMES", help="use only these markers of the set (comma-separated; default: all)")


def add_input_file_options(p) -> None:
    """--up, --units and --device-map: how to read a recording file where it does not say,
    and how to name a device's sensors as the graph's layout does."""
    p.add_argument("--up", choices=("y", "z"),
                   help="the vertical axis: of a marker file (default: the file's; C3D: from the markers' spread, else "
                        "Z) or of a device CSV's orientations (default: its # up= comment, else Y)")
    p.add_argument("--units", choices=("m", "cm", "mm", "g", "m/s2"),
                   help="overriding the file's: a marker file's length unit (m, cm, mm) or a device CSV's acceleration "
                        "unit (g, m/s2); default: what the file says")
    p.add_argument("--device-map", metavar="xsens|FILE", type=PATH,
                   help="rename a device's sensors to the graph layout's: xsens (Xsens segment names, the built-in map "
                        "for the graph's layout) or a JSON map file; unmapped sensors are dropped")


def add_calibration_option(p) -> None:
    """--calibration: a device-frame recording's mounting calibration (`graphsvc calibrate`)."""
    p.add_argument("--calibration", metavar="CAL.json", type=PATH,
                   help="turn a device-frame recording into the layout's sensor frames with this calibration "
                        "(`graphsvc calibrate`; default: none)")


def add_search_options(p, constraints: bool = True, latency_help: str | None = None) -> None:
    """The strategy flags. latency_help: --latency's help where the command streams (a
    live session's lag is its default there)."""
    from graphsvc.strategies import names
    from graphsvc.strategies.options import TRACK_PULL_S

    p.add_argument("--strategy", default="viterbi", choices=names(),
                   help="reconstruction strategy (default viterbi; olng: frame by frame, optimised poses; nearest: the"
                        " per-sample baseline; ssg: optical markers)")
    p.add_argument("--weights", default="1,1,1", metavar="A,P,O[,R]",
                   help="cost weights: accelerometers (per g²), position (per m), heading (per rad), sensor"
                        " orientation (per chord², where the recording has orientations); default 1,1,1,"
                        f"{ORIENTATION_WEIGHT:g}")
    if constraints:
        p.add_argument("--constraints", metavar="FILE", type=PATH,
                       help="annotation constraint sets (JSON), replacing the recording's (default: the recording's)")
    p.add_argument("--latency", type=float, metavar="S",
                   help=latency_help or "fixed-lag decoding with this lag in seconds, as a live stream would (default: "
                                        "whole input)")  # fmt: skip
    p.add_argument("--heading-from-track", action="store_true",
                   help="derive heading from the ground positions: direction of travel above --speed-threshold "
                        "(default: the recording's heading)")
    p.add_argument("--rest-heading-deg", type=float, default=0.0, metavar="D",
                   help="heading when slower than the threshold, degrees about +Y (default 0: facing +Z)")
    p.add_argument("--speed-threshold", type=float, default=2.0, metavar="M/S",
                   help="with --heading-from-track: the speed above which heading is the direction of travel (default "
                        "2 m/s, Kelly et al.)")
    p.add_argument("--beam", type=float, metavar="COST",
                   help="beam search: after each sample keep only the paths within COST of the best (faster; default:"
                        " the exact search)")
    p.add_argument("--track-pull", type=float, metavar="S",
                   help="time constant (s) with which each path's placement follows the measured positions (0: placed"
                        f" once, at the start; default {TRACK_PULL_S:g}); olng follows the tracker the same way")
    g = p.add_argument_group("olng (Tautges et al. 2011)")
    g.add_argument("--olng-k", type=PROTO_UINT, metavar="K",
                   help="neighbours a sample (default: frames / 150, 16 to 4096, the paper's 4096 of ~600,000)")
    g.add_argument("--olng-i", type=PROTO_UINT, metavar="I", help="paths the pose is made from (default K / 16, 4 to 256)")
    g.add_argument("--olng-m", type=PROTO_UINT, metavar="M", help="window columns (default 32)")
    g.add_argument("--olng-basic-steps", action="store_true", help="leave out the extended steps (a column skipped)")
    g.add_argument("--olng-weights", metavar="PRIOR,CONTR,POSE,MOTION,SMOOTH",
                   help="energy weights (default the paper's 5,1,0.6,0.2,0.2)")
    g.add_argument("--olng-fix-feet", action="store_true",
                   help="foot clean-up: a foot in contact moves only as the neighbours' feet moved (costs accuracy)")
    g = p.add_argument_group("ssg (Tautges 2012): optical markers")
    add_marker_options(g)
    g.add_argument("--ssg-window", type=float, metavar="S",
                   help="window length, seconds (default 1/3; 0.25 when every marker is on the head or trunk)")
    g.add_argument("--ssg-overlap", type=float, metavar="S",
                   help="overlap of consecutive windows, seconds, at most half a window (default 1/6; 0.1)")
    g.add_argument("--ssg-k", type=PROTO_UINT, metavar="K", help="subsequences kept a window (default 8; 16)")
    g.add_argument("--ssg-weight", type=float, metavar="W",
                   help="weight of the transition costs against the node costs (default 1; 4)")
    g.add_argument("--ssg-offsets", choices=("auto", "fit", "nominal"),
                   help="marker offsets on their segments: the set's (nominal), fitted to the input (fit), or fit "
                        "unless the recording was simulated (auto, the default)")


def add_synthesize_options(p) -> None:
    """Every flag of `synthesize` but its files: the strategy flags, how to read the
    recording, the BVH scale (a batch manifest's `options` column takes the same)."""
    add_search_options(p)
    add_input_file_options(p)
    add_calibration_option(p)
    p.add_argument("--scale", type=float, default=100.0, help="BVH units per metre (default 100: centimetres)")


def synthesize_inputs(args) -> list[tuple[str, str | None]]:
    """The files a `synthesize` (or `client synthesize`) reads, as (what, path) pairs for
    `fileio.check_outputs`: no output may replace one of them."""
    named = lambda v: None if v in (None, "xsens") else v  # noqa: E731 (a built-in name is no file)
    return [("the graph", getattr(args, "graph", None)), ("the recording", args.recording),
            ("the constraints", getattr(args, "constraints", None)), ("the calibration", getattr(args, "calibration", None)),
            ("the device map", named(getattr(args, "device_map", None))), ("the marker set", getattr(args, "markers", None))]  # fmt: skip


def os_message(exc: OSError) -> str:
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"
