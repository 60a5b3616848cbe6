"""The service commands' help: every subcommand says what it does, every argument has
a help line, every default the service commands set is stated, and the live lag the
help states is the one a stream reports."""

from __future__ import annotations

import argparse

import pytest

SERVICE_COMMANDS = ("serve", "client", "sensor-bridge")
NO_DEFAULT = (None, False, argparse.SUPPRESS)


def _service_parsers():
    """(path, parser) of serve, client, sensor-bridge and every subcommand beneath them,
    as graphsvc's own parser builds them."""
    from graphsvc.cli import build_parser

    def walk(path, parser):
        yield path, parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    yield from walk((*path, name), sub)

    top = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name in SERVICE_COMMANDS:
        yield from walk((name,), top.choices[name])


def _shared_options() -> set[str]:
    """The strategy and calibration flags graphsvc.flags adds to many commands
    (their texts are the main CLI's)."""
    from graphsvc.flags import add_calibration_flag, add_search_flags

    p = argparse.ArgumentParser(add_help=False)
    add_search_flags(p)
    add_calibration_flag(p)
    return {s for a in p._actions for s in a.option_strings}


def test_every_service_subcommand_has_a_description_and_every_argument_a_help():
    parsers = list(_service_parsers())
    assert {p for p, _ in parsers} >= {
        ("serve",),
        ("client", "graphs"),
        ("client", "synthesize"),
        ("client", "stream"),
        ("client", "batch", "submit"),
        ("sensor-bridge",),
    }
    shared = _shared_options()
    missing = []
    for path, parser in parsers:
        if not (parser.description or "").strip():
            missing.append((path, "description"))
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            name = "/".join(action.option_strings) or action.dest
            if not (action.help or "").strip():
                missing.append((path, name, "help"))
            elif (
                action.option_strings
                and action.default not in NO_DEFAULT
                and not action.required
                and "default" not in action.help
                and not shared & set(action.option_strings)
            ):
                missing.append((path, name, f"default {action.default!r} not stated"))
    assert not missing, missing


@pytest.mark.parametrize("command", [("client", "stream"), ("sensor-bridge",)])
def test_live_help_states_the_lag_a_stream_has(command, capsys):
    """The lag of a stream with the default --latency on a 30 Hz graph, by hand: the
    decoder's 1 s = 30 frames, the synthesis' look-ahead ceil(0.35 × 30) + 1 = 12
    frames, its batches of 3 frames, up to 2 more, and the poses' filter, ceil(3σ) = 3
    frames at σ = 1/30 s: 47 frames, 47 / 30 = 1.57 s."""
    from graphsvc.cli import build_parser

    with pytest.raises(SystemExit):
        build_parser().parse_args([*command, "--help"])  # (what `graphsvc client stream --help` prints)
    text = " ".join(capsys.readouterr().out.split())
    assert "(default 1)" in text
    assert "round(S × rate) + 17 frames after its sample at 30 Hz" in text
    assert "47 frames (1.57 s) by default" in text
    assert "output lags the input by S seconds" not in text


def test_a_default_session_reports_the_lag_the_help_states(graph):
    from graphsvc.pipeline import Options, open_session

    assert graph.rate_hz == 30.0
    # the search's latency, the blend's half window, the root's step, the poses' filter's half width (3σ)
    assert open_session(graph, Options()).lag_frames == 30 + 12 + 2 + 3
    assert open_session(graph, Options(latency_s=0.5)).lag_frames == 15 + 12 + 2 + 3
    assert open_session(graph, Options(strategy="nearest")).lag_frames == 12 + 2
