"""Interpolation segments between two knowledge-base clips (Kelly et al. 2013, §4.2).

Pipeline, all on flat arrays of one pair of clips (a: Fa frames, b: Fb frames):

1. `similar_regions`: cells (i, j) of the (Fa, Fb) frame-distance matrix (metres,
   `distance.distance_block`) with equal foot-contact state and distance < t_i,
   grouped into 8-connected components.
2. `bounded_dtw`: per component, the monotone alignment through its cells with the
   step pattern {(1, 1), (1, 2), (2, 1)} (each step advances both clips, by 1–2
   frames, and never more than twice as far on one side as on the other).
3. `aligned_segments`: paths lasting at least 0.5 s on both sides.
4. `blend_along_path` / `blend_arrays_along_path` / `blend_ground`: poses, per-frame
   arrays and the ground trajectory of both clips sampled along the warped timeline
   and blended with even weights into uniformly timed new frames.

DTW objective (Kelly et al. 2013, §4.2, leave begin and end open). A path visits cells c_0 … c_{K−1};
the first cell has weight 1 and a step (di, dj) into a cell has weight (di + dj)/2,
the time it advances on the mean timeline, so the weights sum to the path's mean
duration in frames. The path minimises

    Σ_k weight_k · (cost[c_k] − reward)

over every start and end cell. With `reward` above every allowed cost (the default,
and `aligned_segments` passes reward = t_i), each cell earns its margin below the
threshold: the chosen path is the longest alignment through the component, trading
length against mean cost, i.e. it maximises duration × (reward − mean cost).

Slope bound. Every step has di, dj ≥ 1 and dj/di ∈ {1/2, 1, 2}; the slope over any
run of steps, Σdj / Σdi, is a mediant of per-step slopes in [1/2, 2] and so lies in
[1/2, 2] too. The path is strictly increasing on both sides, so each frame of either
clip is matched at most once (K: "each pose S_α is matched to a single pose P_β").
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from scipy import ndimage

from graphsvc.errors import InputError
from graphsvc.graph.distance import PoseFeatures, alignment
from graphsvc.motion import quat

STEPS = np.array([[1, 1], [1, 2], [2, 1]], dtype=np.int64)  # (da, db) per DTW step
EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)


# --------------------------------------------------------------------------- regions


@dataclass(frozen=True)
class Region:
    """One 8-connected group of similar cells. a0, b0: frame of clip a (row) and clip
    b (column) of the bounding box's first cell; mask: (h, w) bool, the component's
    cells inside its bounding box (other components' cells are False)."""

    a0: int
    b0: int
    mask: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return self.mask.shape

    @property
    def a_slice(self) -> slice:
        return slice(self.a0, self.a0 + self.mask.shape[0])

    @property
    def b_slice(self) -> slice:
        return slice(self.b0, self.b0 + self.mask.shape[1])


def same_contact_matrix(contacts_a: np.ndarray, contacts_b: np.ndarray) -> np.ndarray:
    """(Fa, Fb) bool: frames i of a and j of b have the same contact state.
    contacts_*: (F, C) bool per-foot contact flags (or (F,) integer state codes)."""
    ca = np.asarray(contacts_a)
    cb = np.asarray(contacts_b)
    if ca.ndim == 2:  # pack each frame's flags into one integer code: one comparison per cell
        weights = 1 << np.arange(ca.shape[1])
        ca, cb = ca.astype(np.int64) @ weights, cb.astype(np.int64) @ weights
    return ca[:, None] == cb[None, :]


def similar_regions(distance: np.ndarray, same_contacts: np.ndarray, threshold_m: float) -> list[Region]:
    """8-connected components of the cells with same_contacts and distance <
    threshold_m. distance: (Fa, Fb) metres; same_contacts: (Fa, Fb) bool. Regions come
    in scipy's label order (row-major by first cell)."""
    distance = np.asarray(distance)
    if distance.shape != np.shape(same_contacts):
        raise InputError(f"distance {distance.shape} and contact matrix {np.shape(same_contacts)} differ in shape")
    keep = np.asarray(same_contacts, dtype=bool) & (distance < threshold_m)
    labels, _ = ndimage.label(keep, structure=EIGHT_CONNECTED)
    regions = []
    for k, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        regions.append(Region(box[0].start, box[1].start, labels[box] == k))
    return regions


# --------------------------------------------------------------------------- DTW


@numba.njit(cache=True, nogil=True)
def _dtw_kernel(gain: np.ndarray, allowed: np.ndarray):
    """Open-ended DP over the step pattern {(1,1), (1,2), (2,1)}; gain = cost − reward.
    Returns (path buffer (n, 2), n); n = 0 when no cell is allowed."""
    h, w = gain.shape
    acc = np.full((h, w), np.inf)
    back = np.zeros((h, w), dtype=np.int8)  # 0 start here, 1 from (i−1, j−1), 2 from (i−1, j−2), 3 from (i−2, j−1)
    best = np.inf
    bi = -1
    bj = -1
    for i in range(h):
        for j in range(w):
            if not allowed[i, j]:
                continue
            g = gain[i, j]
            v = g
            b = 0
            # Strict < : on ties prefer starting fresh, then the diagonal.
            if i >= 1 and j >= 1:
                c = acc[i - 1, j - 1] + g
                if c < v:
                    v = c
                    b = 1
            if i >= 1 and j >= 2:
                c = acc[i - 1, j - 2] + 1.5 * g
                if c < v:
                    v = c
                    b = 2
            if i >= 2 and j >= 1:
                c = acc[i - 2, j - 1] + 1.5 * g
                if c < v:
                    v = c
                    b = 3
            acc[i, j] = v
            back[i, j] = b
            if v < best:
                best = v
                bi = i
                bj = j
    out = np.empty((min(h, w), 2), dtype=np.int64)
    if bi < 0:
        return out, 0
    n = 0
    i = bi
    j = bj
    while True:
        out[n, 0] = i
        out[n, 1] = j
        n += 1
        b = back[i, j]
        if b == 0:
            break
        elif b == 1:
            i -= 1
            j -= 1
        elif b == 2:
            i -= 1
            j -= 2
        else:
            i -= 2
            j -= 1
    return out[:n][::-1].copy(), n


def bounded_dtw(cost: np.ndarray, allowed: np.ndarray, reward: float | None = None) -> np.ndarray | None:
    """Slope-bounded open-ended DTW through the allowed cells (see the module doc for
    the objective and the slope proof). cost: (h, w) float, e.g. metres; allowed:
    (h, w) bool; reward: per-frame credit, default just above the largest allowed
    cost so every allowed cell lengthens the path. Returns the path (K, 2) int64 of
    (row, column) cells, strictly increasing in both, or None when no cell is allowed."""
    cost = np.asarray(cost, dtype=np.float64)
    allowed = np.ascontiguousarray(allowed, dtype=bool)
    if cost.shape != allowed.shape or cost.ndim != 2:
        raise InputError(f"cost {cost.shape} and allowed {allowed.shape} must be equal 2-D shapes")
    if not allowed.any():
        return None
    if reward is None:
        top = float(cost[allowed].max())
        reward = top + 1e-6 * max(1.0, abs(top))
    gain = np.ascontiguousarray(cost - reward)
    path, n = _dtw_kernel(gain, allowed)
    return path if n > 0 else None


def path_score(cost: np.ndarray, path: np.ndarray, reward: float) -> float:
    """The objective bounded_dtw minimises, evaluated on `path` (K, 2)."""
    path = np.asarray(path)
    g = np.asarray(cost, dtype=np.float64)[path[:, 0], path[:, 1]] - reward
    steps = np.diff(path, axis=0)
    weights = np.concatenate([[1.0], 0.5 * steps.sum(axis=1)])
    return float(np.sum(weights * g))


def slope_ok(path: np.ndarray) -> bool:
    """Every step advances both sides by ≥ 1 frame and neither side more than twice
    the other, so the slope of every sub-path lies in [1/2, 2]."""
    steps = np.diff(np.asarray(path), axis=0)
    if steps.size == 0:
        return True
    da, db = steps[:, 0], steps[:, 1]
    return bool(np.all(da >= 1) and np.all(db >= 1) and np.all(db <= 2 * da) and np.all(da <= 2 * db))


def aligned_segments(
    distance: np.ndarray,
    same_contacts: np.ndarray,
    threshold_m: float,
    rate_hz: float,
    min_seconds: float = 0.5,
) -> list[np.ndarray]:
    """Aligned frame pairs worth blending: one DTW path (K, 2) int64 of (frame of a,
    frame of b) per similar region, kept when the elapsed time from its first to its
    last frame, (last − first)/rate_hz, is ≥ min_seconds on both sides.
    distance: (Fa, Fb) metres; same_contacts: (Fa, Fb) bool."""
    min_span = min_seconds * rate_hz - 1e-9  # in frames
    distance = np.asarray(distance, dtype=np.float64)
    out = []
    for region in similar_regions(distance, same_contacts, threshold_m):
        h, w = region.shape
        if h - 1 < min_span or w - 1 < min_span:  # the box already too short: skip the DP
            continue
        path = bounded_dtw(distance[region.a_slice, region.b_slice], region.mask, reward=threshold_m)
        if path is None:
            continue
        span = path[-1] - path[0]
        if span[0] >= min_span and span[1] >= min_span:
            out.append(path + np.array([region.a0, region.b0]))
    return out


def trim_to_reachable(
    path: np.ndarray, span_a: tuple[int, int], span_b: tuple[int, int], rate_hz: float, min_seconds: float = 0.5
) -> np.ndarray | None:
    """An aligned path (K, 2) shortened so that its segment can be entered and left:
    a segment is entered from the frame before its first cell in either clip and
    leaves to the frame after its last, and only frames inside a clip's reachable
    span [first, last] (`bridges.reachable_span`) are reached and have a way on. Cells
    are dropped from the front until one clip's frame before the first cell is ≥ its
    span's first, and from the back until one clip's frame after the last cell is ≤
    its span's last. None when what remains is shorter than min_seconds on either side."""
    (fa, la), (fb, lb) = span_a, span_b
    k0, k1 = 0, path.shape[0]
    while k0 < k1 and not (path[k0, 0] - 1 >= fa or path[k0, 1] - 1 >= fb):
        k0 += 1
    while k1 > k0 and not (path[k1 - 1, 0] + 1 <= la or path[k1 - 1, 1] + 1 <= lb):
        k1 -= 1
    if k1 - k0 < 2:
        return None
    out = path[k0:k1]
    span = out[-1] - out[0]
    min_span = min_seconds * rate_hz - 1e-9
    return out if span[0] >= min_span and span[1] >= min_span else None


# --------------------------------------------------------------------------- blending


def blend_timeline(path: np.ndarray, weight: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """Uniformly timed source coordinates of the blended frames.

    The blend's clock at path cell k is u_k = (1 − w)·(a_k − a_0) + w·(b_k − b_0)
    frames (for w = 0.5 the mean of the two sides' elapsed frames, so a (1, 2) step
    lasts 1.5 frames), strictly increasing. Output frame n sits at u = n for
    n = 0 … ⌊u_last⌋; its fractional frame coordinates in a and b are interpolated
    linearly between the path cells around it. At w = 0 this is exactly a's frames.
    Returns coords_a, coords_b: (K',) float frame indices."""
    path = np.asarray(path, dtype=np.float64)
    if path.ndim != 2 or path.shape[1] != 2 or path.shape[0] == 0:
        raise InputError(f"path must be (K, 2) with K ≥ 1, got {path.shape}")
    if not 0.0 <= weight <= 1.0:
        raise InputError(f"blend weight must lie in [0, 1], got {weight}")
    u = (1.0 - weight) * (path[:, 0] - path[0, 0]) + weight * (path[:, 1] - path[0, 1])
    count = int(np.floor(u[-1] + 1e-9)) + 1
    t = np.arange(count, dtype=np.float64)
    return np.interp(t, u, path[:, 0]), np.interp(t, u, path[:, 1])


def _bracket(num_frames: int, coords: np.ndarray):
    lo = np.clip(np.floor(coords).astype(np.int64), 0, num_frames - 1)
    hi = np.minimum(lo + 1, num_frames - 1)
    return lo, hi, coords - lo


def sample_linear(values: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """values (F, ...) float sampled at fractional frames coords (K,) by linear
    interpolation → (K, ...)."""
    values = np.asarray(values, dtype=np.float64)
    lo, hi, frac = _bracket(values.shape[0], np.asarray(coords, dtype=np.float64))
    frac = frac.reshape((-1,) + (1,) * (values.ndim - 1))
    return values[lo] * (1.0 - frac) + values[hi] * frac


def sample_rotations(rotations: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """rotations (F, J, 4) sampled at fractional frames coords (K,) by slerp → (K, J, 4)."""
    lo, hi, frac = _bracket(rotations.shape[0], np.asarray(coords, dtype=np.float64))
    return quat.slerp(rotations[lo], rotations[hi], frac[:, None])


def blend_along_path(rot_a: np.ndarray, rot_b: np.ndarray, path: np.ndarray, weight: float = 0.5) -> np.ndarray:
    """Blended local rotations (K', J, 4) of clips a (Fa, J, 4) and b (Fb, J, 4)
    along `path`, timed by `blend_timeline`: each clip is slerped at its warped
    fractional frame, then the two are slerped at `weight` (shortest arc).
    The root (world) rotation of b must first be expressed in a's frame, see
    `align_root_rotation`."""
    if rot_a.shape[1:] != rot_b.shape[1:]:
        raise InputError(f"rotation arrays {rot_a.shape} and {rot_b.shape} differ in joints")
    ca, cb = blend_timeline(path, weight)
    return quat.slerp(sample_rotations(rot_a, ca), sample_rotations(rot_b, cb), weight)


def blend_arrays_along_path(x_a: np.ndarray, x_b: np.ndarray, path: np.ndarray, weight: float = 0.5) -> np.ndarray:
    """Linear blend (K', ...) of per-frame float arrays x_a (Fa, ...) and x_b (Fb, ...)
    along `path` on the `blend_timeline` clock, e.g. root heights (F,) in metres or
    local translations (F, J, 3)."""
    if np.shape(x_a)[1:] != np.shape(x_b)[1:]:
        raise InputError(f"arrays {np.shape(x_a)} and {np.shape(x_b)} differ in per-frame shape")
    ca, cb = blend_timeline(path, weight)
    return (1.0 - weight) * sample_linear(x_a, ca) + weight * sample_linear(x_b, cb)


# --------------------------------------------------------------------------- ground motion


def path_alignment(fa: PoseFeatures, fb: PoseFeatures, path: np.ndarray) -> tuple[float, np.ndarray]:
    """The rigid ground motion taking b onto a at the path's first cell:
    θ radians about +Y and translation (2,) (x, z) metres (`distance.alignment`)."""
    theta, shift = alignment(fa, np.asarray(path[:1, 0]), fb, np.asarray(path[:1, 1]))
    return float(theta[0]), shift[0]


def align_ground(ground: np.ndarray, heading: np.ndarray, theta: float, translation: np.ndarray):
    """Apply p ↦ R_y(θ)·p + t to ground positions (F, 2) (x, z) metres and θ to the
    headings (F,) radians (atan2(x, z) of the facing direction, so a rotation by θ
    about +Y adds θ). Returns (positions (F, 2), headings (F,) unwrapped)."""
    c, s = np.cos(theta), np.sin(theta)
    x, z = ground[:, 0], ground[:, 1]
    moved = np.stack([c * x + s * z, -s * x + c * z], axis=-1) + np.asarray(translation, dtype=np.float64)
    return moved, np.asarray(heading, dtype=np.float64) + theta


def align_root_rotation(rotations: np.ndarray, theta: float, root: int = 0) -> np.ndarray:
    """Copy of rotations (F, J, 4) with the root's world rotation turned by θ about +Y,
    so b's pose faces the way it does after `align_ground`."""
    out = np.array(rotations, dtype=np.float64, copy=True)
    out[:, root] = quat.mul(quat.about_y(theta), out[:, root])
    return out


def blend_ground(
    ground_a: np.ndarray,
    heading_a: np.ndarray,
    ground_b: np.ndarray,
    heading_b: np.ndarray,
    path: np.ndarray,
    theta: float,
    translation: np.ndarray,
    weight: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Blended root ground trajectory in a's frame.

    ground_*: (F, 2) root (x, z) positions in metres; heading_*: (F,) radians; theta,
    translation: the alignment of b onto a (`path_alignment`). b is moved rigidly
    into a's frame, both are sampled on the `blend_timeline` clock (headings unwrapped
    first so sampling never crosses ±π the long way) and blended: positions linearly,
    headings along the shorter arc. Returns positions (K', 2) and headings (K',)
    wrapped to [−π, π)."""
    gb, hb = align_ground(np.asarray(ground_b, dtype=np.float64), heading_b, theta, translation)
    ca, cb = blend_timeline(path, weight)
    pa = sample_linear(ground_a, ca)
    pb = sample_linear(gb, cb)
    ha = sample_linear(np.unwrap(np.asarray(heading_a, dtype=np.float64)), ca)
    hb = sample_linear(np.unwrap(hb), cb)
    heading = ha + weight * quat.wrap_angle(hb - ha)
    return (1.0 - weight) * pa + weight * pb, quat.wrap_angle(heading)
