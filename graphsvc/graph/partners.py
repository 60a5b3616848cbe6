"""Which clips blend with which: the interpolation partners of the motion graph.

Each clip blends with its few best partners among the clips of its content label
(`BuildOptions.interp_partners`, `build._add_interpolations`), ranked by the share of
its frames (every 0.1 s) that have a frame of equal contact state closer than the
interpolation threshold in the partner. A clip and its own mirror or reversal are one
performance and never partners.

Ranking every pair of a label's clips costs the square of the clips: on the pooled and
augmented Bandai-Namco set (≈ 530 clips a label) that is 1.4 million distance blocks,
the build's one stage quadratic in the data. Labels with more than `EXACT_MAX_CLIPS`
clips are ranked through a clip-level index instead: one kd-tree per contact state
over the rotation-invariant descriptors of all the label's sampled frames (a lower
bound of the frame distance, `transitions.invariant_points`), each frame's
`NEIGHBOURS` nearest within the threshold, their exact distances, and a clip's score
toward another the share of its frames whose close neighbours include one of the
other's. The work is linear in the frames; a frame with more than `NEIGHBOURS` close
frames credits only the nearest, which favours the closest clips — the ones the
blend wants. Labels as small as today's Bandai-Namco ones (at most 58 clips) keep the
all-pairs ranking, so their graph does not change.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from graphsvc.graph import interpolation as interp
from graphsvc.graph.distance import PoseFeatures, concat_features, distance_block, distance_pairs
from graphsvc.graph.transitions import invariant_points, search_radius

EXACT_MAX_CLIPS = 64  # labels with at most this many clips: every pair ranked
NEIGHBOURS = 48  # descriptor neighbours of a sampled frame in the indexed ranking
_CHUNK = 8192  # pairs per exact-distance call


def exact_scores(
    sampled: Sequence[tuple[PoseFeatures, np.ndarray]],
    members: Sequence[int],
    performance: Sequence[Hashable],
    threshold_m: float,
) -> dict[tuple[int, int], float]:
    """score[a, b]: the share of a's sampled frames with a frame of b of the same contact
    state closer than threshold_m, over every ordered pair of members (0 for one
    performance)."""
    score = {}
    for k, a in enumerate(members):
        for b in members[k + 1 :]:
            # A clip and its own mirror or reversal are one performance: blending
            # a left punch with its mirrored right punch makes neither.
            if performance[a] == performance[b]:
                score[a, b] = score[b, a] = 0.0
                continue
            distance = distance_block(sampled[a][0], sampled[b][0])
            same = interp.same_contact_matrix(sampled[a][1], sampled[b][1])
            close = np.where(same, distance, np.inf) < threshold_m
            score[a, b] = float(close.any(axis=1).mean())
            score[b, a] = float(close.any(axis=0).mean())
    return score


def indexed_scores(
    sampled: Sequence[tuple[PoseFeatures, np.ndarray]],
    members: Sequence[int],
    performance: Sequence[Hashable],
    threshold_m: float,
    neighbours: int = NEIGHBOURS,
) -> dict[tuple[int, int], float]:
    """`exact_scores` through the clip-level index of the module docstring: only the
    pairs with a score above 0 are returned, and a frame counts toward a clip only if
    one of its `neighbours` nearest frames (by descriptor) is of that clip."""
    feats = concat_features([sampled[m][0] for m in members])
    contacts = np.concatenate([np.asarray(sampled[m][1], dtype=bool) for m in members])
    lengths = np.array([sampled[m][0].num_frames for m in members], dtype=np.int64)
    owner = np.repeat(np.arange(len(members)), lengths)
    perf_codes: dict = {}
    perf = np.array([perf_codes.setdefault(performance[m], len(perf_codes)) for m in members])[owner]
    every = np.arange(feats.num_frames)
    points = invariant_points(feats)
    radius = search_radius(feats, every, threshold_m)
    state = contacts[:, 0].astype(np.int64) * 2 + contacts[:, 1]
    rows, cols = [np.empty(0, np.int64)], [np.empty(0, np.int64)]
    for s in np.unique(state):
        idx = np.flatnonzero(state == s)
        if idx.size < 2:
            continue
        k = min(neighbours + 1, idx.size)  # +1: each frame finds itself
        dist, nbr = cKDTree(points[idx]).query(points[idx], k=k, distance_upper_bound=radius)
        ok = np.isfinite(dist)
        rows.append(np.repeat(idx, k).reshape(idx.size, k)[ok])
        cols.append(idx[nbr[ok]])
    r, c = np.concatenate(rows), np.concatenate(cols)
    keep = (owner[r] != owner[c]) & (perf[r] != perf[c])
    r, c = r[keep], c[keep]
    d = np.concatenate(
        [distance_pairs(feats, r[s : s + _CHUNK], feats, c[s : s + _CHUNK]) for s in range(0, r.size, _CHUNK)]
        or [np.empty(0)]
    )
    r, c = r[d < threshold_m], c[d < threshold_m]
    # Distinct (frame, other clip) pairs, then per (clip, other clip) their count.
    hit = np.unique(r * len(members) + owner[c])
    frame, other = hit // len(members), hit % len(members)
    pair = owner[frame] * len(members) + other
    cells, counts = np.unique(pair, return_counts=True)
    a, b = cells // len(members), cells % len(members)
    share = counts / lengths[a]
    return {(int(members[i]), int(members[j])): float(v) for i, j, v in zip(a, b, share)}


def choose_partners(
    sampled: Sequence[tuple[PoseFeatures, np.ndarray]],
    by_label: Sequence[Sequence[int]],
    performance: Sequence[Hashable],
    threshold_m: float,
    partners: int,
    exact_max_clips: int = EXACT_MAX_CLIPS,
    bar: Callable = lambda it, **kw: it,
) -> set[tuple[int, int]]:
    """The clip pairs (a < b) to blend: each clip's `partners` best-scored clips of its
    label (ties by clip index). sampled[c]: clip c's features and contacts every 0.1 s;
    by_label: each label's clips; performance[c]: what identifies c's recording."""
    chosen: set[tuple[int, int]] = set()
    for members in bar(list(by_label), desc="similarity", unit="label"):
        members = list(members)
        if len(members) <= exact_max_clips:
            score = exact_scores(sampled, members, performance, threshold_m)
        else:
            score = indexed_scores(sampled, members, performance, threshold_m)
        for a in members:
            ranked = sorted(
                (b for b in members if b != a and score.get((a, b), 0.0) > 0), key=lambda b: (-score[a, b], b)
            )
            chosen.update((min(a, b), max(a, b)) for b in ranked[:partners])
    return chosen
