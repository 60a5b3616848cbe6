"""The SSG path's subsequences as poses: each output frame is one or two knowledge-base
frames (two inside an overlap, cross-faded), each placed on the input by its
subsequence's own transform (Tautges 2012, eq. 4.5: globally aligned, not only
locally). A fractional frame (a slowed step, a chain extended at its warping factor)
is slerped between the two frames around it. Rotations blend by slerp, translations
linearly; the placement is realised at the pelvis (or its nearest ancestor with
position channels), so two sources' placed roots blend in the input's world. Nothing is
optimised afterwards: the thesis keeps the captured detail for an animator to edit.
"""

from __future__ import annotations

import numpy as np

from graphsvc.graph.model import MotionGraph
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion import quat
from graphsvc.motion.joints import joint_map
from graphsvc.motion.placement import joint_tables
from graphsvc.strategies.ssg.graph import Anchor
from graphsvc.strategies.ssg.index import SsgIndex


def _frame_pose(graph: MotionGraph, index: SsgIndex, f: np.ndarray):
    """Local rotations (L, J, 4) and translations (L, J, 3) at fractional index frames."""
    lo = np.floor(f).astype(np.int64)
    hi = np.minimum(lo + 1, index.run_last[lo])
    w = f - lo
    a, b = index.nodes[lo], index.nodes[hi]
    rot = quat.slerp(
        node_rotations(graph, a),
        node_rotations(graph, b),
        np.broadcast_to(w[:, None], (f.size, graph.skeleton.num_joints)),
    )
    trans = node_translations(graph, a) * (1.0 - w[:, None, None]) + node_translations(graph, b) * w[:, None, None]
    return rot, trans


def _carrier_chain(graph: MotionGraph) -> list[int]:
    """Joint 0 … the carrier: the joint that holds the placement (the pelvis, or its
    nearest ancestor with position channels; `motion.placement.joint_tables`)."""
    _, carrier = joint_tables(graph.skeleton, joint_map(graph.skeleton, graph.params.get("mapping")))
    chain = [int(carrier)]
    while graph.skeleton.parents[chain[-1]] >= 0:
        chain.append(int(graph.skeleton.parents[chain[-1]]))
    return chain[::-1]


def _placed_pose(graph, index, anchors: list[Anchor], anchor: np.ndarray, f: np.ndarray, chain: list[int]):
    """The poses at fractional frames f, each placed by its anchor's transform: the
    carrier's world transform turned and moved, re-expressed under its parent (which,
    like every joint above, keeps its own values), so two sources blend in one frame."""
    rot, trans = _frame_pose(graph, index, f)
    theta = np.array([anchors[a].theta for a in anchor])
    t = np.array([[anchors[a].tx, 0.0, anchors[a].tz] for a in anchor]).reshape(-1, 3)
    turn = quat.about_y(theta)
    p_rot = np.zeros((f.size, 4))
    p_rot[:, 0] = 1.0
    p_pos = np.zeros((f.size, 3))
    for j in chain[:-1]:  # the carrier's parent's world transform
        p_pos = p_pos + quat.rotate(p_rot, trans[:, j])
        p_rot = quat.mul(p_rot, rot[:, j])
    c = chain[-1]
    w_rot = quat.mul(turn, quat.mul(p_rot, rot[:, c]))
    w_pos = quat.rotate(turn, p_pos + quat.rotate(p_rot, trans[:, c])) + t
    rot[:, c] = quat.mul(quat.conjugate(p_rot), w_rot)
    trans[:, c] = quat.inv_rotate(p_rot, w_pos - p_pos)
    return rot, trans


def poses(
    graph: MotionGraph,
    index: SsgIndex,
    anchors: list[Anchor],
    anchor: np.ndarray,
    frame: np.ndarray,
    weight: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (L, J, 4) and translations (L, J, 3) of frames given as up to two
    sources each (`SsgDecoder.sources`: anchor, index frame, weight (L, 2))."""
    chain = _carrier_chain(graph)
    rot, trans = _placed_pose(graph, index, anchors, anchor[:, 0], frame[:, 0], chain)
    two = np.flatnonzero(anchor[:, 1] >= 0)
    if two.size:
        r2, t2 = _placed_pose(graph, index, anchors, anchor[two, 1], frame[two, 1], chain)
        w2 = weight[two, 1]
        rot[two] = quat.slerp(rot[two], r2, np.broadcast_to(w2[:, None], r2.shape[:2]))
        trans[two] = trans[two] * (1.0 - w2[:, None, None]) + t2 * w2[:, None, None]
    return rot, trans


def provenance(graph: MotionGraph, index: SsgIndex, anchor: np.ndarray, frame: np.ndarray, weight: np.ndarray):
    """(clip (L, 2), clip frame (L, 2), weight (L, 2), label (L,)) of frames given as
    sources, heaviest first."""
    order = np.argsort(-weight, axis=1, kind="stable")
    anchor = np.take_along_axis(anchor, order, axis=1)
    frame = np.take_along_axis(frame, order, axis=1)
    weight = np.take_along_axis(weight, order, axis=1)
    lo = np.floor(frame).astype(np.int64)
    clip = np.where(anchor >= 0, index.clip[lo], -1)
    clip_frame = np.where(anchor >= 0, index.clip_frame[lo] + (frame - lo), 0.0)
    label = np.asarray(graph.labels, dtype=object)[np.asarray(graph.node_label)[index.nodes[lo[:, 0]]]]
    return clip, clip_frame, np.where(anchor >= 0, weight, 0.0), label
