"""Transition candidates of a motion graph (Kelly et al. 2013, §4, after Safonova and Hodgins).

The knowledge base is C clips concatenated on one frame axis of N frames. A
transition (i, j) means "after frame i, continue with the frame that follows j":
the graph turns it into the edge i → j+1. It is allowed only when

- frames i and j have the same foot-contact state (two bools) and a contact change
  happens at both (frame 0 of a clip never counts);
- j+1 exists in j's clip; i ≠ j, and pairs in the same clip are at least
  `exclude_same_clip_within` frames apart;
- the aligned point-cloud distance D(i, j) (`distance.py`, RMS metres) is at most
  `threshold_m`;
- D(i, j) is a local minimum: no other candidate cell (i', j') of the 2-D distance
  matrix with i' in i's clip, j' in j's clip, the same contact state,
  |i'−i| ≤ r and |j'−j| ≤ r (r = `local_min_radius` frames) is smaller. Ties are
  broken by (src, dst), so of equal neighbours exactly one survives.

Why compare only with candidate cells: transitions live on contact-change frames
only, and those are usually not where the full matrix has its minimum (along a
valley of two similar gaits D(i+1, j+1) ≈ D(i, j), so an 8-neighbour test against
arbitrary frames would reject good cells at random). What the test must remove is
clusters of near-duplicate candidates (contact flags flickering for a few frames,
two heel strikes a frame apart); comparing candidates within ±r does that. Cells of
another contact state do not compete: a heel strike and the toe-off ending double
support ~3 frames later are different transitions, both worth keeping. A
neighbour above the threshold can never beat a cell below it, so only candidates
under the threshold need comparing — which keeps the indexed search exact.

Search without all pairs: every candidate frame gets a rotation- and
translation-invariant descriptor whose Euclidean distance is a LOWER BOUND of D —
the √w-scaled heights y (a rotation about +Y and a ground translation leave them
unchanged) and the √w-scaled ground radii |(x, z)| about the cloud centre (per point
||a| − |R b|| ≤ |a − R b|). An orthonormal PCA projection only shrinks distances, so
a kd-tree radius query at the threshold returns every pair that can pass, and the
exact closed-form distances are computed for those pairs only.

That superset still grows with the square of near-identical clips: fifteen styles of
one walk, each with its mirrored and reversed copies, put every heel strike within the
threshold of hundreds of others (4.8M candidate pairs at 153k augmented frames, 23 s of
a build's time). The build therefore bounds it (`k`, `BuildOptions.transition_candidates`,
128): each frame's k nearest descriptors within the radius. A frame keeps at most 8
transitions (`max_per_source`), and the lower bound ranks its true neighbours well:
at 153k frames k = 128 finds 99.98 % of the exact search's transitions (64: 99.68 %)
from 1.35M pairs in 6.9 s, Bandai dataset 2 all but 1 of 47,112 (2 more), dataset 2
without its takes 004 exactly the same 34,599.

Default threshold, measured on Bandai dataset-2 (30 Hz): two consecutive frames of
one clip are 0.025 m apart (median; 90 % below 0.038 m) in walks and 0.040 m
(0.062 m) in runs; equal-state contact-change frames of different clips of one walk
style are 0.025 m apart (median), of any two walk styles 0.087 m. 0.05 m — a jump no
larger than a natural frame step of a run — keeps transitions smooth without
merging every walking style into every other, as 0.08 m would.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from graphsvc.blas import one_thread
from graphsvc.errors import InputError
from graphsvc.graph.distance import (
    PoseFeatures,
    alignment,
    distance_block,
    distance_pairs,
    take,
)

DEFAULT_THRESHOLD_M = 0.05
DEFAULT_EXCLUDE_WITHIN = 10  # frames (1/3 s at 30 Hz): closer same-clip pairs are trivial
DEFAULT_LOCAL_MIN_RADIUS = 5  # frames (1/6 s at 30 Hz): spans contact-flag flicker
DEFAULT_PCA_DIMS = 16
_PAIR_CHUNK = 8192  # pairs per exact-distance call: bounds the gathered (chunk, n) float64 copies


@dataclass(frozen=True)
class Transitions:
    """T transitions sorted by (src, dst). src, dst: (T,) int64 frame indices on the
    KB axis (edge src → dst+1); distance: (T,) aligned RMS distance in metres;
    theta: (T,) radians about +Y and translation: (T, 2) (x, z) metres of the rigid
    ground motion taking cloud dst onto cloud src (src ≈ R_y(θ)·dst + t)."""

    src: np.ndarray
    dst: np.ndarray
    distance: np.ndarray
    theta: np.ndarray
    translation: np.ndarray

    def __len__(self) -> int:
        return int(self.src.shape[0])


@dataclass(frozen=True)
class KBFrames:
    """Per-frame facts the rules need, on the KB axis of N frames (see `kb_frames`)."""

    contacts: np.ndarray  # (N, 2) bool
    clip: np.ndarray  # (N,) int64
    in_clip: np.ndarray  # (N,) int64
    is_change: np.ndarray  # (N,) bool, contact change not at a clip's frame 0
    has_next: np.ndarray  # (N,) bool, frame+1 exists in the same clip


def kb_frames(features, contacts, changes, clip_of_frame, frame_in_clip, clip_lengths) -> KBFrames:
    """Validate the per-frame inputs of `find_transitions` and derive the flags the
    rules use (a change at a clip's frame 0 is dropped: the clip boundary is not a
    contact event)."""
    N = features.num_frames
    contacts = np.asarray(contacts, dtype=bool)
    changes = np.asarray(changes, dtype=bool)
    clip = np.asarray(clip_of_frame, dtype=np.int64)
    in_clip = np.asarray(frame_in_clip, dtype=np.int64)
    lengths = np.asarray(clip_lengths, dtype=np.int64)
    if contacts.shape != (N, 2) or changes.shape != (N,) or clip.shape != (N,) or in_clip.shape != (N,):
        raise InputError(
            f"expected contacts (N, 2) and changes, clip_of_frame, frame_in_clip (N,) with N = {N}; "
            f"got {contacts.shape}, {changes.shape}, {clip.shape}, {in_clip.shape}"
        )
    if N and (
        clip.min() < 0 or clip.max() >= lengths.shape[0] or np.any(in_clip < 0) or np.any(in_clip >= lengths[clip])
    ):
        raise InputError("clip_of_frame / frame_in_clip do not fit clip_lengths")
    return KBFrames(contacts, clip, in_clip, changes & (in_clip > 0), in_clip + 1 < lengths[clip])


def _invariant_descriptors(features: PoseFeatures) -> np.ndarray:
    """(F, 2n) float64 [y, √(x² + z²)] per cloud point: |d_a − d_b| ≤ D(a, b)."""
    x, z, y = (v.astype(np.float64) for v in (features.x, features.z, features.y))
    return np.concatenate([y, np.hypot(x, z)], axis=1)


def _project(desc: np.ndarray, dims: int) -> np.ndarray:
    """Centred descriptors onto their top `dims` principal axes (orthonormal, so
    projected distances never exceed the original ones)."""
    centred = desc - desc.mean(axis=0)
    if dims >= desc.shape[1]:
        return centred
    with one_thread():  # (the same axes however many threads BLAS has: graphsvc.blas)
        _, vecs = np.linalg.eigh(centred.T @ centred)
        return centred @ vecs[:, ::-1][:, :dims]


def invariant_points(features: PoseFeatures, dims: int = DEFAULT_PCA_DIMS) -> np.ndarray:
    """(F, dims) the frames' rotation-invariant descriptors on their top principal axes:
    Euclidean distances between rows never exceed the frame distance D."""
    return _project(_invariant_descriptors(features), dims)


def search_radius(features: PoseFeatures, frames: np.ndarray, threshold_m: float) -> float:
    # The closed form cancels large terms held in float32, so a computed distance can
    # sit a hair below the true one; widen the radius by that rounding so the lower
    # bound stays a bound for the distances actually computed.
    slack = 1e-5 * float(features.norm2[frames].max(initial=0.0))
    return float(np.sqrt(threshold_m**2 + slack))


def _candidate_frames(fr: KBFrames) -> np.ndarray:
    """(M,) sorted frame indices with a contact change (not at a clip's frame 0)."""
    return np.flatnonzero(fr.is_change)


def _state_code(contacts: np.ndarray) -> np.ndarray:
    return contacts[:, 0].astype(np.int64) * 2 + contacts[:, 1]


def indexed_pairs(
    features: PoseFeatures, fr: KBFrames, threshold_m: float, k: int | None = None, pca_dims: int = DEFAULT_PCA_DIMS
) -> np.ndarray:
    """(Q, 2) unordered pairs (a < b) of contact-change frames with equal contact
    state whose descriptor distance allows D ≤ threshold (a superset of the pairs
    under the threshold). One kd-tree per contact state. k: if given, each frame
    keeps only its k nearest descriptors within the radius (bounded work on huge
    KBs, no longer exact when a frame has more than k close neighbours)."""
    frames = _candidate_frames(fr)
    out = [np.empty((0, 2), dtype=np.int64)]
    if frames.size < 2:
        return out[0]
    radius = search_radius(features, frames, threshold_m)
    points = invariant_points(take(features, frames), pca_dims)
    state = _state_code(fr.contacts[frames])
    for s in np.unique(state):
        members = np.flatnonzero(state == s)
        if members.size < 2:
            continue
        tree = cKDTree(points[members])
        if k is None:
            local = tree.query_pairs(radius, output_type="ndarray")
        else:
            kk = min(k + 1, members.size)  # +1: each point finds itself
            dist, nbr = tree.query(points[members], k=kk, distance_upper_bound=radius)
            row = np.repeat(np.arange(members.size), kk)
            ok = np.isfinite(dist.ravel()) & (nbr.ravel() != row)
            local = np.stack([row[ok], nbr.ravel()[ok]], axis=1)
        if local.size:
            out.append(frames[members[local]])
    pairs = np.concatenate(out)
    pairs = np.sort(pairs, axis=1)
    return np.unique(pairs, axis=0) if pairs.size else pairs


def bruteforce_pairs(features: PoseFeatures, fr: KBFrames, threshold_m: float) -> np.ndarray:
    """Reference for `indexed_pairs` on small KBs: `distance_block` over all
    contact-change frames, pairs (a < b) with equal contact state and D ≤ threshold
    (plus the same rounding slack)."""
    frames = _candidate_frames(fr)
    if frames.size < 2:
        return np.empty((0, 2), dtype=np.int64)
    sub = take(features, frames)
    d = distance_block(sub, sub)
    state = _state_code(fr.contacts[frames])
    ok = (d <= search_radius(features, frames, threshold_m)) & (state[:, None] == state[None, :])
    ia, ib = np.nonzero(np.triu(ok, k=1))
    return np.stack([frames[ia], frames[ib]], axis=1).astype(np.int64)


def local_minima(src: np.ndarray, dst: np.ndarray, dist: np.ndarray, group: np.ndarray, radius: int) -> np.ndarray:
    """(T,) bool: cell (src, dst) has no neighbour among the given cells with the same
    group, |Δsrc| ≤ radius, |Δdst| ≤ radius and a smaller (distance, src, dst) key.
    group (T,) ints: cells compare only within a group (same clips, same state)."""
    T = src.shape[0]
    keep = np.ones(T, dtype=bool)
    if T < 2 or radius < 1:
        return keep
    rank = np.empty(T, dtype=np.int64)
    rank[np.lexsort((dst, src, dist))] = np.arange(T)
    # Chebyshev box search on integer cell coordinates; pairs from other groups
    # (e.g. straddling a clip boundary on the concatenated axis) are dropped below.
    cells = np.stack([src, dst], axis=1).astype(np.float64)
    pairs = cKDTree(cells).query_pairs(radius + 0.5, p=np.inf, output_type="ndarray")
    if pairs.size == 0:
        return keep
    a, b = pairs[:, 0], pairs[:, 1]
    same = group[a] == group[b]
    a, b = a[same], b[same]
    keep[np.where(rank[a] > rank[b], a, b)] = False
    return keep


def best_per_source(src: np.ndarray, dist: np.ndarray, limit: int) -> np.ndarray:
    """(T,) bool: the `limit` smallest distances of each source frame (ties by order)."""
    order = np.lexsort((np.arange(src.shape[0]), dist, src))
    s = src[order]
    first = np.searchsorted(s, s, side="left")  # start of each source's run
    keep = np.zeros(src.shape[0], dtype=bool)
    keep[order] = np.arange(s.shape[0]) - first < limit
    return keep


def _pair_distances(features: PoseFeatures, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`distance_pairs` of frames a[k], b[k], in chunks (each call gathers six
    (chunk, n) float64 arrays; unchunked that is gigabytes on a large KB)."""
    parts = [
        distance_pairs(features, a[s : s + _PAIR_CHUNK], features, b[s : s + _PAIR_CHUNK])
        for s in range(0, a.shape[0], _PAIR_CHUNK)
    ]
    return np.concatenate(parts) if parts else np.empty(0)


def _pair_alignment(features: PoseFeatures, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`alignment` (cloud b[k] onto cloud a[k]) in chunks, as `_pair_distances`."""
    parts = [
        alignment(features, a[s : s + _PAIR_CHUNK], features, b[s : s + _PAIR_CHUNK])
        for s in range(0, a.shape[0], _PAIR_CHUNK)
    ]
    if not parts:
        return np.empty(0), np.empty((0, 2))
    return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _empty() -> Transitions:
    e = np.empty(0, dtype=np.int64)
    return Transitions(e, e.copy(), np.empty(0), np.empty(0), np.empty((0, 2)))


def transitions_from_pairs(
    features: PoseFeatures,
    fr: KBFrames,
    pairs: np.ndarray,
    threshold_m: float,
    exclude_same_clip_within: int,
    local_min_radius: int,
    max_per_source: int | None = None,
) -> Transitions:
    """Exact distances for unordered candidate pairs (Q, 2), both directions, then
    the rules of the module docstring. Shared by the indexed and brute-force paths
    so both decide on identical numbers."""
    if pairs.shape[0] == 0:
        return _empty()
    a, b = pairs[:, 0], pairs[:, 1]
    d = _pair_distances(features, a, b)  # D is symmetric: one evaluation per pair
    keep = (d <= threshold_m) & np.all(fr.contacts[a] == fr.contacts[b], axis=1)
    near = (fr.clip[a] == fr.clip[b]) & (np.abs(a - b) < max(exclude_same_clip_within, 1))
    keep &= ~near
    a, b, d = a[keep], b[keep], d[keep]
    src = np.concatenate([a, b])
    dst = np.concatenate([b, a])
    dist = np.concatenate([d, d])
    ok = fr.has_next[dst]  # the edge goes to dst+1, which must exist in dst's clip
    src, dst, dist = src[ok], dst[ok], dist[ok]
    # Neighbours compete only within one (clip of src, clip of dst, contact state):
    # a heel strike and the toe-off a few frames later are different transitions.
    group = (fr.clip[src] * (fr.clip.max() + 1) + fr.clip[dst]) * 4 + _state_code(fr.contacts[src])
    minimum = local_minima(src, dst, dist, group, local_min_radius)
    src, dst, dist = src[minimum], dst[minimum], dist[minimum]
    if max_per_source is not None:
        best = best_per_source(src, dist, max_per_source)
        src, dst, dist = src[best], dst[best], dist[best]
    order = np.lexsort((dst, src))
    src, dst, dist = src[order], dst[order], dist[order]
    theta, shift = _pair_alignment(features, src, dst)
    return Transitions(src, dst, dist, theta, shift)


def find_transitions(
    features: PoseFeatures,
    contacts: np.ndarray,
    changes: np.ndarray,
    clip_of_frame: np.ndarray,
    frame_in_clip: np.ndarray,
    clip_lengths: np.ndarray,
    threshold_m: float = DEFAULT_THRESHOLD_M,
    k: int | None = None,
    exclude_same_clip_within: int = DEFAULT_EXCLUDE_WITHIN,
    local_min_radius: int = DEFAULT_LOCAL_MIN_RADIUS,
    pca_dims: int = DEFAULT_PCA_DIMS,
    max_per_source: int | None = None,
) -> Transitions:
    """Transitions of a KB of N frames (module docstring), kd-tree indexed.

    features: `pose_features` of all clips concatenated (`concat_features`);
    contacts (N, 2) bool; changes (N,) bool per-clip `contact_changes`;
    clip_of_frame, frame_in_clip (N,) ints; clip_lengths (C,) frames.
    threshold_m: RMS metres. k: None for the exact radius search, else at most k
    nearest descriptor neighbours per frame. exclude_same_clip_within, local_min_radius:
    frames. pca_dims: kd-tree dimension. max_per_source: if given, each source frame
    keeps only its that many closest transitions (applied after the local-minimum
    test; bounds the out-degree on KBs of many similar clips)."""
    fr = kb_frames(features, contacts, changes, clip_of_frame, frame_in_clip, clip_lengths)
    pairs = indexed_pairs(features, fr, threshold_m, k=k, pca_dims=pca_dims)
    return transitions_from_pairs(
        features, fr, pairs, threshold_m, exclude_same_clip_within, local_min_radius, max_per_source
    )


def find_transitions_bruteforce(
    features: PoseFeatures,
    contacts: np.ndarray,
    changes: np.ndarray,
    clip_of_frame: np.ndarray,
    frame_in_clip: np.ndarray,
    clip_lengths: np.ndarray,
    threshold_m: float = DEFAULT_THRESHOLD_M,
    exclude_same_clip_within: int = DEFAULT_EXCLUDE_WITHIN,
    local_min_radius: int = DEFAULT_LOCAL_MIN_RADIUS,
    max_per_source: int | None = None,
) -> Transitions:
    """All-pairs reference of `find_transitions` (quadratic in contact-change frames;
    small KBs and tests only)."""
    fr = kb_frames(features, contacts, changes, clip_of_frame, frame_in_clip, clip_lengths)
    pairs = bruteforce_pairs(features, fr, threshold_m)
    return transitions_from_pairs(
        features, fr, pairs, threshold_m, exclude_same_clip_within, local_min_radius, max_per_source
    )
