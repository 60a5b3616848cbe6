"""The Viterbi search's own options (`options.option()` declarations: flags, checks, the
gRPC form and the report's settings are derived from them)."""

from __future__ import annotations

from dataclasses import dataclass

from graphsvc.strategies.options import option


@dataclass(frozen=True)
class ViterbiOptions:
    """beam: a cost; after each sample only the paths within it of the best one go on
    (faster on built graphs, no longer always the cheapest path; None: the exact
    search)."""

    beam: float | None = option(None, low=0.0, low_open=True, noun="a finite cost", aliases=("--beam",),
                                metavar="COST", help="beam search: after each sample keep only the paths within COST of "
                                                     "the best (faster; default: the exact search)")  # fmt: skip
