"""Full-body motion from a node path through the motion graph (Kelly et al. 2013, §5).

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

Stages 2–4 are numba kernels looping over frames: a live stream re-synthesizes a
trailing stretch of a few dozen frames several times a second, where numpy's per-call
overhead on (K, 4) arrays cost more than the arithmetic (about 5 ms a call against
well under 1 ms). The graph's path tables (each node's predecessor in its own
sequence, each edge's continuity, the joint map) are made once per graph.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph import metadata as meta
from graphsvc.graph.derived import derived
from graphsvc.graph.model import (
    EDGE_BRIDGE,
    EDGE_INTERP,
    EDGE_TRANSITION,
    NODE_BRIDGE,
    NODE_INTERP,
    NODE_ORIGINAL,
    NODE_SLOW,
    MotionGraph,
)
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import diff3 as _diff3
from graphsvc.motion.kinematics import forward_kinematics, motion_fk
from graphsvc.motion.kinematics import qmul4 as _qmul
from graphsvc.motion.kinematics import qrot3 as _qrot
from graphsvc.motion.placement import joint_tables as _joint_tables
from graphsvc.motion.placement import place_poses as _place
from graphsvc.motion.placement import relative_pose as _relative_pose
from graphsvc.motion.skeleton import Motion
from graphsvc.synthesis.smooth import smooth_poses
from graphsvc.synthesis.track import warm_up_track

FOOT_BLEND_S = 0.1  # blend-out of the foot pinning after a contact span (s)


# ---------------------------------------------------------------- quaternion scalars
#
# (w, x, y, z) as four floats, the same formulas and operation order as `quat`, so the
# kernels give what the vectorised helpers give (products and rotations: `kinematics`).

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_jit_scalar = numba.njit(cache=True, error_model="numpy")


@_jit_scalar
def _qlog(w, x, y, z):
    """Rotation vector (rad) of a unit quaternion, shortest arc."""
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    # angle / s → 2 as s → 0 (first order), so small rotations stay exact.
    scale = 2.0 * math.atan2(s, w) / s if s > 1e-12 else 2.0
    return x * scale, y * scale, z * scale


@_jit_scalar
def _qexp(rx, ry, rz):
    """Unit quaternion of a rotation vector (rad)."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    half = 0.5 * angle
    k = math.sin(half) / angle if angle > 1e-12 else 0.5
    return math.cos(half), rx * k, ry * k, rz * k


@_jit_scalar
def _norm3(x, y, z):
    return math.sqrt(x * x + y * y + z * z)


@_jit_scalar
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@_jit_scalar
def _between(ux, uy, uz, vx, vy, vz):
    """Shortest rotation taking direction u onto direction v."""
    nu, nv = _norm3(ux, uy, uz), _norm3(vx, vy, vz)
    ux, uy, uz, vx, vy, vz = ux / nu, uy / nu, uz / nu, vx / nv, vy / nv, vz / nv
    w = 1.0 + (ux * vx + uy * vy + uz * vz)
    ax, ay, az = _cross(ux, uy, uz, vx, vy, vz)
    if w < 1e-9:  # opposite directions: any axis orthogonal to u
        ax, ay, az = _cross(ux, uy, uz, 1.0, 0.0, 0.0)
        if _norm3(ax, ay, az) < 1e-6:
            ax, ay, az = _cross(ux, uy, uz, 0.0, 1.0, 0.0)
        w = 0.0
    n = math.sqrt(w * w + ax * ax + ay * ay + az * az)
    return w / n, ax / n, ay / n, az / n


@_jit_scalar
def _smoothstep(x):
    """3x² − 2x³ on x clipped to [0, 1]."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


# ---------------------------------------------------------------- path structure


@dataclass(frozen=True)
class PathTables:
    """Per-graph lookups for synthesis, made once (`path_tables`).

    predecessor (N,) int64: the node one step before each node in its own source
    sequence (itself where a sequence starts); continuous (E,) bool: the edge plays on
    inside one sequence; joints: the default joint map; below (J,) bool: joints under
    the pelvis; carrier: the joint that carries the placement (see `_place`)."""

    predecessor: np.ndarray
    continuous: np.ndarray
    joints: dict
    below: np.ndarray
    carrier: int


def _continuous_edges(graph: MotionGraph, edges: np.ndarray) -> np.ndarray:
    """(K,) bool: the edge plays on inside one source sequence (original, slow-down,
    speed-up, a step inside an interpolated segment, or into a bridge's node: a bridge
    is its clip a's sequence blending into b) — no pose jump. A bridge's last edge,
    into clip b, lands in b's own frame, so it counts as a cut (of what is left of
    the blend: its last node is nearly b's frame before the exit)."""
    kind = graph.edge_kind[edges]
    src, dst = graph.edge_src[edges], graph.edge_dst[edges]
    inside_segment = (graph.node_kind[src] == NODE_INTERP) & (graph.node_kind[dst] == NODE_INTERP) & (dst == src + 1)
    into_bridge = graph.node_kind[dst] == NODE_BRIDGE
    return (kind != EDGE_TRANSITION) & ((kind != EDGE_INTERP) | inside_segment) & ((kind != EDGE_BRIDGE) | into_bridge)


def _predecessors(graph: MotionGraph, nodes: np.ndarray) -> np.ndarray:
    kind = graph.node_kind[nodes]
    frame = graph.node_frame[nodes]
    first = np.array([c["first_node"] for c in graph.clips], dtype=np.int64)[graph.node_clip[nodes]]
    out = nodes.copy()
    orig = (kind == NODE_ORIGINAL) & (frame >= 1.0)
    out[orig] = nodes[orig] - 1
    slow = kind == NODE_SLOW  # between original frames f and f+1: f precedes it
    out[slow] = first[slow] + np.floor(frame[slow]).astype(np.int64)
    seg_first = graph.segments.column("first_node").astype(np.int64)
    interp = (kind == NODE_INTERP) & ~np.isin(nodes, seg_first)
    out[interp] = nodes[interp] - 1
    # A bridge's nodes follow one another; its first follows the frame of a it is entered from.
    bridge = kind == NODE_BRIDGE
    out[bridge] = nodes[bridge] - 1
    if len(graph.bridges):
        first = graph.bridges.column("first_node").astype(np.int64)
        clip_first = np.array([c["first_node"] for c in graph.clips], dtype=np.int64)
        entry = clip_first[graph.bridges.column("clip_a")] + graph.bridges.column("a_entry")
        at = np.searchsorted(first, nodes[bridge])
        hit = (at < first.size) & (first[np.minimum(at, first.size - 1)] == nodes[bridge])
        out[np.flatnonzero(bridge)[hit]] = entry[at[hit]]
    return out


def path_tables(graph: MotionGraph) -> PathTables:
    """The graph's synthesis lookups, made once per graph object (`graph.derived`)."""
    return derived(graph, "synthesis.path_tables", lambda: _make_path_tables(graph))


def _make_path_tables(graph: MotionGraph) -> PathTables:
    joints = joint_map(graph.skeleton, graph.params.get("mapping"))
    below, carrier = _joint_tables(graph.skeleton, joints)
    tables = PathTables(
        predecessor=_predecessors(graph, np.arange(graph.num_nodes, dtype=np.int64)),
        continuous=_continuous_edges(graph, np.arange(graph.num_edges, dtype=np.int64)),
        joints=joints,
        below=below,
        carrier=carrier,
    )
    return tables


def predecessor_nodes(graph: MotionGraph, nodes: np.ndarray) -> np.ndarray:
    """(K,) the node one step before each node in its own source sequence (the clip
    or interpolated segment it belongs to); the node itself when it starts one.
    Used to continue the entered clip backwards across a transition."""
    return path_tables(graph).predecessor[np.asarray(nodes, dtype=np.int64)]


def check_path(graph: MotionGraph, node_path: np.ndarray, edge_path: np.ndarray, allow_jumps: bool = False) -> None:
    """Raise InputError unless edge_path[k] enters node_path[k+1] — and, unless
    allow_jumps, leaves node_path[k] (a streaming decoder's revisions jump)."""
    T = node_path.shape[0]
    if T == 0:
        raise InputError("empty node path")
    if edge_path.shape != (T - 1,):
        raise InputError(f"edge path must have {T - 1} entries, got {edge_path.shape}")
    if np.any((node_path < 0) | (node_path >= graph.num_nodes)) or np.any(
        (edge_path < 0) | (edge_path >= graph.num_edges)
    ):
        raise InputError("node or edge index out of range")
    if np.any(graph.edge_dst[edge_path] != node_path[1:]):
        raise InputError("edge path does not enter the node path")
    if not allow_jumps and np.any(graph.edge_src[edge_path] != node_path[:-1]):
        raise InputError("edge path does not connect the node path")


def contact_spans(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) runs of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], flags.astype(np.int8), [0]]))
    return list(zip(np.nonzero(edges == 1)[0].tolist(), np.nonzero(edges == -1)[0].tolist()))


# ---------------------------------------------------------------- kernels


@_jit
def _blend(
    rot, trans, rel, height, below, cuts, entered_rot, entered_trans, entered_rel, entered_height, half, half_root
):
    """Offset blending at the cuts, in place on rot (T, J, 4), trans (T, J, 3), rel
    (T, 4) and height (T,). Cut c is a jump between frames cuts[c] − 1 and cuts[c];
    entered_* are the entered clip's own frame before it (rotations, translations,
    relative pelvis rotation, pelvis height). The difference D = entered − left is
    spread over a window of half-width half[c] frames (half_root[c] for the pelvis):
    +α·D before the cut, −(1−α)·D after, α a smoothstep across the window; rotations
    as left-multiplied rotation vectors, several windows adding up."""
    T, J, C = rot.shape[0], rot.shape[1], cuts.shape[0]
    # The differences entered − left, before any frame changes.
    d_rot, d_trans = np.zeros((C, J, 3)), np.zeros((C, J, 3))
    d_rel, d_height = np.empty((C, 3)), np.empty(C)
    for c in range(C):
        left = cuts[c] - 1
        for j in range(J):
            if below[j]:
                a, b = entered_rot[c, j], rot[left, j]
                d_rot[c, j] = _qlog(*_qmul(a[0], a[1], a[2], a[3], b[0], -b[1], -b[2], -b[3]))
                for i in range(3):
                    d_trans[c, j, i] = entered_trans[c, j, i] - trans[left, j, i]
        a, b = entered_rel[c], rel[left]
        d_rel[c] = _qlog(*_qmul(a[0], a[1], a[2], a[3], b[0], -b[1], -b[2], -b[3]))
        d_height[c] = entered_height[c] - height[left]
    off_rot, off_trans = np.zeros((T, J, 3)), np.zeros((T, J, 3))
    off_rel, off_height = np.zeros((T, 3)), np.zeros(T)
    for c in range(C):
        cut = cuts[c]
        centre = cut - 0.5
        h = half[c]
        for t in range(max(0, int(math.floor(centre - h))), min(T, int(math.ceil(centre + h)) + 1)):
            alpha = _smoothstep((t - centre + h) / (2.0 * h))
            w = alpha if t < cut else alpha - 1.0
            for j in range(J):
                for i in range(3):
                    off_rot[t, j, i] += w * d_rot[c, j, i]
                    off_trans[t, j, i] += w * d_trans[c, j, i]
        h = half_root[c]
        for t in range(max(0, int(math.floor(centre - h))), min(T, int(math.ceil(centre + h)) + 1)):
            alpha = _smoothstep((t - centre + h) / (2.0 * h))
            w = alpha if t < cut else alpha - 1.0
            for i in range(3):
                off_rel[t, i] += w * d_rel[c, i]
            off_height[t] += w * d_height[c]
    for t in range(T):
        for j in range(J):
            if below[j]:
                q = rot[t, j]
                rot[t, j] = _qmul(*_qexp(off_rot[t, j, 0], off_rot[t, j, 1], off_rot[t, j, 2]), q[0], q[1], q[2], q[3])
                for i in range(3):
                    trans[t, j, i] += off_trans[t, j, i]
        q = rel[t]
        rel[t] = _qmul(*_qexp(off_rel[t, 0], off_rel[t, 1], off_rel[t, 2]), q[0], q[1], q[2], q[3])
        height[t] += off_height[t]


def blend_cuts(
    rot,
    trans,
    rel,
    height,
    below,
    cuts,
    entered_rot,
    entered_trans,
    entered_rel,
    entered_height,
    half_s: float,
    rate_hz: float,
) -> None:
    """The offset blending of step 3 (module docstring) on frames that are not a graph
    path's, in place: rot (T, J, 4), trans (T, J, 3) local, rel (T, 4), height (T,);
    cuts (C,) the frames right after each jump; entered_* the entered sequence's own
    frame before each cut (C, ...); a window of half-width half_s seconds."""
    cuts = np.ascontiguousarray(cuts, dtype=np.int64)
    if cuts.size == 0 or half_s <= 0:
        return
    half = np.full(cuts.size, half_s * rate_hz)
    _blend(
        rot,
        trans,
        rel,
        height,
        np.ascontiguousarray(below, dtype=np.bool_),
        cuts,
        np.ascontiguousarray(entered_rot, dtype=np.float64),
        np.ascontiguousarray(entered_trans, dtype=np.float64),
        np.ascontiguousarray(entered_rel, dtype=np.float64),
        np.ascontiguousarray(entered_height, dtype=np.float64),
        half,
        half,
    )


@_jit
def _foot_targets(world_pos, intended, flags, blend_frames, target, weight):
    """Skate-free targets (T, 3) (m) of one joint and their weights (T,), in place.

    world_pos (T, 3): the joint's synthesized trajectory; intended (T, 3): the
    displacement it should have from frame t−1 to t (its source clip's own motion,
    placed; row 0 unused); flags (T,): contact. Inside a span the offset is the
    accumulated difference, so the joint moves exactly as intended from the span's
    first frame; after the span it decays to zero over `blend_frames`, never into the
    next span. Returns the offsets (T, 3)."""
    T = world_pos.shape[0]
    offset = np.zeros((T, 3))
    weight[:] = 0.0
    t = 0
    while t < T:
        if not flags[t]:
            t += 1
            continue
        s = t
        acc = np.zeros(3)
        offset[s] = -acc
        weight[s] = 1.0
        t += 1
        while t < T and flags[t]:
            for i in range(3):
                acc[i] += world_pos[t, i] - world_pos[t - 1, i] - intended[t, i]
                offset[t, i] = -acc[i]
            weight[t] = 1.0
            t += 1
        last = t - 1
        for k in range(1, blend_frames + 1):
            f = last + k
            if f >= T:
                break
            if flags[f]:
                continue
            w = 1.0 - _smoothstep(k / (blend_frames + 1.0))
            for i in range(3):
                offset[f, i] = offset[last, i] * w
            weight[f] = w
    for f in range(T):
        for i in range(3):
            target[f, i] = world_pos[f, i] + offset[f, i]
    return offset


@_jit
def _two_bone_ik(rot, world_rot, world_pos, parents, hip, knee, ankle, toe, ankle_target, toe_target, lateral, t):
    """Analytic two-bone IK of one leg at frame t, in place on local rotations rot
    (T, J, 4), given FK world rotations/positions (T, J, 4/3) of the current pose.

    The knee flexes in the leg's current bend plane (normal hip→knee × knee→ankle;
    `lateral` (3,), the pelvis's right→left axis, for a straight leg) to reach the
    target hip–ankle distance, then the hip swings the leg by the shortest rotation
    onto the target. The foot keeps its world orientation except for the shortest
    swing that points it at the toe target. Targets (3,) in metres."""
    a, b, c = world_pos[t, hip], world_pos[t, knee], world_pos[t, ankle]
    thigh, shin, reach = _diff3(b, a), _diff3(c, b), _diff3(ankle_target, a)
    l1, l2 = _norm3(*thigh), _norm3(*shin)
    d = min(max(_norm3(*reach), abs(l1 - l2) + 1e-4), l1 + l2 - 1e-4)
    up = _diff3(a, b)
    cos_now = (up[0] * shin[0] + up[1] * shin[1] + up[2] * shin[2]) / (l1 * l2)
    cos_new = (l1 * l1 + l2 * l2 - d * d) / (2.0 * l1 * l2)
    # Rotating knee→ankle about (knee→ankle) × (knee→hip) = (hip→knee) × (knee→ankle)
    # by +φ closes the knee angle by φ.
    nx, ny, nz = _cross(*thigh, *shin)
    nn = _norm3(nx, ny, nz)
    if nn > 1e-4 * (l1 * l2):
        m = max(nn, 1e-12)
        nx, ny, nz = nx / m, ny / m, nz / m
    else:
        nx, ny, nz = lateral[0], lateral[1], lateral[2]
    bend = math.acos(min(max(cos_now, -1.0), 1.0)) - math.acos(min(max(cos_new, -1.0), 1.0))
    m = _norm3(nx, ny, nz)
    half = 0.5 * bend
    s = math.sin(half)
    kw, kx, ky, kz = math.cos(half), s * (nx / m), s * (ny / m), s * (nz / m)
    cx, cy, cz = _qrot(kw, kx, ky, kz, *shin)
    sw, sx, sy, sz = _between(*_diff3((b[0] + cx, b[1] + cy, b[2] + cz), a), *reach)
    h, k, an = world_rot[t, hip], world_rot[t, knee], world_rot[t, ankle]
    hw = _qmul(sw, sx, sy, sz, h[0], h[1], h[2], h[3])
    kd = _qmul(kw, kx, ky, kz, k[0], k[1], k[2], k[3])
    knw = _qmul(sw, sx, sy, sz, kd[0], kd[1], kd[2], kd[3])
    # Foot: keep its world orientation, then swing ankle→toe onto the toe target.
    e, f = world_pos[t, ankle], world_pos[t, toe]
    fs = _between(*_diff3(f, e), *_diff3(toe_target, ankle_target))
    fw = _qmul(fs[0], fs[1], fs[2], fs[3], an[0], an[1], an[2], an[3])
    p = world_rot[t, parents[hip]]
    rot[t, hip] = _qmul(p[0], -p[1], -p[2], -p[3], hw[0], hw[1], hw[2], hw[3])
    rot[t, knee] = _qmul(hw[0], -hw[1], -hw[2], -hw[3], knw[0], knw[1], knw[2], knw[3])
    rot[t, ankle] = _qmul(knw[0], -knw[1], -knw[2], -knw[3], fw[0], fw[1], fw[2], fw[3])


@_jit
def _intended(src_pos, pred_pos, turn_angle, joint, out):
    """The displacement (T, 3) (m) joint should make into each frame: its source
    clip's own, from the predecessor node's pose (T, J, 3) to the node's, turned about
    +Y by turn_angle (T,) (rad), the frame's placement against its source's. In place."""
    for t in range(src_pos.shape[0]):
        half = 0.5 * turn_angle[t]
        out[t] = _qrot(math.cos(half), 0.0, math.sin(half), 0.0, *_diff3(src_pos[t, joint], pred_pos[t, joint]))


@_jit
def _fix_feet(rot, world_rot, world_pos, src_pos, pred_pos, turn_angle, contacts, parents, legs, hips, blend_frames):
    """Footskate clean-up, in place on local rotations rot (T, J, 4): while a foot's
    contact flag (contacts (T, 2), left/right) is on, its ankle and toe move only as
    they moved in their source clip (src_pos − pred_pos (T, J, 3), turned into the
    output by turn_angle (T,) rad); IK on hip–knee–ankle removes the difference.
    legs (2, 4): hip, knee, ankle, toe of each side; hips: (left, right) hip joints."""
    T = rot.shape[0]
    lateral = np.empty((T, 3))
    for t in range(T):
        lx = world_pos[t, hips[0], 0] - world_pos[t, hips[1], 0]
        ly = world_pos[t, hips[0], 1] - world_pos[t, hips[1], 1]
        lz = world_pos[t, hips[0], 2] - world_pos[t, hips[1], 2]
        m = max(_norm3(lx, ly, lz), 1e-12)
        lateral[t] = (lx / m, ly / m, lz / m)
    intended = np.empty((T, 3))
    ankle_target, toe_target = np.empty((T, 3)), np.empty((T, 3))
    weight, toe_weight = np.empty(T), np.empty(T)
    for side in range(2):
        hip, knee, ankle, toe = legs[side, 0], legs[side, 1], legs[side, 2], legs[side, 3]
        flags = contacts[:, side]
        if not flags.any():
            continue
        _intended(src_pos, pred_pos, turn_angle, ankle, intended)
        ankle_offset = _foot_targets(world_pos[:, ankle], intended, flags, blend_frames, ankle_target, weight)
        _intended(src_pos, pred_pos, turn_angle, toe, intended)
        toe_offset = _foot_targets(world_pos[:, toe], intended, flags, blend_frames, toe_target, toe_weight)
        for t in range(T):
            moved = (
                _norm3(ankle_offset[t, 0], ankle_offset[t, 1], ankle_offset[t, 2]) > 1e-6
                or _norm3(toe_offset[t, 0], toe_offset[t, 1], toe_offset[t, 2]) > 1e-6
            )
            if weight[t] > 0.0 and moved:
                _two_bone_ik(
                    rot,
                    world_rot,
                    world_pos,
                    parents,
                    hip,
                    knee,
                    ankle,
                    toe,
                    ankle_target[t],
                    toe_target[t],
                    lateral[t],
                    t,
                )


@_jit
def _normalize(rot):
    for t in range(rot.shape[0]):
        for j in range(rot.shape[1]):
            q = rot[t, j]
            n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            rot[t, j] = (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


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
    track: np.ndarray | None = None,
) -> Motion:
    """The motion (T frames at graph.rate_hz on graph.skeleton) of a node path (T,)
    and the edges (T−1,) between its nodes, started at `start_ground` (2,) (x, z in
    m) and `start_heading` (rad). blend_s / flight_root_blend_s: blend windows (s)
    at pose discontinuities, for the pelvis the second while both feet are off the
    ground on both sides. fix_feet: footskate clean-up during contact flags.
    allow_jumps: edges may leave another node than the previous one (a streaming
    decoder's revision); such a step is blended as a cut, its edge still moves the root.
    track (T, 2) m: the ground track to follow instead of the path's own
    (`synthesis.track.fused_track`: fused with a tracker's positions). The motion is
    synthesized on the path's own track, clean-up included, and then moved frame by
    frame onto `track`, the whole body at once (docs/reconstruction.md, *Following the
    tracker*: holding the planted feet with the legs instead cost 0.8 cm of joint error
    on eight clips of a held-out actor)."""
    node_path = np.asarray(node_path, dtype=np.int64).reshape(-1)
    edge_path = np.asarray(edge_path, dtype=np.int64).reshape(-1)
    check_path(graph, node_path, edge_path, allow_jumps)
    sk = graph.skeleton
    parents = np.ascontiguousarray(sk.parents, dtype=np.int64)
    tables = path_tables(graph)
    if mapping is None:
        joints, below, carrier = tables.joints, tables.below, tables.carrier
    else:
        joints = joint_map(sk, mapping)
        below, carrier = _joint_tables(sk, joints)
    pelvis = joints["pelvis"]
    rate = float(graph.rate_hz)

    # a. Root path.
    ground, heading = meta.integrate_path(
        np.asarray(start_ground, dtype=np.float64),
        float(start_heading),
        graph.edge_offset[edge_path].astype(np.float64),
        graph.edge_heading[edge_path].astype(np.float64),
    )

    # b. Poses relative to their source placement.
    rot = node_rotations(graph, node_path)
    trans = node_translations(graph, node_path)
    src_rot, src_pos = forward_kinematics(rot, trans, parents)
    node_heading = graph.node_heading[node_path].astype(np.float64)
    rel, height = _relative_pose(src_rot, src_pos, node_heading, pelvis)

    # c. Offset blending at discontinuities.
    cont = tables.continuous[edge_path] & (graph.edge_src[edge_path] == node_path[:-1])
    cuts = np.nonzero(~cont)[0] + 1  # frame index right after each jump
    # The node one step before each frame's node in its own clip: the previous frame's
    # node where the path plays on, at a cut the entered clip's own frame before it.
    entered = tables.predecessor[node_path[cuts]]
    entered_rot = node_rotations(graph, entered)
    entered_trans = node_translations(graph, entered)
    e_rot, e_pos = forward_kinematics(entered_rot, entered_trans, parents)
    if cuts.size and blend_s > 0:
        left = node_path[cuts - 1]
        rel_e, height_e = _relative_pose(e_rot, e_pos, graph.node_heading[entered].astype(np.float64), pelvis)
        half = np.full(cuts.size, 0.5 * blend_s * rate)
        airborne = ~graph.node_contacts[left].any(axis=1) & ~graph.node_contacts[node_path[cuts]].any(axis=1)
        half_root = np.where(airborne, 0.5 * flight_root_blend_s * rate, half)
        _blend(rot, trans, rel, height, below, cuts, entered_rot, entered_trans, rel_e, height_e, half, half_root)

    # Re-place at the integrated root path.
    _place(rot, trans, rel, height, ground, heading, src_rot, src_pos, parents, pelvis, carrier)

    # d. Footskate clean-up (it places the toes: not on a skeleton without them).
    if fix_feet and not {"l_toe", "r_toe"} & getattr(joints, "missing", frozenset()):
        contacts = np.ascontiguousarray(graph.node_contacts[node_path], dtype=np.bool_)
        if contacts.any():
            world_rot, world_pos = forward_kinematics(rot, trans, parents)
            # Source motion of each frame's node since the frame before (its own clip),
            # turned into the output by the frame's placement: the predecessors' poses
            # are the previous frames' source poses, and the entered frames' at cuts.
            pred_pos = np.empty_like(src_pos)
            pred_pos[0], pred_pos[1:] = src_pos[0], src_pos[:-1]
            pred_pos[cuts] = e_pos
            legs = np.array(
                [[joints[f"{s}_{n}"] for n in ("hip", "knee", "ankle", "toe")] for s in ("l", "r")], dtype=np.int64
            )
            _fix_feet(
                rot,
                world_rot,
                world_pos,
                src_pos,
                pred_pos,
                heading - node_heading,
                contacts,
                parents,
                legs,
                legs[:, 0].copy(),
                max(1, round(FOOT_BLEND_S * rate)),
            )

    _normalize(rot)
    if track is not None:
        track = np.asarray(track, dtype=np.float64)
        if track.shape != ground.shape:
            raise InputError(
                f"track must be ({ground.shape[0]}, 2) for a {ground.shape[0]}-frame path, got {track.shape}"
            )
        for root in np.flatnonzero(parents < 0):  # (root translations are in world space)
            trans[:, root, 0] += track[:, 0] - ground[:, 0]
            trans[:, root, 2] += track[:, 1] - ground[:, 1]
    return Motion(sk, rot, trans, rate, name="synthesized", source="graph path")


def path_world_positions(motion: Motion) -> np.ndarray:
    """(T, J, 3) world joint positions (m) of a synthesized motion."""
    return motion_fk(motion)[1]


def warm_up_synthesis(graph: MotionGraph) -> None:
    """Synthesize a two-frame path with a cut into a node in contact, so numba
    compiles (or loads from its cache) every synthesis kernel and the graph's path
    tables are made now, not on a client's first frames. Once per graph."""
    warmed = derived(graph, "synthesis.warmed", lambda: [False])
    if warmed[0]:
        return
    warmed[0] = True
    path_tables(graph)
    warm_up_track()
    smooth_poses(np.tile([1.0, 0.0, 0.0, 0.0], (3, 2, 1)), np.zeros((3, 2, 3)), 1.0)
    entered = np.zeros(graph.num_nodes, dtype=bool)
    entered[graph.edge_dst] = True
    in_contact = np.flatnonzero(graph.node_contacts.any(axis=1) & entered)  # (a clip's first frame has no way in)
    if not in_contact.size:
        return
    node = int(in_contact[0])
    edge = int(np.flatnonzero(graph.edge_dst == node)[0])
    before = (int(graph.edge_src[edge]) + 1) % graph.num_nodes  # not the edge's source: a cut
    synthesize_motion(graph, np.array([before, node]), np.array([edge]), np.zeros(2), 0.0, allow_jumps=True)
    # A second of each of two clips joined by a cut: the blends and the foot clean-up,
    # which run only where a path has contact spans and a cut with frames around it.
    runs = [c["first_node"] + 1 + np.arange(min(30, c["frames"] - 1)) for c in (graph.clips[0], graph.clips[-1])]
    nodes = np.concatenate(runs).astype(np.int64)
    edges = np.empty(len(nodes) - 1, dtype=np.int64)
    for k in range(1, len(nodes)):
        into = np.flatnonzero(graph.edge_dst == nodes[k])
        if not into.size:
            return
        same = into[graph.edge_src[into] == nodes[k - 1]]
        edges[k - 1] = same[0] if same.size else into[0]  # (at the cut: any edge into the node)
    synthesize_motion(graph, nodes, edges, np.zeros(2), 0.0, allow_jumps=True)
