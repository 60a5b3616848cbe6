"""What the commands share beyond graphsvc/flags.py's argument types: a subcommand's
parser, arguments that are a file or a built-in name, notes and flushed lines."""

from __future__ import annotations

import sys


def command(sub, name: str, summary: str, description: str | None = None, **kwargs):
    """Subcommand `name` of `sub` (an argparse subparsers action): `summary` in the
    command list, `description` (default: the summary as a sentence) in its help;
    kwargs: `add_parser`'s others (parents, say)."""
    return sub.add_parser(
        name, help=summary, description=description or summary[0].upper() + summary[1:] + ".", **kwargs
    )


def file_arg(value: str | None) -> str | None:
    """An argument that is a file or a built-in name (`--mapping guess`, `--device-map
    xsens`): the file, or None for a name."""
    from graphsvc.sensors.devices import DEVICES

    return None if value is None or value in ("guess", *DEVICES) else value


def print_note(note: str) -> None:
    """A remark for the user (an option the strategy ignores, say): `note: …` on stderr."""
    print(f"note: {note}", file=sys.stderr)


def print_notes(notes) -> None:
    for note in notes:
        print_note(note)


def print_flushed(line: str) -> None:
    print(line, flush=True)  # flushed: tests and tools read these lines from a pipe
