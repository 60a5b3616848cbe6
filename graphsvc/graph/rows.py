"""Row arrays: the distinct rows of an array, compared bit for bit (the search's
readings table, `strategies/viterbi/tables.py`, and the graph's bone sets,
`graph/poses.py`); parts gathered row block by row block concatenated while they
are freed (the build's node and edge arrays); and runs of consecutive ids (a record's
nodes, a node's incoming edges) joined."""

from __future__ import annotations

import numpy as np


def distinct_rows(rows: np.ndarray, hashes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of a (E, D) 4-byte array, compared bit for bit, numbered in
    order of first appearance: (first (R,) ascending, the index of each distinct row's
    first appearance; label (E,) int32, each row's number). Rows are hashed to 64 bits
    (FNV-1a over the words) and the hashes sorted — a 1-D sort, about 5× faster than
    numpy's row-wise unique on a 400k-edge graph; rows that share a hash but differ
    (checked) fall back to the row-wise unique. hashes: (E,) uint64 to use instead
    (tests force collisions with it)."""
    words = np.ascontiguousarray(rows).view(np.uint32).reshape(len(rows), -1)
    if hashes is None:
        hashes = np.full(len(words), 0xCBF29CE484222325, dtype=np.uint64)
        for j in range(words.shape[1]):
            hashes = (hashes ^ words[:, j]) * np.uint64(0x100000001B3)
    _, first, group = np.unique(hashes, return_index=True, return_inverse=True)
    if not np.array_equal(words[first[group.reshape(-1)]], words):
        _, first, group = np.unique(words, axis=0, return_index=True, return_inverse=True)
    by_first_use = np.argsort(first, kind="stable")
    label = np.empty(len(first), dtype=np.int32)
    label[by_first_use] = np.arange(len(first), dtype=np.int32)
    return first[by_first_use], label[group.reshape(-1)]


def drain(parts: list[np.ndarray], empty: tuple[int, ...], dtype) -> np.ndarray:
    """`np.concatenate(parts)` (or zeros of shape `empty` when there are none) that
    empties the list as it copies: the whole and one part held at once, not the whole
    twice, when nothing else holds the parts."""
    if not parts:
        return np.zeros(empty, dtype)
    out = np.empty((sum(len(p) for p in parts),) + parts[0].shape[1:], dtype=np.result_type(*parts))
    parts.reverse()
    at = 0
    while parts:
        part = parts.pop()
        out[at : at + len(part)] = part
        at += len(part)
    return out


def ranges(starts, counts) -> np.ndarray:
    """(sum(counts),) int64: starts[k], starts[k] + 1, …, starts[k] + counts[k] − 1 for
    each k in turn, `np.concatenate([s + np.arange(n) for s, n in zip(starts, counts)])`
    without a Python loop."""
    starts, counts = np.asarray(starts, dtype=np.int64), np.asarray(counts, dtype=np.int64)
    return np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()), dtype=np.int64)
