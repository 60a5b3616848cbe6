"""Full-body motion from a node path through the motion graph (SPEC §5, K §5).

Pipeline, all on flat (T, ...) arrays:

1. Root path: integrate the path's edge offsets from a start ground position and
   heading (`metadata.integrate_path`).
2. Poses: each frame takes its node's local pose. The pose is described relative to
   its node's own ground position/heading in the source clip (pelvis rotation with
   the node heading removed, pelvis height, local rotations below the pelvis) and
   re-placed at the integrated ground position/heading.
3. Blending (offset blending, after Kovar & Gleicher / Lee & Shin "motion
   displacement"): at every discontinuity the pose difference D between the entered
   clip's own previous frame and the frame we leave is spread over a window of w
   seconds centred on the transition — frames before get +α·D, frames after −(1−α)·D,
   α a smoothstep rising across the window. Each side thus keeps its own clip's
   velocity and the result is C¹ at the window ends. Rotations are offset through
   rotation vectors (several overlapping windows add up), the pelvis height
   linearly; the pelvis uses w = 0.1 s when both feet are off the ground.
4. Footskate clean-up: while a foot's contact flag is on, the ankle and toe may move
   only as they moved in their source clip (heel and toe roll are kept); whatever
   extra motion the synthesis added is removed by an accumulated world offset,
   solved with analytic two-bone IK on hip–knee–ankle (knee bend plane kept) plus a
   foot swing for the toe, blended out over a short window after the span.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph import metadata as meta
from graphsvc.graph.model import (
    EDGE_INTERP,
    EDGE_TRANSITION,
    NODE_INTERP,
    NODE_ORIGINAL,
    NODE_SLOW,
    MotionGraph,
)
from graphsvc.motion import quat
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics, motion_fk
from graphsvc.motion.skeleton import Motion

FOOT_BLEND_S = 0.1  # blend-out of the foot pinning after a contact span (s)


# ---------------------------------------------------------------- small helpers


def smoothstep(x: np.ndarray) -> np.ndarray:
    """3x² − 2x³ on x clipped to [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def quat_log(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) (axis × angle, rad) of unit quaternions (..., 4),
    shortest arc."""
    q = np.where(q[..., :1] < 0.0, -q, q)
    v = q[..., 1:]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., :1])
    # angle/s → 2 as s → 0 (first-order), so small rotations stay exact.
    scale = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return v * scale


def quat_exp(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3) (rad)."""
    angle = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * angle
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half), r * k], axis=-1)


def _ancestors(parents: np.ndarray, joint: int) -> list[int]:
    """Strict ancestors of `joint`, root first."""
    out = []
    p = int(parents[joint])
    while p >= 0:
        out.append(p)
        p = int(parents[p])
    return out[::-1]


def _descendant_mask(parents: np.ndarray, joint: int) -> np.ndarray:
    """(J,) bool: `joint` and every joint below it (topological order)."""
    mask = np.zeros(parents.shape[0], dtype=bool)
    mask[joint] = True
    for j in range(joint + 1, parents.shape[0]):
        if parents[j] >= 0 and mask[parents[j]]:
            mask[j] = True
    return mask


def _has_position(channels: tuple[str, ...]) -> bool:
    return any(c.endswith("position") for c in channels)


# ---------------------------------------------------------------- path structure


def continuous_edges(graph: MotionGraph, edges: np.ndarray) -> np.ndarray:
    """(K,) bool: the edge plays on inside one source sequence (original, slow-down,
    speed-up, or a step inside an interpolated segment) — no pose jump."""
    kind = graph.edge_kind[edges]
    src, dst = graph.edge_src[edges], graph.edge_dst[edges]
    inside_segment = (graph.node_kind[src] == NODE_INTERP) & (graph.node_kind[dst] == NODE_INTERP) & (dst == src + 1)
    return (kind != EDGE_TRANSITION) & ((kind != EDGE_INTERP) | inside_segment)


def predecessor_nodes(graph: MotionGraph, nodes: np.ndarray) -> np.ndarray:
    """(K,) the node one step before each node in its own source sequence (the clip
    or interpolated segment it belongs to); the node itself when it starts one.
    Used to continue the entered clip backwards across a transition."""
    nodes = np.asarray(nodes, dtype=np.int64)
    kind = graph.node_kind[nodes]
    frame = graph.node_frame[nodes]
    first = np.array([c["first_node"] for c in graph.clips], dtype=np.int64)[graph.node_clip[nodes]]
    out = nodes.copy()
    orig = (kind == NODE_ORIGINAL) & (frame >= 1.0)
    out[orig] = nodes[orig] - 1
    slow = kind == NODE_SLOW  # between original frames f and f+1: f precedes it
    out[slow] = first[slow] + np.floor(frame[slow]).astype(np.int64)
    seg_first = np.array([s["first_node"] for s in graph.segments], dtype=np.int64)
    interp = (kind == NODE_INTERP) & ~np.isin(nodes, seg_first)
    out[interp] = nodes[interp] - 1
    return out


def check_path(graph: MotionGraph, node_path: np.ndarray, edge_path: np.ndarray, allow_jumps: bool = False) -> None:
    """Raise InputError unless edge_path[k] enters node_path[k+1] — and, unless
    allow_jumps, leaves node_path[k] (a streaming decoder's revisions jump)."""
    T = node_path.shape[0]
    if T == 0:
        raise InputError("empty node path")
    if edge_path.shape != (T - 1,):
        raise InputError(f"edge path must have {T - 1} entries, got {edge_path.shape}")
    if np.any((node_path < 0) | (node_path >= graph.num_nodes)) or np.any((edge_path < 0) | (edge_path >= graph.num_edges)):
        raise InputError("node or edge index out of range")
    if np.any(graph.edge_dst[edge_path] != node_path[1:]):
        raise InputError("edge path does not enter the node path")
    if not allow_jumps and np.any(graph.edge_src[edge_path] != node_path[:-1]):
        raise InputError("edge path does not connect the node path")


# ---------------------------------------------------------------- pose description


def _relative_pose(graph: MotionGraph, nodes: np.ndarray, pelvis: int):
    """Node poses with their source placement removed: pelvis world rotation with the
    node heading taken off (K, 4), pelvis height (K,) (m), plus source-clip world
    rotations/positions (K, J, 4/3) from FK."""
    world_rot, world_pos = forward_kinematics(graph.node_rotations[nodes], graph.node_translations[nodes], graph.skeleton.parents)
    rel = quat.mul(quat.about_y(-graph.node_heading[nodes].astype(np.float64)), world_rot[:, pelvis])
    return rel, world_pos[:, pelvis, 1].copy(), world_rot, world_pos


def _blend_offsets(T: int, cuts: np.ndarray, values: np.ndarray, half_widths: np.ndarray) -> np.ndarray:
    """(T, ...) sum of offset-blend contributions: for each cut k (a jump between
    frames cuts[k]−1 and cuts[k]) with difference values[k] (entered − left) and
    window half-width half_widths[k] (frames): +α·D before the cut, −(1−α)·D after,
    α = smoothstep across [cut − ½ − h, cut − ½ + h]."""
    out = np.zeros((T,) + values.shape[1:])
    t = np.arange(T, dtype=np.float64)
    for cut, d, h in zip(cuts, values, half_widths):
        lo, hi = max(0, int(np.floor(cut - 0.5 - h))), min(T, int(np.ceil(cut - 0.5 + h)) + 1)
        tt = t[lo:hi]
        alpha = smoothstep((tt - (cut - 0.5) + h) / (2.0 * h))
        w = np.where(tt < cut, alpha, alpha - 1.0)
        out[lo:hi] += w.reshape((-1,) + (1,) * d.ndim) * d
    return out


# ---------------------------------------------------------------- IK


def two_bone_ik(
    rotations: np.ndarray, world_rot: np.ndarray, world_pos: np.ndarray, parents: np.ndarray,
    hip: int, knee: int, ankle: int, toe: int, ankle_target: np.ndarray, toe_target: np.ndarray,
    lateral: np.ndarray,
) -> None:
    """Analytic two-bone IK on frames (K,) of one leg, in place on local `rotations`
    (K, J, 4), given FK world rotations/positions (K, J, 4/3) of the current pose.

    The knee flexes in the leg's current bend plane (normal hip→knee × knee→ankle;
    `lateral` (K, 3), the pelvis's right→left axis, for a straight leg) to reach the
    target hip–ankle distance, then the hip swings the leg by the shortest rotation
    onto the target. The foot keeps its world orientation except for the shortest
    swing that points it at `toe_target`. Targets (K, 3) in metres."""
    a, b, c = world_pos[:, hip], world_pos[:, knee], world_pos[:, ankle]
    l1 = np.linalg.norm(b - a, axis=-1)
    l2 = np.linalg.norm(c - b, axis=-1)
    d = np.clip(np.linalg.norm(ankle_target - a, axis=-1), np.abs(l1 - l2) + 1e-4, l1 + l2 - 1e-4)
    cos_now = np.sum((a - b) * (c - b), axis=-1) / (l1 * l2)
    cos_new = (l1 * l1 + l2 * l2 - d * d) / (2.0 * l1 * l2)
    # Rotating knee→ankle about (knee→ankle) × (knee→hip) = (hip→knee) × (knee→ankle)
    # by +φ closes the knee angle by φ.
    n = np.cross(b - a, c - b)
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(nn > 1e-4 * (l1 * l2)[:, None], n / np.maximum(nn, 1e-12), lateral)
    bend = np.arccos(np.clip(cos_now, -1, 1)) - np.arccos(np.clip(cos_new, -1, 1))
    knee_delta = quat.from_axis_angle(n, bend)
    c1 = b + quat.rotate(knee_delta, c - b)
    swing = quat.between(c1 - a, ankle_target - a)
    hip_w = quat.mul(swing, world_rot[:, hip])
    knee_w = quat.mul(swing, quat.mul(knee_delta, world_rot[:, knee]))
    # Foot: keep its world orientation, then swing ankle→toe onto the toe target.
    foot = world_pos[:, toe] - world_pos[:, ankle]  # unchanged by moving the leg above it
    foot_w = quat.mul(quat.between(foot, toe_target - ankle_target), world_rot[:, ankle])
    parent_w = world_rot[:, parents[hip]]
    rotations[:, hip] = quat.mul(quat.conjugate(parent_w), hip_w)
    rotations[:, knee] = quat.mul(quat.conjugate(hip_w), knee_w)
    rotations[:, ankle] = quat.mul(quat.conjugate(knee_w), foot_w)


def contact_spans(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) runs of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.nonzero(edges == 1)[0].tolist(), np.nonzero(edges == -1)[0].tolist()))


def foot_corrections(out_pos: np.ndarray, intended: np.ndarray, flags: np.ndarray, blend_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """World offsets (T, 3) (m) that remove a joint's skate and their weights (T,).

    out_pos (T, 3): the joint's synthesized trajectory; intended (T, 3): the
    displacement it should have from frame t−1 to t (its source clip's own motion,
    placed; row 0 unused); flags (T,): contact. Inside a span the offset is the
    accumulated difference (so the joint moves exactly as intended from the span's
    first frame); after the span it decays to zero over `blend_frames`."""
    T = out_pos.shape[0]
    offset = np.zeros((T, 3))
    weight = np.zeros(T)
    skate = np.zeros((T, 3))
    skate[1:] = out_pos[1:] - out_pos[:-1] - intended[1:]
    for s, e in contact_spans(flags):
        offset[s:e] = -np.cumsum(np.concatenate([np.zeros((1, 3)), skate[s + 1:e]]), axis=0)
        weight[s:e] = 1.0
        k = np.arange(1, blend_frames + 1)
        k = k[(e - 1 + k < T)]
        free = ~flags[e - 1 + k]  # never overwrite the next span
        k = k[free]
        w = 1.0 - smoothstep(k / (blend_frames + 1.0))
        offset[e - 1 + k] = offset[e - 1] * w[:, None]
        weight[e - 1 + k] = w
    return offset, weight


# ---------------------------------------------------------------- main entry


def synthesize_motion(
    graph: MotionGraph,
    node_path: np.ndarray,
    edge_path: np.ndarray,
    start_ground: np.ndarray,
    start_heading: float,
    blend_s: float = 0.7,
    flight_root_blend_s: float = 0.1,
    fix_feet: bool = True,
    mapping=None,
    allow_jumps: bool = False,
) -> Motion:
    """The motion (T frames at graph.rate_hz on graph.skeleton) of a node path (T,)
    and the edges (T−1,) between its nodes, started at `start_ground` (2,) (x, z in
    m) and `start_heading` (rad). blend_s / flight_root_blend_s: blend windows (s)
    at pose discontinuities, for the pelvis the second while both feet are off the
    ground on both sides. fix_feet: footskate clean-up during contact flags.
    allow_jumps: edges may leave another node than the previous one (a streaming
    decoder's revision); such a step is blended as a cut, its edge still moves the root."""
    node_path = np.asarray(node_path, dtype=np.int64).reshape(-1)
    edge_path = np.asarray(edge_path, dtype=np.int64).reshape(-1)
    check_path(graph, node_path, edge_path, allow_jumps)
    sk = graph.skeleton
    parents = sk.parents
    T = node_path.shape[0]
    table = joint_map(sk, mapping if mapping is not None else graph.params.get("mapping"))
    pelvis = table["pelvis"]
    rate = float(graph.rate_hz)

    # a. Root path.
    ground, heading = meta.integrate_path(
        np.asarray(start_ground, dtype=np.float64), float(start_heading),
        graph.edge_offset[edge_path].astype(np.float64), graph.edge_heading[edge_path].astype(np.float64),
    )  # fmt: skip

    # b. Poses relative to their source placement.
    rot = graph.node_rotations[node_path].astype(np.float64)
    trans = graph.node_translations[node_path].astype(np.float64)
    rel, height, src_rot, src_pos = _relative_pose(graph, node_path, pelvis)
    below = _descendant_mask(parents, pelvis)
    below[pelvis] = False  # the pelvis itself is blended through `rel`

    # c. Offset blending at discontinuities.
    cont = continuous_edges(graph, edge_path) & (graph.edge_src[edge_path] == node_path[:-1])
    cuts = np.nonzero(~cont)[0] + 1  # frame index right after each jump
    pred = node_path.copy()
    pred[1:] = np.where(cont, node_path[:-1], predecessor_nodes(graph, node_path[1:]))
    if cuts.size and blend_s > 0:
        left, entered = node_path[cuts - 1], pred[cuts]
        rel_e, height_e, _, _ = _relative_pose(graph, entered, pelvis)
        # Differences entered − left, as left-multiplied rotation vectors.
        d_rot = quat_log(quat.mul(graph.node_rotations[entered].astype(np.float64),
                                  quat.conjugate(graph.node_rotations[left].astype(np.float64))))  # fmt: skip
        d_rel = quat_log(quat.mul(rel_e, quat.conjugate(rel[cuts - 1])))
        d_trans = graph.node_translations[entered].astype(np.float64) - trans[cuts - 1]
        d_height = height_e - height[cuts - 1]
        half = np.full(cuts.size, 0.5 * blend_s * rate)
        airborne = ~graph.node_contacts[left].any(axis=1) & ~graph.node_contacts[node_path[cuts]].any(axis=1)
        half_root = np.where(airborne, 0.5 * flight_root_blend_s * rate, half)
        off_rot = _blend_offsets(T, cuts, d_rot[:, below], half)
        rot[:, below] = quat.mul(quat_exp(off_rot), rot[:, below])
        trans[:, below] += _blend_offsets(T, cuts, d_trans[:, below], half)
        rel = quat.mul(quat_exp(_blend_offsets(T, cuts, d_rel, half_root)), rel)
        height = height + _blend_offsets(T, cuts, d_height, half_root)

    # Re-place: pelvis world transform from the integrated path, realised at the
    # "carrier" joint — the pelvis or its nearest ancestor with position channels
    # (joint 0 otherwise) — so every joint above and below keeps its local values.
    target_rot = quat.mul(quat.about_y(heading), rel)
    target_pos = np.stack([ground[:, 0], height, ground[:, 1]], axis=-1)
    chain = _ancestors(parents, pelvis) + [pelvis]
    carrier = next((j for j in chain[::-1] if _has_position(sk.channels[j])), 0)
    c_rot = quat.mul(quat.conjugate(src_rot[:, carrier]), src_rot[:, pelvis])
    c_pos = quat.inv_rotate(src_rot[:, carrier], src_pos[:, pelvis] - src_pos[:, carrier])
    carrier_rot = quat.mul(target_rot, quat.conjugate(c_rot))
    carrier_pos = target_pos - quat.rotate(carrier_rot, c_pos)
    if carrier > 0:
        q = parents[carrier]
        carrier_rot = quat.mul(quat.conjugate(src_rot[:, q]), carrier_rot)
        carrier_pos = quat.inv_rotate(src_rot[:, q], carrier_pos - src_pos[:, q])
    rot[:, carrier] = carrier_rot
    trans[:, carrier] = carrier_pos

    # d. Footskate clean-up.
    if fix_feet:
        world_rot, world_pos = forward_kinematics(rot, trans, parents)
        # Source motion of each frame's node since the frame before (its own clip),
        # rotated into the output by the frame's placement.
        _, pred_pos = forward_kinematics(graph.node_rotations[pred], graph.node_translations[pred], parents)
        turn = quat.about_y(heading - graph.node_heading[node_path].astype(np.float64))
        lateral = world_pos[:, table["l_hip"]] - world_pos[:, table["r_hip"]]
        lateral /= np.maximum(np.linalg.norm(lateral, axis=-1, keepdims=True), 1e-12)
        blend_frames = max(1, round(FOOT_BLEND_S * rate))
        for side, s in enumerate(("l", "r")):
            hip, knee, ankle, toe = (table[f"{s}_{n}"] for n in ("hip", "knee", "ankle", "toe"))
            flags = graph.node_contacts[node_path, side].astype(bool)
            if not flags.any():
                continue
            targets = []
            for j in (ankle, toe):
                intended = quat.rotate(turn, src_pos[:, j] - pred_pos[:, j])
                off, w = foot_corrections(world_pos[:, j], intended, flags, blend_frames)
                targets.append((world_pos[:, j] + off, off, w))
            (ank_t, ank_off, w), (toe_t, toe_off, _) = targets
            moved = np.nonzero((w > 0) & ((np.linalg.norm(ank_off, axis=-1) > 1e-6) | (np.linalg.norm(toe_off, axis=-1) > 1e-6)))[0]
            if moved.size == 0:
                continue
            sub = rot[moved]
            two_bone_ik(sub, world_rot[moved], world_pos[moved], parents, hip, knee, ankle, toe,
                        ank_t[moved], toe_t[moved], lateral[moved])  # fmt: skip
            rot[moved] = sub

    return Motion(sk, quat.normalize(rot), trans, rate, name="synthesized", source="graph path")


def path_world_positions(motion: Motion) -> np.ndarray:
    """(T, J, 3) world joint positions (m) of a synthesized motion."""
    return motion_fk(motion)[1]
