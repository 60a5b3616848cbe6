"""The interface every reconstruction strategy implements (`Strategy`).

A strategy turns a recording into motion on a graph's skeleton. It:

- declares the inputs it needs (`needs`: a recording without one is refused, naming
  it) and those it can use (`uses`: the others are ignored and the report lists them
  under `ignored_inputs`), from INPUTS;
- prepares an index from a graph (`prepare`: built on first use, held for the graph
  object; a strategy whose index is costly caches it beside the graph file, keyed by
  the file's checksum — `strategies.index`);
- reconstructs a whole recording (`reconstruct`), given the recording already
  checked and put on the graph's sample grid (`strategies.inputs.prepare_input`);
- opens a live session (`session_class`, a `strategies.live.LiveSession`:
  `push(sample) -> frames`, `flush()`);
- hides clips for leave-one-out evaluation (`allowed_mask`: for the graph strategies a
  node mask, `graph.holdout.held_out_mask`).

What they share lives beside this module: the checks and resampling of a recording
(`inputs`), where a reconstruction starts (`start`), the result types (`results`) and
the live session's sample handling (`live`), so a strategy writes only its own
decoding.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from graphsvc.graph.derived import derived
from graphsvc.graph.model import MotionGraph
from graphsvc.strategies.options import Options

if TYPE_CHECKING:  # (the modules below import this one)
    from graphsvc.strategies.inputs import PreparedInput
    from graphsvc.strategies.results import Reconstruction

INPUTS = ("accelerations", "orientations", "markers", "ground_position", "heading", "constraints")


class Strategy:
    """One way to reconstruct motion (module docstring). Subclasses set `name`, `needs`,
    `uses` and `summary`, and implement `prepare`, `reconstruct` and `session_class`."""

    name: str = ""
    needs: frozenset = frozenset()
    uses: frozenset = frozenset()
    summary: str = ""
    session_class: type = None  # a LiveSession subclass

    def prepare(self, graph: MotionGraph):
        """The strategy's index for `graph`, made once per graph object."""
        raise NotImplementedError

    def reconstruct(self, index, graph: MotionGraph, inp: "PreparedInput", options: Options,
                    allowed: np.ndarray | None = None, threads: bool = True, should_stop=None) -> "Reconstruction":  # fmt: skip
        raise NotImplementedError

    def warm_up(self, index, graph: MotionGraph, threads: bool = False) -> None:
        """Load compiled code and make tables now, not on a client's first sample."""

    def allowed_mask(self, graph: MotionGraph, clips) -> np.ndarray:
        """(N,) bool: the nodes a search may use when graph clips `clips` (their
        performances) are held out."""
        from graphsvc.graph.holdout import held_out_mask

        return held_out_mask(graph, clips)

    def ignored_options(self, options: Options) -> list[str]:
        """Options set to something this strategy does not use (for the report)."""
        return []


def frame_by_frame_ignored(options: Options) -> list[str]:
    """The options a strategy that decides each frame from its own sample ignores:
    the beam and the latency (no search over time to prune or to delay)."""
    return [name for name, v in (("beam", options.beam), ("latency_s", options.latency_s)) if v is not None]


def prepared_index(strategy: Strategy, graph: MotionGraph):
    """`strategy.prepare(graph)`, once per graph object and strategy (`graph.derived`:
    an index must not refer to its graph but weakly)."""
    return derived(graph, ("strategy index", strategy.name), lambda: strategy.prepare(graph))
