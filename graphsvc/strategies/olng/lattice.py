"""The online lazy neighbourhood graph (Tautges et al. 2011, "Motion reconstruction
using sparse accelerometer data", §4; Tautges 2012, §3.4): per input sample, the K
knowledge-base frames whose readings are nearest become a new column of a window of
the last M columns, and every node of the newest column keeps the cheapest path that
ends in it.

A node is a knowledge-base frame f in column t (its cost: its readings' distance to
sample t's). A path enters node (t, f) from

- (t − 1, f − 1) or (t − 1, f − 2): the next frame or the one after (basic steps),
- (t − 2, f − 1): the next frame, a column skipped (a slower performance),
- (t − 2, f − 2), (t − 2, f − 3), (t − 2, f − 4): extended steps, a column skipped,

where f − k is the frame k before f in the same clip. A step that skips a column costs
the node it enters once more (standing in for the skipped column's node). A path's cost
over the window is one contribution a column: the cost of its node there (or of the
node a skip entered), and twice the K-th neighbour's distance for each window column
before the path starts, so a short path pays for the columns it does not explain. A
node's best path is the cheapest of the six extensions of its predecessors' best paths
and a new path starting at it; as the window slides, each path drops the contribution
of the column that leaves it. Each node carries its path's contributions over the last
M + 1 columns, so the update is O(K · M) a sample whatever the stream's length.

Ties go to the first candidate in the order above, a new start last (so a path goes on
rather than restarting at equal cost). The I cheapest nodes of the newest column give
the neighbourhood the pose is made from, weighted wᵢ = (max C − cᵢ) / Σⱼ (max C − cⱼ)
over those I (equal weights when all I costs are equal).

Written here in numba, not taken from a library: the lattice is the product, and its
update is a few array passes over K nodes a sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from graphsvc.errors import InputError

# (column back, frames back) of each step into a node, in the tie order.
BASIC_STEPS = ((1, 1), (1, 2), (2, 1))
EXTENDED_STEPS = ((2, 2), (2, 3), (2, 4))
STEPS = BASIC_STEPS + EXTENDED_STEPS
NEW_PATH = -1  # `step_of` of a path that starts at its node


@dataclass(frozen=True)
class LatticeOptions:
    """K neighbours a column, M columns in the window, I paths in the neighbourhood,
    and whether the extended steps are allowed (Tautges et al.'s defaults: K 4096,
    M 32, I 256, extended on)."""

    k: int = 4096
    m: int = 32
    i: int = 256
    extended: bool = True

    def check(self, frames: int | None = None) -> None:
        for name in ("k", "m", "i"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise InputError(f"OLNG {name.upper()} must be a whole number, got {v!r}")
        if self.k < 1:
            raise InputError(f"OLNG K must be ≥ 1, got {self.k}")
        if self.m < 2:
            raise InputError(f"OLNG M must be ≥ 2 (a path needs two columns), got {self.m}")
        if not 1 <= self.i <= self.k:
            raise InputError(f"OLNG I must be between 1 and K ({self.k}), got {self.i}")
        if frames is not None and self.k > frames:
            raise InputError(f"OLNG K ({self.k}) exceeds the knowledge base's {frames} frames")


class Lattice:
    """The window of one stream. push(frames (K,) int64, distances (K,)) per sample,
    where frames are knowledge-base frame numbers such that frame f − k is the frame
    k before f in the same clip exactly when clip_of[f − k] == clip_of[f] (frames of a
    clip numbered consecutively); then `best(I)` gives the I cheapest paths' newest
    frames, costs and weights."""

    def __init__(self, clip_of: np.ndarray, options: LatticeOptions = LatticeOptions()):
        options.check()
        self.options = options
        self.clip_of = np.ascontiguousarray(clip_of, dtype=np.int64)
        self.steps = np.array(STEPS if options.extended else BASIC_STEPS, dtype=np.int64)
        K, M = options.k, options.m
        self.t = -1
        # Columns t, t − 1, t − 2 (ring of 3): frames, sorted copy and its order, the
        # best path's cost, window contributions (M + 1 columns, ring by column), start
        # column and the step it came by.
        self.frames = np.full((3, K), -1, np.int64)
        self.sorted_frames = np.full((3, K), np.iinfo(np.int64).max, np.int64)
        self.sorted_at = np.zeros((3, K), np.int64)
        self.count = np.zeros(3, np.int64)
        self.cost = np.full((3, K), np.inf)
        self.contrib = np.zeros((3, K, M + 1))
        self.start = np.zeros((3, K), np.int64)
        self.step_of = np.zeros((3, K), np.int64)
        self.node_cost = np.zeros((3, K))
        self.penalty = np.zeros(M + 1)  # 2 × the K-th distance of each column, ring by column

    def push(self, frames: np.ndarray, distances: np.ndarray) -> None:
        frames = np.ascontiguousarray(frames, dtype=np.int64)
        distances = np.ascontiguousarray(distances, dtype=np.float64)
        if frames.ndim != 1 or frames.shape != distances.shape or not 1 <= frames.size <= self.options.k:
            raise InputError(
                f"a column needs 1 to {self.options.k} frames with a distance each, got {frames.shape} "
                f"and {distances.shape}"
            )
        if not np.all(np.isfinite(distances)) or (distances < 0).any():
            raise InputError("neighbour distances must be finite and ≥ 0")
        self.t += 1
        c = self.t % 3
        n = frames.size
        self.frames[c, :n], self.frames[c, n:] = frames, -1
        order = np.argsort(frames, kind="stable")
        self.sorted_frames[c, :n], self.sorted_frames[c, n:] = frames[order], np.iinfo(np.int64).max
        self.sorted_at[c, :n] = order
        self.count[c] = n
        self.node_cost[c, :n] = distances
        M = self.options.m
        self.penalty[self.t % (M + 1)] = 2.0 * float(distances.max())
        _advance(
            self.t,
            M,
            frames,
            distances,
            self.clip_of,
            self.steps,
            self.frames,
            self.sorted_frames,
            self.sorted_at,
            self.count,
            self.cost,
            self.contrib,
            self.start,
            self.step_of,
            self.penalty,
        )

    def column(self, back: int = 0) -> dict:
        """Column t − back: frames, node costs, best path costs, path lengths (window
        columns covered), the step each came by (index into `steps`, NEW_PATH)."""
        if back > 2 or self.t - back < 0:
            raise InputError(f"column t − {back} is not held")
        c = (self.t - back) % 3
        n = int(self.count[c])
        length = np.minimum(self.t - back - self.start[c, :n] + 1, self.options.m)
        return {
            "frames": self.frames[c, :n].copy(),
            "node_cost": self.node_cost[c, :n].copy(),
            "cost": self.cost[c, :n].copy(),
            "length": length,
            "step": self.step_of[c, :n].copy(),
        }

    def best(
        self, count: int | None = None, col: dict | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The I (count) cheapest paths into the newest column: (positions in the
        column, frames, costs, weights), cheapest first (ties: the column's order).
        col: `column()` when the caller has it already."""
        col = self.column() if col is None else col
        I = min(self.options.i if count is None else int(count), col["cost"].size)
        order = np.argsort(col["cost"], kind="stable")[:I]
        cost = col["cost"][order]
        return order, col["frames"][order], cost, path_weights(cost)


def path_weights(cost: np.ndarray) -> np.ndarray:
    """wᵢ = (max C − cᵢ) / Σⱼ (max C − cⱼ); equal weights when every cost is the same."""
    cost = np.asarray(cost, dtype=np.float64)
    room = cost.max() - cost
    total = room.sum()
    if not total > 0.0:
        return np.full(cost.size, 1.0 / cost.size)
    return room / total


@numba.njit(cache=True, nogil=True)
def _find(sorted_frames, count, frame):
    """Position in the column's sorted frames of `frame`, or −1."""
    lo, hi = 0, count
    while lo < hi:
        mid = (lo + hi) >> 1
        if sorted_frames[mid] < frame:
            lo = mid + 1
        else:
            hi = mid
    return lo if lo < count and sorted_frames[lo] == frame else -1


@numba.njit(cache=True, nogil=True)
def _advance(
    t,
    M,
    frames,
    distances,
    clip_of,
    steps,
    all_frames,
    sorted_frames,
    sorted_at,
    count,
    cost,
    contrib,
    start,
    step_of,
    penalty,
):
    """Column t's best paths (see the module docstring), written into ring slot t % 3."""
    R = M + 1
    c = t % 3
    n = frames.shape[0]
    # A new path at column t: 2 × the K-th distance of every earlier window column.
    start_cost = 0.0
    for tau in range(max(0, t - M + 1), t):
        start_cost += penalty[tau % R]
    drop1 = (t - M) % R  # the column that leaves a path one column old (t − 1's window)
    drop2 = (t - M - 1) % R
    for j in range(n):
        f = frames[j]
        d = distances[j]
        best = np.inf
        best_step = -1
        best_at = -1
        for s in range(steps.shape[0]):
            back, skip = steps[s, 0], steps[s, 1]
            if t - back < 0:
                continue
            g = f - skip
            if g < 0 or clip_of[g] != clip_of[f]:
                continue
            pc = (t - back) % 3
            p = _find(sorted_frames[pc], count[pc], g)
            if p < 0:
                continue
            a = sorted_at[pc, p]
            if back == 1:
                total = cost[pc, a] - (contrib[pc, a, drop1] if t - M >= 0 else 0.0) + d
            else:
                total = (
                    cost[pc, a]
                    - (contrib[pc, a, drop2] if t - M - 1 >= 0 else 0.0)
                    - (contrib[pc, a, drop1] if t - M >= 0 else 0.0)
                    + 2.0 * d
                )
            if total < best:
                best, best_step, best_at = total, s, a
        if start_cost + d < best:
            best_step = -1
        # The chosen path's contributions over the window, summed afresh (no drift).
        if best_step < 0:
            for tau in range(t - M, t):
                contrib[c, j, tau % R] = penalty[tau % R] if tau >= 0 else 0.0
            start[c, j] = t
        else:
            back = steps[best_step, 0]
            pc = (t - back) % 3
            for r in range(R):
                contrib[c, j, r] = contrib[pc, best_at, r]
            if back == 2:
                contrib[c, j, (t - 1) % R] = d
            start[c, j] = start[pc, best_at]
        contrib[c, j, t % R] = d
        total = 0.0
        for tau in range(max(0, t - M + 1), t + 1):
            total += contrib[c, j, tau % R]
        cost[c, j] = total
        step_of[c, j] = best_step
    for j in range(n, cost.shape[1]):
        cost[c, j] = np.inf
