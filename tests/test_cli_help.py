"""Every command says what it does: the top-level help describes graphsvc for a user,
every subcommand has a description, every argument a help line, and every default
that is a value is named in its help."""

from __future__ import annotations

import argparse

import pytest

from graphsvc.cli import build_parser

SERVICE = {"serve", "client", "sensor-bridge"}  # (the service's commands: tests/service)


def _subparsers(parser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            yield from action.choices.items()


def _commands(parser, prefix=()):
    for name, sub in _subparsers(parser):
        yield (*prefix, name), sub
        yield from _commands(sub, (*prefix, name))


def _main_commands():
    return [(path, p) for path, p in _commands(build_parser()) if path[0] not in SERVICE]


def test_the_top_level_help_describes_graphsvc_for_a_user(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--help"])
    out = capsys.readouterr().out
    assert "reconstructs full-body human motion" in out
    assert "No logic of its own" not in out and "parses arguments" not in out


@pytest.mark.parametrize("path", [" ".join(p) for p, _ in _main_commands()])
def test_every_command_and_argument_has_a_help_line(path):
    parser = dict((" ".join(p), sub) for p, sub in _main_commands())[path]
    assert parser.description and len(parser.description) > 20, f"{path}: no description"
    missing = [
        a.dest for a in parser._actions if not isinstance(a, argparse._HelpAction) and not (a.help or "").strip()
    ]
    assert missing == [], f"{path}: arguments without help: {missing}"


@pytest.mark.parametrize("path", [" ".join(p) for p, _ in _main_commands()])
def test_every_value_default_is_stated(path):
    parser = dict((" ".join(p), sub) for p, sub in _main_commands())[path]
    unstated = [
        a.dest
        for a in parser._actions
        if a.default not in (None, False, argparse.SUPPRESS)
        and not isinstance(a, argparse._HelpAction)
        and "default" not in (a.help or "")
    ]
    assert unstated == [], f"{path}: defaults not named in the help: {unstated}"


def test_synthesize_help_has_no_argument_without_a_line(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["synthesize", "--help"])
    out = capsys.readouterr().out
    # argparse prints an argument with no help as its flags alone on a line
    lines = out.splitlines()
    body = lines[lines.index("positional arguments:") :]
    bare = [
        line
        for line in body
        if line.startswith("  ")
        and not line.startswith("   ")
        and len(line.split("  ")) < 3
        and (line.strip().startswith("-") or line.strip().isupper())
        and not line.rstrip().endswith(":")
    ]
    # a flag whose help starts on the next line is followed by a deeper-indented line
    bare = [line for line in bare if not _continued(lines, line)]
    assert bare == [], bare


def _continued(lines, line) -> bool:
    k = lines.index(line)
    return k + 1 < len(lines) and lines[k + 1].startswith(" " * 10) and lines[k + 1].strip() != ""
