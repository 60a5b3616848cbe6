"""The Viterbi search's own options (`options.option()` declarations: flags, checks, the
gRPC form and the report's settings are derived from them)."""

from __future__ import annotations

from dataclasses import dataclass

from graphsvc.strategies.options import option


@dataclass(frozen=True)
class ViterbiOptions:
    """beam: a cost; after each sample only the paths within it of the best one go on
    (faster on built graphs, no longer always the cheapest path; None: the exact
    search). live_paths: with a beam and a latency (a live stream, or `--latency`), the
    search keeps at most this many paths live after each sample, the cheapest, and
    starts at this many chosen by how well their edges' readings fit its second sample
    (`stream.FixedLagDecoder`'s max_live; 0: the beam alone, every node starting a path)."""

    beam: float | None = option(
        None,
        low=0.0,
        low_open=True,
        noun="a finite cost",
        aliases=("--beam",),
        metavar="COST",
        help="beam search: after each sample keep only the paths within COST of "
        "the best (faster; default: the exact search)",
    )
    live_paths: int = option(
        4096,
        low=0,
        metavar="PATHS",
        label="Viterbi live paths",
        help="with --beam and a latency (live): keep at most the PATHS cheapest paths after each "
        "sample, and start at the PATHS whose edges' readings fit the second sample best "
        "(default 4096; 0: the beam alone, every node starting a path, as a batch search)",
    )
