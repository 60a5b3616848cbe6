"""Bridges: blended transitions that connect actions: a search can only follow what the graph connects.

Plain transitions (`transitions.py`) join frames whose windowed poses nearly coincide
(5 cm) at a foot-contact change. On a knowledge base of single-action clips they never
join a walk to a run (walking's double support never meets running's flight at a
contact change, and the two gaits' windows differ by more than 5 cm) nor locomotion to
a standing gesture (a moving window never matches a standing one). A bridge joins two
clips whose frames are further apart through a short run of new nodes that blend one
clip into the other, and those nodes carry the readings of the blend, so the search
scores what the transition plays.

**Matches.** A pair (frame i of clip a, frame j of clip b) qualifies when the two frames
have a planted foot in common (no bridge starts or ends in flight; a run's single
support may meet a standing pose, the other foot landing during the blend) and the
clips are different performances. It is scored by the windowed point-cloud distance D
(`distance.py`) of the two frames' poses relative to their own root ground position
(`body_features`): the pose and how the limbs move over the window, not how fast the
body travels, which the blend changes on its own (with the travel in, a 1 m/s walk and
a 3.7 m/s run of one performer were never within 0.25 m). Candidates come from frames
every 0.1 s through a heading-normalised feature (the canonical joints at t − 0.1 s, t
and t + 0.1 s, each relative to its own root and turned by frame t's heading; 24
principal axes), searched as a dense float32 distance matrix in row blocks, best per
target label; the three best per slot are then scored by D.

**Which bridges** (`select_matches`):
- per clip a, per other label λ and per `spacing_s` of a's timeline, the match toward
  any clip of λ with the smallest D, and the one toward a clip of λ by a's own
  performer (equal skeleton offsets: one person walks, then runs), when D ≤
  `threshold_m`; and, D being symmetric, per clip b, λ and `spacing_s` of b's timeline
  the best match from any clip of λ into b — so from every stretch of every clip each
  other action is one blend away, and every stretch is reached from each other action.
  Only label pairs that the graph without bridges connects slowly get them (`needed`);
- from each clip's last frame with a foot down, and into each clip's first, the best
  match with any other performance (any label), when D ≤ `end_threshold_m` — so no
  clip ends in a dead end and none starts where nothing enters.

**Blend** (`blend_bridges`). A bridge of L nodes enters from frame p of a and leaves
to frame q of b; node k (1 … L) pairs a's frame p + k with b's frame q − L − 1 + k
(clamped to each clip: past its end a clip holds its end frame) and weighs b by
w_k = smoothstep(k / (L + 1)):
- local rotations and translations of the joints below the pelvis slerped / lerped;
  the pelvis rotation relative to its frame's heading slerped, its height lerped;
- the root path integrated from a's frame p over the blended per-step ground
  displacements and heading changes (a clip held at its end keeps its last step:
  its velocity carries on, not its pose), so a walk blended into a standing pose
  slows down rather than sliding back;
- a foot is in contact where it is in contact in both.
The match sits in the middle of the blend (L // 2 nodes of a before it), at its end
for a bridge into a clip's first frame and at its start for one out of a clip's last.
Length: L = rate · clip(max(3 s/m · D, Δv / 2 m/s², 0.3 s), 1.2 s): a pose difference
closes at about 0.5 m/s of added joint speed at most, a ground-speed difference Δv at
2 m/s² (a walker stops in about half a second), never shorter than the 0.3 s a
transition needs to look like one.

**Readings** (`metadata.bridge_readings`). The layout's sensors are simulated on each blend with
two frames of a before it and three of b after it (moved rigidly onto the blend's
end), so the edge into node k reads node k and the edge out to b's frame q reads b's
frame q as it follows the blend. The same function recomputes them for another
layout from the graph's stored poses (`metadata.recompute_accelerations`).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np

from graphsvc.blas import one_thread
from graphsvc.graph import metadata as meta
from graphsvc.graph.distance import PoseFeatures, window_features
from graphsvc.graph.records import BRIDGE_KINDS
from graphsvc.graph.transitions import _pair_distances, _state_code
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.placement import joint_tables, place_poses, relative_pose

DEFAULT_THRESHOLD_M = 0.25  # loosest D a bridge between labels may span
DEFAULT_END_THRESHOLD_M = 0.35  # loosest D of a bridge out of a clip's end or into its start
DEFAULT_SPACING_S = 3.0  # one bridge per other label per this much of a clip
MIN_BLEND_S, MAX_BLEND_S = 0.3, 1.2
POSE_CLOSING_S_PER_M = 3.0  # blend seconds per metre of D
SPEED_CLOSING_M_S2 = 2.0  # ground-speed change a blend may ask for (m/s²)
FEATURE_DT_S = 0.1  # the match feature's frames before and after
FEATURE_DIMS = 24
SAMPLE_DT_S = 0.1  # candidate frames this far apart
CANDIDATES_SCORED = 3  # per slot, the feature's best few are scored by D
MAX_LABELS_PER_STRETCH = 8  # labels a stretch of a clip bridges to (and from), the nearest
_ROWS = 512  # source rows per block of the candidate distance matrix


@dataclass(frozen=True)
class KBFrames:
    """The knowledge base on one frame axis of N frames (C clips), as `build` holds it.

    rotations (N, J, 4), translations (N, J, 3): local poses; pelvis_rel (N, 4),
    pelvis_height (N,): the pelvis world rotation with the frame's heading taken off and
    its height (`motion.placement.relative_pose`); ground (N, 2) m, heading (N,) rad;
    contacts (N, 2) bool; window: the distance window (frames, `distance.py`); canon
    (N, P, 3) canonical joint positions; start (C + 1,) first frame of each clip; label
    (C,), performance (C,), performer (C,) int per clip (a performer: clips with equal
    skeleton offsets). The world poses of every frame are not kept (1.2 KB a frame in
    float64): `world_summaries` makes canon and the pelvis from them a chunk at a time,
    and a bridge's readings compute the few clip frames around it again (`_blend_chunk`)."""

    rotations: np.ndarray
    translations: np.ndarray
    pelvis_rel: np.ndarray
    pelvis_height: np.ndarray
    ground: np.ndarray
    heading: np.ndarray
    contacts: np.ndarray
    window: int
    canon: np.ndarray
    start: np.ndarray
    label: np.ndarray
    performance: np.ndarray
    performer: np.ndarray

    @property
    def clip(self) -> np.ndarray:
        lengths = np.diff(self.start)
        return np.repeat(np.arange(lengths.shape[0]), lengths)


def world_summaries(
    rotations: np.ndarray,
    translations: np.ndarray,
    heading: np.ndarray,
    parents: np.ndarray,
    pelvis: int,
    canon_joints: list[int],
    chunk: int = 65536,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """KBFrames' canon (N, P, 3), pelvis_rel (N, 4) and pelvis_height (N,) from the local
    poses (N, J, 4/3), by forward kinematics `chunk` frames at a time (each frame's the
    same numbers as all at once)."""
    N = rotations.shape[0]
    canon = np.empty((N, len(canon_joints), 3))
    rel, height = np.empty((N, 4)), np.empty(N)
    for f0 in range(0, N, chunk):
        f1 = min(N, f0 + chunk)
        world_rot, world_pos = forward_kinematics(rotations[f0:f1], translations[f0:f1], parents)
        canon[f0:f1] = world_pos[:, canon_joints]
        rel[f0:f1], height[f0:f1] = relative_pose(world_rot, world_pos, heading[f0:f1], pelvis)
    return canon, rel, height


@dataclass(frozen=True)
class Matches:
    """B chosen bridges, arrays (B,): clip_a, clip_b, match frames i (in a) and j (in
    b), distance D (m), length L (nodes), before c (nodes of a before the match), and
    kind (0 between labels, 1 out of a clip's end, 2 into a clip's start)."""

    clip_a: np.ndarray
    clip_b: np.ndarray
    i: np.ndarray
    j: np.ndarray
    distance: np.ndarray
    length: np.ndarray
    before: np.ndarray
    kind: np.ndarray

    def __len__(self) -> int:
        return int(self.clip_a.shape[0])

    @property
    def entry(self) -> np.ndarray:
        """(B,) frame p of clip a the bridge is entered from."""
        return self.i - self.before

    @property
    def exit(self) -> np.ndarray:
        """(B,) frame q of clip b the bridge leaves to."""
        return self.j - self.before + self.length + 1


KINDS = BRIDGE_KINDS


# ---------------------------------------------------------------- candidates


def match_features(
    canon: np.ndarray,
    ground: np.ndarray,
    heading: np.ndarray,
    start: np.ndarray,
    rate_hz: float,
    frames: np.ndarray | None = None,
) -> np.ndarray:
    """(F, 3·P·3) float32: at each of `frames` (default every frame) the canonical
    joints (N, P, 3) at t − dt, t, t + dt (dt = FEATURE_DT_S, clamped to the clip), each
    relative to its own frame's root ground position and turned by frame t's heading
    onto +Z, the centre frame weighted twice: the pose and the limbs' motion, not the
    root's speed."""
    f = np.arange(canon.shape[0]) if frames is None else np.asarray(frames)
    clip = np.searchsorted(start, f, side="right") - 1
    lo, hi = start[clip], start[clip + 1] - 1
    d = max(1, int(round(FEATURE_DT_S * rate_hz)))
    c, s = np.cos(heading[f]), np.sin(heading[f])
    parts = []
    for at, weight in ((np.maximum(f - d, lo), 0.5), (f, 1.0), (np.minimum(f + d, hi), 0.5)):
        x = canon[at, :, 0] - ground[at, None, 0]
        z = canon[at, :, 2] - ground[at, None, 1]
        # R_y(−h)·(x, z) = (c·x − s·z, s·x + c·z): the facing direction onto +Z.
        parts += [
            weight * (c[:, None] * x - s[:, None] * z),
            weight * canon[at, :, 1],
            weight * (s[:, None] * x + c[:, None] * z),
        ]
    return np.concatenate(parts, axis=1).astype(np.float32)


def body_features(
    canon: np.ndarray, ground: np.ndarray, start: np.ndarray, window: int, frames: np.ndarray | None = None
) -> PoseFeatures:
    """The window point clouds of `distance.pose_features` at `frames` (default every
    frame; each clip's windows clamped to it), made of the canonical joints (N, P, 3)
    relative to each frame's own root ground position (N, 2): their distance compares
    the pose and how the limbs move over the window but not how fast the body travels,
    which a bridge's blend changes on its own."""
    rel = canon.copy()
    rel[..., 0] -= ground[:, None, 0]
    rel[..., 2] -= ground[:, None, 1]
    f = np.arange(canon.shape[0]) if frames is None else np.asarray(frames)
    clip = np.searchsorted(start, f, side="right") - 1
    half = window // 2
    idx = np.clip(f[:, None] + np.arange(-half, half + 1)[None, :], start[clip, None], start[clip + 1, None] - 1)
    return window_features(rel, idx)


def _project(x: np.ndarray, dims: int) -> np.ndarray:
    centred = x - x.mean(axis=0)
    if dims >= x.shape[1]:
        return centred.astype(np.float32)
    _, vecs = np.linalg.eigh(centred.T.astype(np.float64) @ centred.astype(np.float64))
    return (centred @ vecs[:, ::-1][:, :dims].astype(np.float32)).astype(np.float32)


def candidate_frames(kb: KBFrames, rate_hz: float) -> np.ndarray:
    """Sorted frames that may start or end a bridge: every SAMPLE_DT_S of each clip,
    and each clip's first and last frame with a foot down; never a frame in flight."""
    step = max(1, int(round(SAMPLE_DT_S * rate_hz)))
    in_clip = np.arange(kb.contacts.shape[0]) - kb.start[kb.clip]
    keep = kb.contacts.any(axis=1) & (in_clip % step == 0)
    first, last = reachable_span(kb.contacts, kb.start)
    has = last >= 0
    keep[kb.start[:-1][has] + first[has] - 1] = True
    keep[kb.start[:-1][has] + last[has]] = True
    return np.flatnonzero(keep)


def reachable_span(contacts: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per clip (C,): the first frame a bridge into its start can land on (its first
    frame with a foot down, plus one) and its last frame with a foot down (where the
    bridge out of its end leaves). Frames outside [first, last] can only be left
    toward the clip's end or reached from its start, so nothing else should enter or
    leave there. A clip without a grounded frame gets an empty span."""
    C = start.shape[0] - 1
    first = np.full(C, np.iinfo(np.int64).max // 2, dtype=np.int64)
    last = np.full(C, -1, dtype=np.int64)
    grounded = contacts.any(axis=1)
    for c in range(C):
        frames = np.flatnonzero(grounded[start[c] : start[c + 1]])
        if frames.size:
            first[c], last[c] = frames[0] + 1, frames[-1]
    return first, last


def best_per_label(
    points: np.ndarray,
    state: np.ndarray,
    performance: np.ndarray,
    label: np.ndarray,
    num_labels: int,
    performer: np.ndarray | None = None,
    jobs: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """For each point (M, d) and each label, the nearest point of that label that
    shares a planted foot with it (contact states with a common bit) and belongs to
    another performance: (M, L, V) indices (−1: none) and squared distances (inf:
    none); V = 1, or 2 with `performer` (M,) given, the second the nearest of the
    point's own performer. Dense float32 blocks of _ROWS rows: the products by BLAS,
    the squared distances, masks and minima folded in one compiled pass over each
    block (`_fold_nearest`; numpy's masked argmin made ten passes over it), row blocks
    on `jobs` threads (each writes its own rows: the same result however many); exact
    enough to rank candidates that D then scores. Call it inside `one_thread()`: each
    product on one BLAS thread."""
    M = points.shape[0]
    V = 1 if performer is None else 2
    order = np.argsort(label, kind="stable")
    bounds = np.searchsorted(label[order], np.arange(num_labels + 1))
    y = np.ascontiguousarray(points[order], dtype=np.float32)
    y2 = np.einsum("md,md->m", y, y)
    ys = np.ascontiguousarray(state[order], dtype=np.int64)
    yp = np.ascontiguousarray(performance[order], dtype=np.int64)
    yq = np.zeros(M, np.int64) if performer is None else np.ascontiguousarray(performer[order], dtype=np.int64)
    xs = np.ascontiguousarray(state, dtype=np.int64)
    xp = np.ascontiguousarray(performance, dtype=np.int64)
    xq = np.zeros(M, np.int64) if performer is None else np.ascontiguousarray(performer, dtype=np.int64)
    x = np.ascontiguousarray(points, dtype=np.float32)
    x2 = np.einsum("md,md->m", x, x)
    best = np.full((M, num_labels, V), -1, dtype=np.int64)
    best_d2 = np.full((M, num_labels, V), np.inf, dtype=np.float32)

    def rows(r0: int) -> None:
        r1 = min(M, r0 + _ROWS)
        for lab in range(num_labels):
            a, b = bounds[lab], bounds[lab + 1]
            if a == b:
                continue
            _fold_nearest(
                x[r0:r1] @ y[a:b].T,
                x2[r0:r1], y2[a:b], xs[r0:r1], ys[a:b], xp[r0:r1], yp[a:b], xq[r0:r1], yq[a:b],
                V, best[r0:r1, lab], best_d2[r0:r1, lab],
            )  # fmt: skip

    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        list(pool.map(rows, range(0, M, _ROWS)))
    found = best >= 0
    best[found] = order[bounds[np.nonzero(found)[1]] + best[found]]  # (a label's column → its point)
    return best, best_d2


@numba.njit(cache=True, nogil=True)
def _fold_nearest(G, x2, y2, xs, ys, xp, yp, xq, yq, V, best, best_d2):  # pragma: no cover - compiled
    """Rows r of a block against one label's columns c, G = x·yᵀ (float32): the first
    column of least (x2 + y2) − 2 G (float32, as numpy rounds it) among those sharing a
    contact bit and of another performance, into best[r, 0] (column index) and
    best_d2[r, 0] (clamped at 0); with V = 2 the same among the row's own performer's
    into best[r, 1]. Rows without one keep −1 / inf."""
    two = np.float32(2.0)
    for r in range(G.shape[0]):
        b0, b1 = -1, -1
        d0, d1 = np.float32(np.inf), np.float32(np.inf)
        for c in range(G.shape[1]):
            if (xs[r] & ys[c]) == 0 or xp[r] == yp[c]:
                continue
            d = (x2[r] + y2[c]) - two * G[r, c]
            if d < d0:
                d0, b0 = d, c
            if V == 2 and d < d1 and xq[r] == yq[c]:
                d1, b1 = d, c
        if b0 >= 0:
            best[r, 0], best_d2[r, 0] = b0, max(d0, np.float32(0.0))
        if V == 2 and b1 >= 0:
            best[r, 1], best_d2[r, 1] = b1, max(d1, np.float32(0.0))


def _best_of_groups(key: np.ndarray, score: np.ndarray, limit: int) -> np.ndarray:
    """Indices of the `limit` lowest scores of each key (ties by position)."""
    order = np.lexsort((np.arange(key.shape[0]), score, key))
    k = key[order]
    first = np.searchsorted(k, k, side="left")
    return order[np.arange(k.shape[0]) - first < limit]


def blend_length(distance: np.ndarray, speed_change: np.ndarray, rate_hz: float) -> np.ndarray:
    """(B,) nodes of a bridge: the module docstring's rule."""
    seconds = np.clip(
        np.maximum(np.maximum(POSE_CLOSING_S_PER_M * distance, speed_change / SPEED_CLOSING_M_S2), MIN_BLEND_S),
        MIN_BLEND_S,
        MAX_BLEND_S,
    )
    return np.maximum(2, np.rint(seconds * rate_hz)).astype(np.int64)


def _ground_speed(kb: KBFrames, rate_hz: float) -> np.ndarray:
    out = np.zeros(kb.ground.shape[0])
    for c in range(kb.start.shape[0] - 1):
        a, b = kb.start[c], kb.start[c + 1]
        if b - a >= 2:
            out[a:b] = np.linalg.norm(np.gradient(kb.ground[a:b], 1.0 / rate_hz, axis=0), axis=1)
    return out


def select_matches(
    kb: KBFrames,
    rate_hz: float,
    threshold_m: float = DEFAULT_THRESHOLD_M,
    end_threshold_m: float = DEFAULT_END_THRESHOLD_M,
    spacing_s: float = DEFAULT_SPACING_S,
    needed: np.ndarray | None = None,
    jobs: int = 1,
) -> Matches:
    """The bridges of a knowledge base (module docstring), feasible and distinct.
    needed: (L, L) bool, the ordered label pairs that get bridges between labels (None:
    all); jobs: threads for the candidate search (the same matches however many)."""
    C = kb.start.shape[0] - 1
    num_labels = int(kb.label.max()) + 1 if C else 0
    frames = candidate_frames(kb, rate_hz)
    empty = np.zeros(0, dtype=np.int64)
    if frames.size < 2 or C < 2:
        return Matches(empty, empty, empty, empty, np.zeros(0), empty, empty, empty)
    clip = kb.clip
    feats = match_features(kb.canon, kb.ground, kb.heading, kb.start, rate_hz, frames)
    fclip = clip[frames]
    with one_thread():  # (the nearest candidates the same however many threads BLAS has: graphsvc.blas)
        points = _project(feats, FEATURE_DIMS)
        best, best_d2 = best_per_label(
            points,
            _state_code(kb.contacts[frames]),
            kb.performance[fclip],
            kb.label[fclip],
            num_labels,
            kb.performer[fclip],
            jobs,
        )
    in_clip = frames - kb.start[fclip]
    lengths = np.diff(kb.start)

    src, dst, kind, slot = [], [], [], []
    # Between labels: one slot per (clip, stretch of spacing_s, other label, toward any
    # performer or the clip's own).
    bin_frames = max(1, int(round(spacing_s * rate_hz)))
    own = kb.label[fclip]
    rows, labs, var = np.nonzero(np.isfinite(best_d2) & (own[:, None, None] != np.arange(num_labels)[None, :, None]))
    if needed is None:
        needed = ~np.eye(num_labels, dtype=bool)
    key = (
        (fclip[rows] * (lengths.max() // bin_frames + 1) + in_clip[rows] // bin_frames) * num_labels + labs
    ) * 2 + var
    # Departures from every stretch of every clip toward each other label (any
    # performer's clips and the clip's own performer's), and — D and the masks being
    # symmetric, the same table read the other way — arrivals into every stretch of
    # every clip from each other label (any performer's: an own-performer variant there
    # added 6 % more nodes and measured no better), for the label pairs that need them.
    # With many labels, a stretch bridges to its MAX_LABELS_PER_STRETCH nearest ones
    # only (the rest are two bridges away), so the bridges grow with the data, not with
    # data × labels.
    for arrive in (False, True):
        want = needed[labs, own[rows]] & (var == 0) if arrive else needed[own[rows], labs]
        top = np.flatnonzero(want)[
            _best_of_groups(key[want], best_d2[rows[want], labs[want], var[want]], CANDIDATES_SCORED)
        ]
        slots, first_of = np.unique(key[top], return_index=True)  # a slot's best candidate comes first
        stretch = (slots // 2) // num_labels * 2 + slots % 2  # (clip, stretch, variant)
        kept = slots[
            _best_of_groups(
                stretch, best_d2[rows[top[first_of]], labs[top[first_of]], var[top[first_of]]], MAX_LABELS_PER_STRETCH
            )
        ]
        top = top[np.isin(key[top], kept)]
        here, there = frames[rows[top]], frames[best[rows[top], labs[top], var[top]]]
        src.append(there if arrive else here)
        dst.append(here if arrive else there)
        kind.append(np.zeros(top.size, dtype=np.int64))
        slot.append(2 * key[top] + int(arrive))
    best, best_d2 = best[..., 0], best_d2[..., 0]
    # Out of each clip's last grounded frame and into its first: any label.
    next_slot = 2 * int(key.max()) + 2 if key.size else 0
    last = np.r_[np.flatnonzero(np.diff(fclip)), fclip.size - 1]
    first = np.r_[0, np.flatnonzero(np.diff(fclip)) + 1]
    for ends, k in ((last, 1), (first, 2)):
        r, lab = np.nonzero(np.isfinite(best_d2[ends]))
        r_rows = ends[r]
        key_end = next_slot + fclip[r_rows]
        top = np.arange(r_rows.size)  # every label's best: the first feasible of them may be far down
        a, b = frames[r_rows[top]], frames[best[r_rows[top], lab[top]]]
        # Into a clip's start: the candidate's own frame is the target.
        src.append(a if k == 1 else b)
        dst.append(b if k == 1 else a)
        kind.append(np.full(top.size, k, dtype=np.int64))
        slot.append(key_end[top])
        next_slot += C
    src, dst, kind, slot = (np.concatenate(v) for v in (src, dst, kind, slot))
    # (the clouds of the frames the candidates pair only: every frame's is 0.8 KB a frame)
    scored, pair = np.unique(np.concatenate([src, dst]), return_inverse=True)
    features = body_features(kb.canon, kb.ground, kb.start, kb.window, scored)
    distance = _pair_distances(features, pair[: src.size], pair[src.size :])
    del features
    ok = distance <= np.where(kind == 0, threshold_m, end_threshold_m)
    src, dst, kind, slot, distance = src[ok], dst[ok], kind[ok], slot[ok], distance[ok]

    speed = _ground_speed(kb, rate_hz)
    length = blend_length(distance, np.abs(speed[src] - speed[dst]), rate_hz)
    ca, cb = clip[src], clip[dst]
    i, j = src - kb.start[ca], dst - kb.start[cb]
    # A bridge lands no later than b's last frame with a foot down, where b's own way
    # out starts (past it a clip may end in flight, a dead end), and is entered from no
    # earlier than the frame after a's first grounded one, where the bridge into a's
    # start lands (a clip's frames before it are never reached).
    first_reached, last_grounded = reachable_span(kb.contacts, kb.start)
    reach_a = first_reached[ca]
    # Out of a clip's end the blend starts at the match (c = 0), into a clip's start it
    # ends there (c = L); either is shortened, when it must, to fit the clip it plays.
    length = np.where(kind == 1, np.minimum(length, last_grounded[cb] - j - 1), length)
    length = np.where(kind == 2, np.minimum(length, i - reach_a), length)
    before = np.where(kind == 1, 0, np.where(kind == 2, length, length // 2))
    # Between labels the match is centred, moved as far as needed to keep the entry
    # p = i − c in a's reached frames and the exit q = j − c + L + 1 no later than b's
    # last grounded frame.
    before = np.where(
        kind == 0, np.minimum(np.maximum(before, j + length + 1 - last_grounded[cb]), i - reach_a), before
    )
    feasible = (length >= 2) & (before >= 0) & (before <= length) & (i - before >= np.where(kind == 1, 0, reach_a))
    feasible &= j - before + length + 1 <= last_grounded[cb]
    sel = np.flatnonzero(feasible)
    # The best-scored feasible candidate of each slot, then one bridge per (a, i, b, j, c):
    # slots of different labels may pick the same pair.
    sel = sel[_best_of_groups(slot[sel], distance[sel], 1)]
    rec = np.stack([ca[sel], i[sel], cb[sel], j[sel], before[sel], length[sel]], axis=1)
    _, first_of = np.unique(rec, axis=0, return_index=True)
    sel = sel[np.sort(first_of)]
    order = sel[np.lexsort((j[sel], cb[sel], i[sel], ca[sel]))]
    return Matches(ca[order], cb[order], i[order], j[order], distance[order], length[order], before[order], kind[order])


# ---------------------------------------------------------------- blending


@dataclass(frozen=True)
class BridgeNodes:
    """The M new nodes of B bridges, in bridge order (bridge b's nodes are
    first[b] … first[b] + count[b] − 1 of these arrays, first relative to the bridges'
    first node; their poses went to `blend_bridges`'s add_poses as they were made).
    ground (M, 2), heading (M,) their placement in clip a's frame; contacts (M, 2);
    source_clip, source_frame (M,) the clip and frame of the dominant side;
    step_offset (M + B, 2), step_heading (M + B,): the ground displacement and heading
    change of every edge, bridge by bridge the L edges into its nodes then the one
    out; readings (M + B, S, 3) float32 in the same order."""

    ground: np.ndarray
    heading: np.ndarray
    contacts: np.ndarray
    source_clip: np.ndarray
    source_frame: np.ndarray
    first: np.ndarray
    count: np.ndarray
    step_offset: np.ndarray
    step_heading: np.ndarray
    readings: np.ndarray


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _step_offsets(kb: KBFrames) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2), (N,): each frame's step from the frame before it in its clip (local
    ground displacement, heading change); a clip's frame 0 takes the step into frame 1."""
    N = kb.ground.shape[0]
    clip = kb.clip
    prev = np.arange(N) - 1
    first = np.arange(N) == kb.start[clip]
    one_frame = np.diff(kb.start)[clip] < 2
    cur = np.where(first & ~one_frame, np.arange(N) + 1, np.arange(N))
    prev = np.where(first, np.where(one_frame, cur, cur - 1), prev)
    return meta.local_offsets(kb.ground[prev], kb.heading[prev], kb.ground[cur], kb.heading[cur])


@numba.njit(cache=True, nogil=True)
def _integrate_bridges(first, count, ground0, heading0, offsets, dheadings, ground, heading):
    """Per bridge b, integrate its count[b] blended steps from (ground0[b], heading0[b]);
    steps and outputs are the bridges' node rows first[b] … first[b] + count[b] − 1."""
    for b in range(first.shape[0]):
        gx, gz, h = ground0[b, 0], ground0[b, 1], heading0[b]
        for k in range(first[b], first[b] + count[b]):
            c, s = np.cos(h), np.sin(h)
            gx, gz = gx + (c * offsets[k, 0] + s * offsets[k, 1]), gz + (-s * offsets[k, 0] + c * offsets[k, 1])
            h = (h + dheadings[k] + np.pi) % (2.0 * np.pi) - np.pi
            ground[k, 0], ground[k, 1], heading[k] = gx, gz, h


@numba.njit(cache=True, nogil=True)
def _slerp_into(a, b, t, out):
    """Shortest-arc slerp of unit quaternions a, b (4,) at t into out (4,) (`quat.slerp`'s rule)."""
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    sign = 1.0
    if dot < 0.0:
        sign, dot = -1.0, -dot
    if dot > 1.0 - 1e-12:
        wa, wb = 1.0 - t, t
    else:
        theta = np.arccos(min(dot, 1.0))
        st = np.sin(theta)
        wa, wb = np.sin((1.0 - t) * theta) / st, np.sin(t * theta) / st
    n = 0.0
    for k in range(4):
        out[k] = wa * a[k] + sign * wb * b[k]
        n += out[k] * out[k]
    n = np.sqrt(n)
    for k in range(4):
        out[k] /= n


@numba.njit(cache=True, nogil=True)
def _blend_poses(rotations, translations, rel, height, ga, gb, w, below, rot, trans, rel_out, height_out):
    """Node m blends frames ga[m] and gb[m] at weight w[m] on the second: the joints
    below the pelvis slerped / lerped, the others as in ga[m] (the carrier is placed
    afterwards), the heading-relative pelvis rotation rel (N, 4) slerped and its
    height lerped. In place on rot (M, J, 4), trans (M, J, 3), rel_out, height_out."""
    for m in range(ga.shape[0]):
        a, b, t = ga[m], gb[m], w[m]
        for j in range(rotations.shape[1]):
            if below[j]:
                _slerp_into(rotations[a, j], rotations[b, j], t, rot[m, j])
                for k in range(3):
                    trans[m, j, k] = (1.0 - t) * translations[a, j, k] + t * translations[b, j, k]
            else:
                rot[m, j] = rotations[a, j]
                trans[m, j] = translations[a, j]
        _slerp_into(rel[a], rel[b], t, rel_out[m])
        height_out[m] = (1.0 - t) * height[a] + t * height[b]


def blend_bridges(
    kb: KBFrames,
    matches: Matches,
    skeleton,
    joints: dict,
    placement_of_clip,
    rate_hz: float,
    add_poses: Callable[[np.ndarray, np.ndarray], None],
    chunk_nodes: int = 32768,
) -> BridgeNodes:
    """The nodes, edges' steps and readings of every bridge (module docstring), readings
    in float32 as the graph stores them; the nodes' placed local poses, float32 rotations
    (m, J, 4) and translations (m, J, 3), go to add_poses chunk by chunk in node order
    (the build packs them: never every bridge's at once). joints: the canonical joint map;
    placement_of_clip(c): the layout placed on clip c's skeleton (a bridge's readings
    use clip a's). Bridges are blended about chunk_nodes nodes at a time, so the
    float64 working arrays stay a few hundred MB on any knowledge base."""
    blend = lambda some: _blend_chunk(kb, some, skeleton, joints, placement_of_clip, rate_hz, add_poses)  # noqa: E731
    ends = np.cumsum(matches.length)
    parts = []
    b0 = 0
    while b0 < len(matches):
        b1 = max(b0 + 1, int(np.searchsorted(ends, (ends[b0 - 1] if b0 else 0) + chunk_nodes, side="right")))
        sub = Matches(
            *(
                getattr(matches, f)[b0:b1]
                for f in ("clip_a", "clip_b", "i", "j", "distance", "length", "before", "kind")
            )
        )
        parts.append(blend(sub))
        b0 = b1
    if not parts:
        parts.append(blend(matches))
    first, at = [], 0
    for p in parts:
        first.append(p.first + at)
        at += p.ground.shape[0]
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return BridgeNodes(
        cat("ground"),
        cat("heading"),
        cat("contacts"),
        cat("source_clip"),
        cat("source_frame"),
        np.concatenate(first),
        cat("count"),
        cat("step_offset"),
        cat("step_heading"),
        cat("readings"),
    )


def _blend_chunk(
    kb: KBFrames,
    matches: Matches,
    skeleton,
    joints: dict,
    placement_of_clip,
    rate_hz: float,
    add_poses: Callable[[np.ndarray, np.ndarray], None],
) -> BridgeNodes:
    """`blend_bridges` of a few bridges."""
    B = len(matches)
    count = matches.length
    first = np.zeros(B, dtype=np.int64)
    np.cumsum(count[:-1], out=first[1:])
    M = int(count.sum())
    bridge = np.repeat(np.arange(B), count)
    k = np.arange(M) - first[bridge] + 1  # 1 … L
    L = count[bridge]
    lengths = np.diff(kb.start)
    ca, cb = matches.clip_a[bridge], matches.clip_b[bridge]
    a = np.clip(matches.entry[bridge] + k, 0, lengths[ca] - 1)
    b = np.clip(matches.exit[bridge] - L - 1 + k, 0, lengths[cb] - 1)
    ga, gb = kb.start[ca] + a, kb.start[cb] + b
    w = _smoothstep(k / (L + 1.0))

    # Steps: a clip past its end (or before its start) keeps its end step.
    step_off, step_dh = _step_offsets(kb)
    sa = kb.start[ca] + np.clip(matches.entry[bridge] + k, 1, lengths[ca] - 1)
    sb = kb.start[cb] + np.clip(matches.exit[bridge] - L - 1 + k, 1, lengths[cb] - 1)
    offset = (1.0 - w)[:, None] * step_off[sa] + w[:, None] * step_off[sb]
    dheading = (1.0 - w) * step_dh[sa] + w * step_dh[sb]
    entry = kb.start[matches.clip_a] + matches.entry
    ground = np.empty((M, 2))
    heading = np.empty(M)
    _integrate_bridges(first, count, kb.ground[entry], kb.heading[entry], offset, dheading, ground, heading)

    # Poses relative to their own placement, blended, then placed on the bridge's root path.
    pelvis = joints["pelvis"]
    below, carrier = joint_tables(skeleton, joints)
    rot = np.empty((M,) + kb.rotations.shape[1:])
    trans = np.empty((M,) + kb.translations.shape[1:])
    rel = np.empty((M, 4))
    height = np.empty(M)
    _blend_poses(
        kb.rotations, kb.translations, kb.pelvis_rel, kb.pelvis_height, ga, gb, w, below, rot, trans, rel, height
    )
    parents = np.ascontiguousarray(skeleton.parents, dtype=np.int64)
    src_rot, src_pos = forward_kinematics(rot, trans, parents)
    place_poses(rot, trans, rel, height, ground, heading, src_rot, src_pos, parents, pelvis, carrier)
    rot /= np.linalg.norm(rot, axis=-1, keepdims=True)

    dominant_b = w >= 0.5
    source_clip = np.where(dominant_b, cb, ca)
    source_frame = np.where(dominant_b, b, a).astype(np.float64)
    contacts = kb.contacts[ga] & kb.contacts[gb]

    # Every edge's step: the L into the bridge's nodes, then b's own step out of it.
    exit_frame = kb.start[matches.clip_b] + matches.exit
    edge_first = first + np.arange(B)
    step_offset = np.empty((M + B, 2))
    step_heading = np.empty(M + B)
    inner = np.ones(M + B, dtype=bool)
    inner[edge_first + count] = False
    step_offset[inner], step_heading[inner] = offset, dheading
    step_offset[~inner], step_heading[~inner] = step_off[exit_frame], step_dh[exit_frame]

    world_rot, world_pos = forward_kinematics(rot, trans, parents)
    readings = meta.bridge_readings(
        lambda f: forward_kinematics(kb.rotations[f], kb.translations[f], parents),
        kb.ground,
        kb.heading,
        world_rot,
        world_pos,
        ground,
        heading,
        first,
        count,
        entry,
        exit_frame,
        kb.start[matches.clip_a],
        kb.start[matches.clip_a + 1],
        kb.start[matches.clip_b],
        kb.start[matches.clip_b + 1],
        [placement_of_clip(int(c)) for c in matches.clip_a],
        rate_hz,
    )
    add_poses(rot.astype(np.float32), trans.astype(np.float32))
    return BridgeNodes(
        ground,
        heading,
        contacts,
        source_clip,
        source_frame,
        first,
        count,
        step_offset,
        step_heading,
        readings,
    )
