"""Command line: parses arguments and calls the library. No logic of its own.

Errors a user can cause (GraphsvcError, unreadable or unwritable paths) print one
line on stderr and exit 2 with nothing written; --debug shows the traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from graphsvc.errors import GraphsvcError


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2, like every other user error
        self.exit(2, f"graphsvc: error: {message} (see --help)\n")


def _cmd_inspect(args) -> int:
    from graphsvc.describe import describe_paths, format_description

    info = describe_paths(args.paths, progress=False if args.json else None)
    if args.json:
        print(json.dumps(info, indent=2, sort_keys=True))
    else:
        print(format_description(info))
    return 0


def _cmd_simulate(args) -> int:
    from graphsvc.motion.library import load_motion
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.recording import export_csv, save_recording
    from graphsvc.sensors.simulate import simulate_recording

    noise = parse_noise(args.noise)
    if args.position_noise is not None:
        from dataclasses import replace

        noise = replace(noise, position=args.position_noise)
    layout = load_layout(args.layout)
    out = Path(args.output)
    _check_output(out)
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


def _cmd_demo(args) -> int:
    from graphsvc.demo import format_demo_summary, run_demo

    summary = run_demo(Path(args.output), seed=args.seed, layout_name=args.layout, minutes=args.minutes)
    print(format_demo_summary(summary))
    return 0


def _check_output(path: Path) -> None:
    if not path.parent.exists() or not path.parent.is_dir():
        raise GraphsvcError(f"output folder {path.parent} does not exist")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="graphsvc", description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("inspect", help="describe motion files, folders and recordings")
    p.add_argument("paths", nargs="+", metavar="PATH")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(run=_cmd_inspect)

    p = sub.add_parser("simulate", help="simulate sensor readings of a clip into a recording")
    p.add_argument("clip", metavar="CLIP")
    p.add_argument("--layout", required=True, help="preset (wrists-ankles, kelly6, right-wrist) or layout file")
    p.add_argument("--noise", default="none", help="PRESET[,key=value...] (presets: none, default, harsh)")
    p.add_argument("--position-noise", type=float, metavar="M", help="overhead-tracker noise σ in metres")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rate", type=float, metavar="HZ", help="resample to this rate first")
    p.add_argument("--mapping", metavar="FILE", help="joint mapping JSON for unknown skeletons")
    p.add_argument("-o", "--output", required=True, metavar="REC", help="output .rec (or .csv)")
    p.set_defaults(run=_cmd_simulate)

    p = sub.add_parser("demo", help="run the embedded demo on a procedural knowledge base")
    p.add_argument("-o", "--output", default="graphsvc-demo", metavar="DIR")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--layout", default="kelly6")
    p.add_argument("--minutes", type=float, default=3.0, help="knowledge-base length")
    p.set_defaults(run=_cmd_demo)
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
    except (GraphsvcError, OSError) as exc:
        if args.debug:
            raise
        message = str(exc) if isinstance(exc, GraphsvcError) else _os_message(exc)
        print(f"graphsvc: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("graphsvc: interrupted", file=sys.stderr)
        return 130


def _os_message(exc: OSError) -> str:
    where = f"{exc.filename}: " if exc.filename else ""
    return f"{where}{exc.strerror or exc}"


if __name__ == "__main__":
    sys.exit(main())
