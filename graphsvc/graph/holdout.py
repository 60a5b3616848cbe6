"""Which nodes of a graph carry a clip's data: what leave-one-out evaluation hides.

What a held-out clip hides (its *performance*: the recorded take and its augmented
copies, as `graphsvc.graph.build._performance` groups them — same source, same name
once the `_mirror`/`_reverse` suffixes are removed):
- the original, slow-down and interpolated nodes whose `node_clip` is one of the
  performance's clips (slow-down nodes and interpolated segments are filed under their
  clip, interpolated ones under the segment's first clip, `clip_a`);
- the nodes of interpolated segments whose second clip (`clip_b`) is one of them, and
  of bridges from or to one of them (a bridge's nodes are filed under the clip that
  dominates each, so a bridge is hidden whole);
- the mirrored and reversed copies themselves.
"""

from __future__ import annotations

import re

import numpy as np

from graphsvc.graph.model import MotionGraph
from graphsvc.graph.rows import ranges

_AUGMENT_SUFFIX = re.compile(r"(_mirror|_reverse)+$")


def performance_key(source: str, name: str) -> tuple[str, str]:
    """What identifies one recorded performance across its augmented copies: the
    source and the name without `_mirror`/`_reverse` suffixes (the rule of
    `graphsvc.graph.build._performance`, on a graph's clip records)."""
    return str(source), _AUGMENT_SUFFIX.sub("", str(name))


def is_augmented(name: str) -> bool:
    """True for the mirrored or reversed copies the builder adds (not files of the KB)."""
    return _AUGMENT_SUFFIX.search(str(name)) is not None


def performance_clips(graph: MotionGraph, clip_index: int) -> np.ndarray:
    """(k,) int: indices of the graph clips of `clip_index`'s performance (itself included)."""
    want = performance_key(graph.clips[clip_index]["source"], graph.clips[clip_index]["name"])
    return np.array(
        [k for k, c in enumerate(graph.clips) if performance_key(c["source"], c["name"]) == want], dtype=np.int64
    )


def held_out_mask(graph: MotionGraph, clip_index: int | list[int]) -> np.ndarray:
    """(N,) bool `allowed` node mask for testing graph clip `clip_index` (or several,
    a joined performance's): False on every node derived from its performance (see
    the module docstring), True elsewhere."""
    indices = [clip_index] if np.ndim(clip_index) == 0 else list(clip_index)
    clips = np.unique(np.concatenate([performance_clips(graph, int(k)) for k in indices]))
    hidden = np.isin(np.asarray(graph.node_clip), clips)
    for recs in (graph.segments, graph.bridges):
        made = np.isin(recs.column("clip_a"), clips) | np.isin(recs.column("clip_b"), clips)
        hidden[ranges(recs.column("first_node")[made], recs.column("count")[made])] = True
    return ~hidden
