"""The `graphsvc` command: parse arguments, call the library, print what it did.

One module a group of commands, each adding its parsers (`add_…`) and holding its
command functions: motion_files (inspect, simulate, mapping, samples), graph (build, info,
relayout), reconstruction (synthesize, calibrate, demo), batch, evaluation (evaluate,
report), service (serve), client (client …, sensor-bridge); args: what they share
beyond graphsvc/flags.py.

Errors a user can cause (GraphsvcError, unreadable or unwritable paths) print one
line on stderr and exit 2 with nothing written; --debug shows the traceback (`main`,
for every command).

Each command function imports the library it calls inside itself: `graphsvc --help`
and a command load only what they use (numba's kernels, grpc, dask are seconds of
start-up a command that does not need them should not pay).
"""

from __future__ import annotations

import argparse
import os
import sys

from graphsvc.cli import batch, client, evaluation, graph, motion_files, reconstruction, service
from graphsvc.errors import GraphsvcError
from graphsvc.flags import Parser, os_message

DESCRIPTION = (
    "graphsvc reconstructs full-body human motion from sparse measurements — body-worn accelerometers, an "
    "overhead tracker's position and heading, annotations, or a few optical markers — by searching motion "
    "capture: build a motion graph of a knowledge base of clips, then synthesize motion from a recording, "
    "in batch, or live through the gRPC service."
)

# The commands in the order `graphsvc --help` lists them.
COMMANDS = (
    motion_files.add_inspect,
    motion_files.add_simulate,
    graph.add_build,
    graph.add_info,
    graph.add_relayout,
    reconstruction.add_synthesize,
    reconstruction.add_calibrate,
    batch.add_batch,
    evaluation.add_evaluate,
    evaluation.add_report,
    motion_files.add_mapping,
    reconstruction.add_demo,
    motion_files.add_samples,
    service.add_serve,
    client.add_client,
    client.add_sensor_bridge,
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="graphsvc",
        description=DESCRIPTION,
        epilog="Run `graphsvc COMMAND --help` for a command's arguments; the README and docs/ for more.",
    )
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error instead of one line")
    parser.add_argument("--version", action="version", version=_version(), help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser, metavar="COMMAND")
    for add in COMMANDS:
        add(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("graphsvc")
    except PackageNotFoundError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run(args)


def run(args) -> int:
    """The command `args` names (`args.run`), with the errors a user can cause as one
    line `graphsvc: error: …` and exit 2 (with --debug: raised); a closed pipe is no
    error; Ctrl-C exits 130."""
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
