"""Reconstruction strategies behind one interface (`base.Strategy`), looked up by name.

The pipeline, the evaluation, the CLI, batch and the server find a strategy here and
nothing else; each strategy owns its options, its checks, its index, its batch
reconstruction and its live session.

| name | needs | also uses | good at |
| --- | --- | --- | --- |
| `viterbi` | accelerations | ground position, heading, constraints | whole actions from the graph: the path that best explains every stream over time |
| `nearest` | accelerations | (the track only to place the start) | nothing: per sample the nearest knowledge-base frame, the floor a search must beat |
| `olng` | accelerations | ground position, heading | frame by frame, poses no clip holds: per sample the neighbourhood of frames moving as the readings do (Tautges et al. 2011) and a pose optimised from it |
| `ssg` | labelled optical markers | | sparse, gappy markers: the knowledge base's subsequences that fit each window of the input, joined by a subsequence graph (Tautges 2012) |
| `piecewise` | accelerations | ground position, heading | frame by frame, poses no clip holds: per sample its cluster's local model of the readings, an RBF map to a reduced pose or a small optimisation (Xie 2009) |
| `multilinear` | accelerations | ground position, heading | whole recordings, poses no clip holds: per motion unit of the search's segmentation the mix of its class's takes whose simulated readings fit (Tautges 2012, ch. 2); no live streams |

A strategy is registered by `register(strategy)`: the built-in ones (BUILTIN, one line
each: a module whose `STRATEGY` is the instance) on first lookup, and every strategy an
installed package declares in the `graphsvc.strategies` entry-point group
(`name = "package.module:STRATEGY"`), so one installed as its own package reaches the
CLI, batch workers and the service's live-worker processes alike (docs/code-layout.md,
"Adding a strategy"). Importing this package compiles and loads nothing.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import replace
from importlib import import_module
from typing import TYPE_CHECKING

from graphsvc.errors import InputError, StrategyNotImplementedError
from graphsvc.strategies import options as _options
from graphsvc.strategies.base import Strategy
from graphsvc.strategies.options import Options, SharedOptions, check_common, option_specs

if TYPE_CHECKING:  # (importing this package loads no strategy, nor what a session needs)
    import numpy as np

    from graphsvc.graph.model import MotionGraph
    from graphsvc.strategies.live import LiveSession

DEFAULT = "viterbi"
ENTRY_POINTS = "graphsvc.strategies"
BUILTIN = (
    "graphsvc.strategies.viterbi",
    "graphsvc.strategies.nearest",
    "graphsvc.strategies.olng",
    "graphsvc.strategies.ssg",
    "graphsvc.strategies.piecewise",
    "graphsvc.strategies.multilinear",
)
PLANNED: tuple[str, ...] = ()  # specified, not built: asked for, they answer "not implemented yet"
_REGISTRY: dict[str, Strategy] = {}
_loaded = False


def register(strategy: Strategy) -> Strategy:
    """Make `strategy` (a `base.Strategy` instance) available by its name; the first
    registered under a name stays. Returns it."""
    if not isinstance(strategy, Strategy) or not strategy.name:
        raise TypeError(f"a strategy must be a named graphsvc.strategies.base.Strategy instance, got {strategy!r}")
    if strategy.session_class is None:
        raise TypeError(f"strategy {strategy.name!r} has no session_class")
    _REGISTRY.setdefault(strategy.name, strategy)
    return strategy


def _load() -> None:
    """The built-in strategies, then the installed ones (entry points), once."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    for module in BUILTIN:
        register(import_module(module).STRATEGY)
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group=ENTRY_POINTS), key=lambda e: e.name):
        try:
            register(ep.load())
        except Exception as exc:  # noqa: BLE001  (one broken plug-in must not stop the others)
            print(
                f"graphsvc: warning: strategy plug-in {ep.name!r} ({ep.value}) did not load: "
                f"{type(exc).__name__}: {exc}",
                file=sys.stderr,
            )


def get(name: str) -> Strategy:
    """The strategy called `name`: InputError if there is none, StrategyNotImplementedError
    for one that is specified but not built."""
    _load()
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name in PLANNED:
        raise StrategyNotImplementedError(f"strategy {name!r} is not implemented yet (use {', '.join(available())})")
    raise InputError(f"unknown strategy {name!r} (choose from {', '.join(names())})")


def available() -> tuple[str, ...]:
    """The strategies that are built, in registration order."""
    _load()
    return tuple(_REGISTRY)


def names() -> tuple[str, ...]:
    """Every strategy name a request may give: the built ones, then the planned ones."""
    return available() + tuple(n for n in PLANNED if n not in _REGISTRY)


def check_options(options: Options) -> Options:
    """`options` checked — what every strategy reads, the shared options, the chosen
    strategy's own (its declared fields and its rule) and every other strategy's given
    — and returned with the chosen strategy's own options filled in (its defaults where
    none were given): the settings a report shows. InputError (an `OptionError` naming
    the field) or StrategyNotImplementedError."""
    if not isinstance(options, Options):
        raise InputError(f"options must be graphsvc Options, got {type(options).__name__}")
    if not isinstance(options.strategy, str):
        raise InputError(f"strategy must be a name, got {options.strategy!r}")
    strategy = get(options.strategy)
    check_common(options)
    for name, own in options.settings:
        get(name).check_own(own)
    if options.own is not None:
        return options
    return replace(options, settings=(*options.settings, (options.strategy, strategy.options_class())))


def open_session(
    graph: MotionGraph,
    options: Options | None = None,
    sensor_names: Sequence[str] | None = None,
    allowed: np.ndarray | None = None,
    threads: bool = False,
    keep_motion: bool = True,
    marker_names: Sequence[str] | None = None,
    orientations: bool = False,
) -> LiveSession:
    """The live session of `options.strategy` on `graph` (its `session_class`, a
    `strategies.live.LiveSession`): samples in by `push`, pose frames out as they become
    final, `flush` at the end. sensor_names: the stream's sensors, in the graph's order
    (default: the graph's); allowed: (N,) bool node mask (hidden clips left out);
    threads: numba's threads in its steps; keep_motion: keep every frame for
    `motion()`; marker_names: the markers a stream of markers carries; orientations:
    its samples carry each sensor's orientation. InputError for options or a stream the
    strategy cannot take."""
    options = check_options(Options() if options is None else options)
    strategy = get(options.strategy)
    strategy.check_stream(options, sensor_names, marker_names)
    return strategy.session_class(
        strategy, graph, options, sensor_names, allowed, threads, keep_motion, marker_names, orientations
    )


def _legacy_names(name: str, default: bool = False):
    """Where an older `Options` field lives now (`options.LEGACY_NAMES`); with default,
    strategy `name`'s default own options."""
    if default:
        return get(name).options_class()
    if name in {s.name for s in option_specs(SharedOptions)}:
        return ("shared", name)
    if name in available():
        return ("strategy", name)
    flag = f"--{name.replace('_', '-')}"
    for s in _REGISTRY.values():
        for spec in option_specs(s.options_class):
            if flag in spec.aliases:
                return ("option", s.name, spec.name)
    return None


_options.LEGACY_NAMES = _legacy_names

__all__ = [
    "BUILTIN",
    "DEFAULT",
    "ENTRY_POINTS",
    "Strategy",
    "available",
    "check_options",
    "get",
    "names",
    "open_session",
    "register",
]
