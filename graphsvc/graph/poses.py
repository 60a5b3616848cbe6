"""The graph's node poses, stored compactly, and read back as float64 arrays.

A node keeps its whole local pose, so the graph alone can give any layout's readings
and every strategy its poses; stored as float32 this was 80 % of a graph file (756
bytes a node on a 27-joint skeleton). Two facts make it small without losing what
the poses say:

- **Rotations in 64 bits a joint** ("smallest three"): of a unit quaternion's four
  components the largest in magnitude follows from the other three, which lie in
  [−1/√2, 1/√2] and are stored in 20 bits each; three more bits hold which component
  was dropped (2) and its sign (1), so a stored quaternion keeps its sign (blends and
  the neighbour models see the same hemisphere as the source). A component is off by
  at most 6.8e-7, a rotation by at most ~4e-6 rad: a few micrometres at the end of a
  metre of bones. Readings recomputed from the stored poses (second differences at the
  graph's rate) differ from the build's by 0.0006 m/s² on average, 0.05 at most (the
  tests' procedural knowledge base; float32 poses: 0.02); 15 bits a component (48 a
  joint) put them 0.3 m/s² apart.
- **Rotations of the joints that turn**: end sites and joints without rotation
  channels hold the identity in every frame (to 2e-9 rad); they are not stored.
- **Translations by what moves**: in a BVH or AMC skeleton only the root (and, in
  some exports, one joint below it) is animated in translation; every other joint's
  local translation is its bone offset, the same in every frame of a clip and in most
  blends. A graph stores the moving joints' translations per node (float32)
  and the rest as a table of distinct bone sets with an index a node, on a grid of
  2^-24 m (6e-8 m; exports print constant channels with 1e-14 m of noise, which would
  make every frame a set of its own); a blend of two clips of different bone lengths
  gets its own set, so nothing is lost.

Packing is a numba pass (`cache=True`) because the build packs millions of joints and
the strategies unpack a handful of nodes a frame; no library offers this layout.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numba
import numpy as np

from graphsvc.graph.rows import distinct_rows, drain

if TYPE_CHECKING:
    from graphsvc.graph.model import MotionGraph

Nodes = int | slice | Sequence[int] | np.ndarray  # what numpy indexing takes

_HALF = np.float64(0.7071067811865476)  # 1/√2: the bound of the three kept components
_BITS = 20
_MID = 1 << (_BITS - 1)  # a component c is stored as _MID + round(c / _HALF · _SCALE)
_SCALE = float(_MID - 1)  # so 0 and ±1/√2 are exact
_MASK = (1 << _BITS) - 1


@numba.njit(cache=True)
def _pack(q, out):  # pragma: no cover - compiled
    for m in range(q.shape[0]):
        big = 0
        for k in range(1, 4):
            if abs(q[m, k]) > abs(q[m, big]):
                big = k
        norm = np.sqrt(q[m, 0] ** 2 + q[m, 1] ** 2 + q[m, 2] ** 2 + q[m, 3] ** 2)
        if norm == 0.0:
            norm = 1.0
        word = np.uint64(0)
        shift = 0
        for k in range(4):
            if k == big:
                continue
            c = min(max(q[m, k] / norm / _HALF, -1.0), 1.0)
            word |= np.uint64(_MID + np.int64(np.rint(c * _SCALE))) << np.uint64(shift)
            shift += _BITS
        word |= np.uint64(big) << np.uint64(3 * _BITS)
        if q[m, big] < 0.0:
            word |= np.uint64(1) << np.uint64(3 * _BITS + 2)
        out[m] = word


@numba.njit(cache=True)
def _unpack(words, out):  # pragma: no cover - compiled
    for m in range(words.shape[0]):
        word = words[m]
        big = np.int64((word >> np.uint64(3 * _BITS)) & np.uint64(3))
        rest = 1.0
        shift = 0
        for i in range(4):
            if i == big:
                continue
            u = np.int64((word >> np.uint64(shift)) & np.uint64(_MASK))
            c = (u - _MID) / _SCALE * _HALF
            out[m, i] = c
            rest -= c * c
            shift += _BITS
        v = np.sqrt(max(rest, 0.0))
        out[m, big] = -v if (word >> np.uint64(3 * _BITS + 2)) & np.uint64(1) else v


def pack_rotations(rotations: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) (w, x, y, z; normalised first) → (...) uint64."""
    q = np.ascontiguousarray(rotations, dtype=np.float64).reshape(-1, 4)
    out = np.zeros(q.shape[0], np.uint64)
    if q.shape[0]:
        _pack(q, out)
    return out.reshape(np.shape(rotations)[:-1])


def unpack_rotations(words: np.ndarray) -> np.ndarray:
    """(...) uint64 from `pack_rotations` → unit quaternions (..., 4) float64."""
    w = np.ascontiguousarray(words, dtype=np.uint64).reshape(-1)
    out = np.empty((w.shape[0], 4))
    if w.shape[0]:
        _unpack(w, out)
    return out.reshape(np.shape(words) + (4,))


MOVING_M = 1e-6  # a joint whose translation changes more within a clip is stored per node
STILL_RAD = 2e-9  # a joint whose rotation stays closer to the identity in every clip is not stored
BONE_GRID_M = 2.0**-24  # the other joints' translations, on this grid (exact in float32 below 1 m)


def moving_joints(translations: list[np.ndarray]) -> np.ndarray:
    """(V,) int32: the root and every joint whose local translation changes by more than
    MOVING_M within one of the clips' translations [(F, J, 3)] — the joints a graph
    stores per node. (Exports print constant channels with float noise: 1e-14 m.)"""
    J = translations[0].shape[1] if translations else 1
    moving = np.zeros(J, bool)
    moving[0] = True
    for t in translations:
        if len(t):
            moving |= np.ptp(np.asarray(t, np.float64), axis=0).max(axis=-1) > MOVING_M
    return np.nonzero(moving)[0].astype(np.int32)


def rotating_joints(rotations: list[np.ndarray]) -> np.ndarray:
    """(R,) int32: the root and every joint whose local rotation is more than STILL_RAD
    from the identity in some frame of the clips' rotations [(F, J, 4)]; the others
    (end sites, joints without rotation channels) are stored as nothing and read back
    as the identity. (A retargeted clip's end sites hold 1e-16 rad of rounding.)"""
    J = rotations[0].shape[1] if rotations else 1
    turning = np.zeros(J, bool)
    turning[0] = True
    for q in rotations:
        if len(q):
            turning |= np.abs(np.asarray(q)[..., 1:]).max(axis=(0, 2)) > STILL_RAD / 2
    return np.nonzero(turning)[0].astype(np.int32)


class PosePacker:
    """Gathers node poses part by part as the graph file holds them: the packed
    rotations of the rotating joints, the moving joints' translations and an index into
    the distinct bone sets, numbered in the order they first appear (so equal builds
    give equal bytes)."""

    def __init__(self, rotating: np.ndarray, moving: np.ndarray, num_joints: int):
        self.rotating = np.asarray(rotating, np.int32)
        self.still = np.setdiff1d(np.arange(num_joints), self.rotating)
        self.moving = np.asarray(moving, np.int32)
        self.fixed = np.setdiff1d(np.arange(num_joints), self.moving)
        self.num_joints = num_joints
        self.rotations: list[np.ndarray] = []
        self.moving_translations: list[np.ndarray] = []
        self.bone_index: list[np.ndarray] = []
        self._sets: dict[bytes, int] = {}
        self._rows: list[np.ndarray] = []

    def add(self, rotations: np.ndarray, translations: np.ndarray) -> None:
        """rotations (M, J, 4), translations (M, J, 3) local, metres."""
        t = np.asarray(translations, np.float32)
        q = np.asarray(rotations)
        # A blend of identities is the identity to rounding; anything more is a build error.
        if self.still.size and float(np.abs(q[:, self.still, 1:]).max(initial=0.0)) > 1e-6:
            raise ValueError("a joint without rotation in every clip turns in a made node")
        self.rotations.append(pack_rotations(q[:, self.rotating]))
        self.moving_translations.append(np.ascontiguousarray(t[:, self.moving]))
        on_grid = np.round(np.asarray(translations, np.float64)[:, self.fixed] / BONE_GRID_M) * BONE_GRID_M
        fixed = np.ascontiguousarray(on_grid, np.float32).reshape(len(t), 3 * len(self.fixed))
        if len(t) == 0:
            self.bone_index.append(np.zeros(0, np.int32))
            return
        if fixed.shape[1] == 0:  # every joint moves: one empty set
            fixed = np.zeros((len(t), 1), np.float32)
        first, label = distinct_rows(fixed)  # (in order of first appearance)
        ids = np.empty(len(first), np.int32)
        for r, row in enumerate(first):
            key = fixed[row].tobytes()
            if key not in self._sets:
                self._sets[key] = len(self._rows)
                full = np.zeros((self.num_joints, 3), np.float32)
                full[self.fixed] = fixed[row, : 3 * len(self.fixed)].reshape(-1, 3)
                self._rows.append(full)
            ids[r] = self._sets[key]
        self.bone_index.append(ids[label])

    def arrays(self) -> dict[str, Any]:
        """The MotionGraph's pose arrays, once: the chunks added are freed as they are copied."""
        J, R, V = self.num_joints, len(self.rotating), len(self.moving)
        return {
            "node_rot64": drain(self.rotations, (0, R), np.uint64),
            "rotating_joints": self.rotating.copy(),
            "node_moving": drain(self.moving_translations, (0, V, 3), np.float32),
            "node_bones": drain(self.bone_index, (0,), np.int32),
            "bone_sets": np.stack(self._rows) if self._rows else np.zeros((0, J, 3), np.float32),
            "moving_joints": self.moving.copy(),
        }


def pack_poses(rotations: np.ndarray, translations: np.ndarray) -> dict:
    """Every node's pose at once (N, J, 4), (N, J, 3) → the MotionGraph's pose arrays
    (the rotating and moving joints found over all rows)."""
    t = np.asarray(translations)
    packer = PosePacker(rotating_joints([np.asarray(rotations)]), moving_joints([t]), t.shape[1])
    packer.add(rotations, t)
    return packer.arrays()


def node_rotations(graph: MotionGraph, nodes: Nodes) -> np.ndarray:
    """Local unit quaternions of graph nodes (an index, a slice or an array of them):
    (..., J, 4) float64."""
    turning = unpack_rotations(graph.node_rot64[nodes])
    out = np.zeros(turning.shape[:-2] + (graph.bone_sets.shape[1], 4))
    out[..., 0] = 1.0
    out[..., graph.rotating_joints, :] = turning
    return out


def node_translations(graph: MotionGraph, nodes: Nodes) -> np.ndarray:
    """Local joint translations of graph nodes (..., J, 3) float64, metres."""
    out = graph.bone_sets[graph.node_bones[nodes]].astype(np.float64)
    out[..., graph.moving_joints, :] = graph.node_moving[nodes]
    return out


def node_poses(graph: MotionGraph, nodes: Nodes) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (..., J, 4), translations (..., J, 3)) float64 of graph nodes."""
    return node_rotations(graph, nodes), node_translations(graph, nodes)
