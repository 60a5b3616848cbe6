"""Local poses as flat vectors, and a motion's local poses replaced by others.

A local pose says how the body is posed and not where it stands or faces: the pelvis
rotation with the frame's heading taken off (4), the pelvis height (1, m), and the local
rotation of every joint under the pelvis (4 each), each quaternion on the w ≥ 0 side so
that poses can be averaged and regressed component by component (`strategies.refine`).
The heading is `signals.heading`, the one the graph's nodes carry. `place_local_poses`
puts such vectors into a motion at each frame's own ground position and heading, so the
root's track and turning stay the motion's and only the pose changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion import signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.placement import joint_tables, place_poses, relative_pose

CHUNK = 32768


@dataclass(frozen=True)
class PoseLayout:
    """Where a skeleton's local pose sits in a vector: the joints under the pelvis
    (`joints`, in skeleton order) from index 5 on, four values each; the joint map,
    the pelvis and the carrier joint (`placement.joint_tables`)."""

    joints: np.ndarray
    table: dict
    pelvis: int
    carrier: int

    @property
    def dims(self) -> int:
        return 5 + 4 * self.joints.size

    @property
    def slot(self) -> np.ndarray:
        """(1 + joints,) the column each quaternion starts at: 0, then 5, 9, …"""
        return np.concatenate([[0], 5 + 4 * np.arange(self.joints.size)]).astype(np.int64)


def pose_layout(skeleton, mapping=None) -> PoseLayout:
    table = joint_map(skeleton, mapping)
    below, carrier = joint_tables(skeleton, table)
    return PoseLayout(np.flatnonzero(below).astype(np.int64), table, int(table["pelvis"]), int(carrier))


@numba.njit(cache=True, nogil=True)
def positive_quaternions(p, slot):
    """Each quaternion of pose vectors p (F, D), starting at the columns `slot` (K,),
    onto its w ≥ 0 side, in place."""
    for f in range(p.shape[0]):
        for k in range(slot.shape[0]):
            s = slot[k]
            if p[f, s] < 0.0:
                for c in range(4):
                    p[f, s + c] = -p[f, s + c]


def pose_vectors(
    rot: np.ndarray, trans: np.ndarray, parents: np.ndarray, layout: PoseLayout, heading: np.ndarray | None = None
) -> np.ndarray:
    """(F, D) float64 local poses of frames with local rotations (F, J, 4) and
    translations (F, J, 3); heading (F,) rad: the frames' own when known (a graph's
    nodes carry theirs), else `signals.heading` of their pose."""
    world_rot, world_pos = forward_kinematics(rot, trans, parents)
    if heading is None:
        heading = signals.heading(world_pos, layout.table)
    rel, height = relative_pose(world_rot, world_pos, heading, layout.pelvis)
    F = rot.shape[0]
    p = np.empty((F, layout.dims))
    p[:, 0:4] = rel
    p[:, 4] = height
    p[:, 5:] = rot[:, layout.joints].reshape(F, -1)
    positive_quaternions(p, layout.slot)
    return p


def node_pose_vectors(graph: MotionGraph, nodes: np.ndarray, layout: PoseLayout) -> np.ndarray:
    """(F, D) float32 local poses of graph nodes."""
    nodes = np.asarray(nodes, dtype=np.int64)
    out = np.empty((nodes.size, layout.dims), np.float32)
    parents = graph.skeleton.parents
    for lo in range(0, nodes.size, CHUNK):
        n = nodes[lo : lo + CHUNK]
        out[lo : lo + n.size] = pose_vectors(node_rotations(graph, n), node_translations(graph, n), parents, layout)
    return out


def place_local_poses(
    rot: np.ndarray, trans: np.ndarray, parents: np.ndarray, layout: PoseLayout, poses: np.ndarray, use: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Copies of a motion's (rot (T, J, 4), trans (T, J, 3)) with the frames where `use`
    (T,) holds posed as `poses` (T, D) says (quaternions normalised here), each at its
    own ground position and heading (`signals`); the other frames untouched. Frame by
    frame: the same frames give the same output whatever else is in the call."""
    rot = np.array(rot, dtype=np.float64, copy=True)
    trans = np.array(trans, dtype=np.float64, copy=True)
    idx = np.flatnonzero(np.asarray(use, dtype=bool))
    if idx.size == 0:
        return rot, trans
    p = np.asarray(poses, dtype=np.float64)[idx]
    _, world_pos = forward_kinematics(rot[idx], trans[idx], parents)
    ground = signals.ground_position(world_pos, layout.pelvis)
    heading = signals.heading(world_pos, layout.table)
    rel = p[:, 0:4] / np.linalg.norm(p[:, 0:4], axis=1, keepdims=True)
    q = p[:, 5:].reshape(idx.size, -1, 4)
    r, tr = rot[idx], trans[idx]
    r[:, layout.joints] = q / np.linalg.norm(q, axis=2, keepdims=True)
    src_rot, src_pos = forward_kinematics(r, tr, parents)
    place_poses(
        r,
        tr,
        rel,
        p[:, 4].copy(),
        ground,
        heading,
        src_rot,
        src_pos,
        np.ascontiguousarray(parents, np.int64),
        layout.pelvis,
        layout.carrier,
    )
    rot[idx], trans[idx] = r, tr
    return rot, trans
