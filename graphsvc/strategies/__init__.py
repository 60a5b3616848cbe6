"""Reconstruction strategies behind one interface (`base.Strategy`), looked up by name.

The pipeline, the evaluation, the CLI and the server find a strategy here and nothing
else; each strategy owns its index, its batch reconstruction and its live session.

| name | needs | also uses | good at |
| --- | --- | --- | --- |
| `viterbi` | accelerations | ground position, heading, constraints | whole actions from the graph: the path that best explains every stream over time |
| `nearest` | accelerations | (the track only to place the start) | nothing: per sample the nearest knowledge-base frame, the floor a search must beat |
| `olng` | accelerations | ground position, heading | frame by frame, poses no clip holds: per sample the neighbourhood of frames moving as the readings do (Tautges et al. 2011) and a pose optimised from it |
| `ssg` | labelled optical markers | | sparse, gappy markers: the knowledge base's subsequences that fit each window of the input, joined by a subsequence graph (Tautges 2012) |

`register` adds one (a `Strategy` instance); the built-in ones load on first lookup, so
importing this package compiles and loads nothing.
"""

from __future__ import annotations

from graphsvc.errors import InputError, StrategyNotImplementedError
from graphsvc.strategies.base import Strategy

PLANNED: tuple[str, ...] = ()
_REGISTRY: dict[str, Strategy] = {}
_loaded = False


def register(strategy: Strategy) -> None:
    _REGISTRY[strategy.name] = strategy


def _builtins() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    from graphsvc.strategies.nearest import NearestStrategy
    from graphsvc.strategies.olng.strategy import OlngStrategy
    from graphsvc.strategies.ssg import SsgStrategy
    from graphsvc.strategies.viterbi import ViterbiStrategy

    for s in (ViterbiStrategy(), NearestStrategy(), OlngStrategy(), SsgStrategy()):
        _REGISTRY.setdefault(s.name, s)


def get(name: str) -> Strategy:
    """The strategy called `name`: InputError if there is none, StrategyNotImplementedError
    for one that is specified but not built."""
    _builtins()
    if name in _REGISTRY:
        return _REGISTRY[name]
    if name in PLANNED:
        raise StrategyNotImplementedError(f"strategy {name!r} is not implemented yet (use {', '.join(available())})")
    raise InputError(f"unknown strategy {name!r} (choose from {', '.join(names())})")


def available() -> tuple[str, ...]:
    """The strategies that are built, in registration order."""
    _builtins()
    return tuple(_REGISTRY)


def open_session(graph, options=None, sensor_names=None, allowed=None, threads: bool = False,
                 keep_motion: bool = True, marker_names=None, orientations: bool = False):
    """The live session of `options.strategy` on `graph` (its `session_class`, a
    `strategies.live.LiveSession`): samples in by `push`, pose frames out as they become
    final, `flush` at the end. sensor_names: the stream's sensors, in the graph's order
    (default: the graph's); allowed: (N,) bool node mask (hidden clips left out);
    threads: numba's threads in its steps; keep_motion: keep every frame for
    `motion()`; marker_names: the markers a stream of markers carries; orientations:
    its samples carry each sensor's orientation. InputError for options or a stream the
    strategy cannot take."""
    from graphsvc.strategies.options import Options

    options = Options() if options is None else options
    return get(options.strategy).session_class(graph, options, sensor_names, allowed, threads, keep_motion, marker_names,
                                               orientations)  # fmt: skip


def names() -> tuple[str, ...]:
    """Every strategy name a request may give: the built ones, then the planned ones."""
    return available() + tuple(n for n in PLANNED if n not in _REGISTRY)
