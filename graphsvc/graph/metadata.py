"""Edge metadata (Kelly et al. 2013, §4.3): sensor readings and root offsets of playing an edge.

A node can be reached at three playback speeds: normal (an original edge or a
transition), half (through a slow-down node) and double (a speed-up edge). For each
clip we simulate the layout's sensors on the clip itself, on the clip resampled to
twice the rate but played at the graph rate (half speed), and on every other frame
(double speed); an edge's reading is the reading of its destination at the edge's
speed. Original edges therefore reproduce the clip's simulated stream exactly, and
a transition — only allowed between frames whose windowed poses match — reads what
its destination reads in its own clip.

A bridge (`bridges.py`) reads what its blend plays: `bridge_readings` simulates the
blend with the frames of its two clips around it.

The same functions run at build time on the clips' float64 poses and later on the
graph's stored float32 poses, for another layout (`recompute_accelerations`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from graphsvc.graph.model import EDGE_BRIDGE, EDGE_SLOW, EDGE_SPEEDUP, NODE_BRIDGE, NODE_SLOW
from graphsvc.graph.poses import node_poses, node_rotations, node_translations
from graphsvc.graph.rows import ranges
from graphsvc.motion import quat, signals
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.resample import resample_arrays
from graphsvc.motion.skeleton import Skeleton
from graphsvc.sensors.accelerometer import sensor_poses, simulate_accelerations
from graphsvc.sensors.anatomy import ANATOMICAL, REST_POSE
from graphsvc.sensors.layout import Placement, anatomical_placement, layout_from_dict, place, root_sensor
from graphsvc.sensors.orientation import RELATIVE_WIDTH, TILT_WIDTH, orientation_cue

BEFORE, AFTER = 2, 3  # context frames of a bridge's readings: the 5-point stencil's reach, and b's frame q


@dataclass(frozen=True)
class SpeedReadings:
    """Readings (m/s², float32) of one clip of F frames: normal (F, S, 3); half
    (2F−1, S, 3) along the half-speed timeline (even rows are original frames, odd
    rows the slow-down poses); double (F, S, 3): frame g in the double-speed
    playback through frames of g's parity."""

    normal: np.ndarray
    half: np.ndarray
    double: np.ndarray


def half_speed_poses(rotations: np.ndarray, translations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(2F−1, J, 4), (2F−1, J, 3): the clip with a slerped pose between every pair of
    frames (rows 2f are frame f, rows 2f+1 the slow-down pose between f and f+1)."""
    if rotations.shape[0] < 2:
        return rotations.copy(), translations.copy()
    return resample_arrays(rotations, translations, 1.0, 2.0)


def speed_readings(
    world_rot: np.ndarray,
    world_pos: np.ndarray,
    half_world_rot: np.ndarray,
    half_world_pos: np.ndarray,
    placement: Placement,
    rate_hz: float,
) -> SpeedReadings:
    """Sensor readings of one clip at the three playback speeds, from the world
    poses of the clip (F, J, 4/3) and of its half-speed timeline (2F−1, J, 4/3).
    FK is per frame, so double speed needs no FK of its own: it plays every other
    row of the clip's world poses."""
    normal = simulate_accelerations(world_rot, world_pos, placement, rate_hz)
    half = simulate_accelerations(half_world_rot, half_world_pos, placement, rate_hz)
    double = np.empty_like(normal)
    for parity in (0, 1):
        if parity < world_rot.shape[0]:
            double[parity::2] = simulate_accelerations(world_rot[parity::2], world_pos[parity::2], placement, rate_hz)
    return SpeedReadings(normal, half, double)


def ground_and_heading(world_pos: np.ndarray, joints: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """(F, 2) root ground positions (m) and (F,) headings (rad) from world positions."""
    return signals.ground_position(world_pos, joints["pelvis"]), signals.heading(world_pos, joints)


def local_offsets(
    ground_src: np.ndarray, heading_src: np.ndarray, ground_dst: np.ndarray, heading_dst: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Ground displacement src → dst in src's local frame (K, 2) (m; facing +Z, left
    +X) and the wrapped heading change (K,) (rad)."""
    delta = ground_dst - ground_src
    c, s = np.cos(heading_src), np.sin(heading_src)
    # R_y(−h)·(x, z) = (c·x − s·z, s·x + c·z) turns the facing direction onto +Z.
    local = np.stack([c * delta[:, 0] - s * delta[:, 1], s * delta[:, 0] + c * delta[:, 1]], axis=-1)
    return local, quat.wrap_angle(heading_dst - heading_src)


def apply_offsets(ground: np.ndarray, heading: float, offset: np.ndarray, dheading: float) -> tuple[np.ndarray, float]:
    """Inverse of `local_offsets` for one step: the destination's ground position
    and heading given the source's and an edge's offsets."""
    g, h = integrate_path(ground, heading, np.asarray(offset, np.float64)[None], np.array([dheading], np.float64))
    return g[1], float(h[1])


def integrate_path(
    ground0: np.ndarray,
    heading0: float,
    offsets: np.ndarray,
    dheadings: np.ndarray,
    targets: np.ndarray | None = None,
    alpha: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Root ground path (K+1, 2) and headings (K+1,) from a start and K edge offsets,
    `apply_offsets` step by step (compiled: a live stream integrates a few edges many
    times a second). targets (K, 2) m, NaN where none: after step k the position is
    pulled toward targets[k] by the share alpha, as the Viterbi search pulls each
    path's placement toward the tracker (`strategies.viterbi.costs.track_pull`)."""
    K = offsets.shape[0]
    ground = np.empty((K + 1, 2))
    heading = np.empty(K + 1)
    ground[0], heading[0] = ground0, heading0
    if targets is None or alpha == 0.0:
        targets, alpha = np.full((0, 2), np.nan), 0.0
    _integrate(
        np.ascontiguousarray(offsets, dtype=np.float64),
        np.ascontiguousarray(dheadings, dtype=np.float64),
        np.ascontiguousarray(targets, dtype=np.float64),
        float(alpha),
        ground,
        heading,
    )
    return ground, heading


@numba.njit(cache=True, nogil=True)
def _integrate(offsets, dheadings, targets, alpha, ground, heading):
    for k in range(offsets.shape[0]):
        c, s = np.cos(heading[k]), np.sin(heading[k])
        ground[k + 1, 0] = ground[k, 0] + (c * offsets[k, 0] + s * offsets[k, 1])
        ground[k + 1, 1] = ground[k, 1] + (-s * offsets[k, 0] + c * offsets[k, 1])
        heading[k + 1] = (heading[k] + dheadings[k] + np.pi) % (2.0 * np.pi) - np.pi
        if alpha != 0.0 and np.isfinite(targets[k, 0]) and np.isfinite(targets[k, 1]):
            ground[k + 1, 0] = (1.0 - alpha) * ground[k + 1, 0] + alpha * targets[k, 0]
            ground[k + 1, 1] = (1.0 - alpha) * ground[k + 1, 1] + alpha * targets[k, 1]


def rotate_ground(points: np.ndarray, theta: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """R_y(θ)·(x, z) + t for (K, 2) points, (K,) angles, (K, 2) translations."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * points[:, 0] + s * points[:, 1], -s * points[:, 0] + c * points[:, 1]], axis=-1) + translation


def bridge_readings(
    ctx_world,
    ctx_ground,
    ctx_heading,
    node_rot,
    node_pos,
    node_ground,
    node_heading,
    first,
    count,
    entry,
    exit_frame,
    a_lo,
    a_hi,
    b_lo,
    b_hi,
    placements,
    rate_hz,
) -> np.ndarray:
    """(M + B, S, 3) float32 readings of B bridges, in the order of `BridgeNodes`.

    ctx_world(frames) → (rotations (K, J, 4), positions (K, J, 3)): the world poses of
    clip frames (indexed by frame on one axis: only the few around each bridge are
    asked for); ctx_ground, ctx_heading: every clip frame's ground position and
    heading; node_*: the world poses, ground positions and headings of the bridges' M nodes
    (bridge b's are rows first[b] … first[b] + count[b] − 1). entry, exit_frame (B,):
    the clip frames each bridge is entered from and leaves to; a_lo, a_hi, b_lo, b_hi
    (B,): the frame ranges [lo, hi) of its two clips, for clamping the context;
    placements: the layout placed on each bridge's clip a. A bridge plays BEFORE frames
    of a, its nodes, then AFTER frames of b moved rigidly so that b's frame before the
    exit lands on the bridge's last node. Bridges with equal placements are simulated
    in one call, their sequences end to end: the context frames keep each row's
    stencil inside its own sequence."""
    B = first.shape[0]
    S = len(placements[0].segment) if B else 0
    out = np.zeros((int(count.sum()) + B, S, 3), dtype=np.float32)
    if not B:
        return out
    before = np.clip(entry[:, None] + np.arange(1 - BEFORE, 1)[None, :], a_lo[:, None], a_hi[:, None] - 1)
    after = np.clip(exit_frame[:, None] + np.arange(AFTER)[None, :], b_lo[:, None], b_hi[:, None] - 1)
    last = first + count - 1
    anchor = np.maximum(exit_frame - 1, b_lo)
    turn = node_heading[last] - ctx_heading[anchor]
    c, s = np.cos(turn)[:, None, None], np.sin(turn)[:, None, None]
    after_rot, after_pos = (v.reshape((B, AFTER) + v.shape[1:]) for v in ctx_world(after.ravel()))
    rel = after_pos - np.stack([ctx_ground[anchor, 0], np.zeros(B), ctx_ground[anchor, 1]], axis=-1)[:, None, None]
    moved = np.empty_like(rel)  # (B, AFTER, J, 3)
    moved[..., 0] = c * rel[..., 0] + s * rel[..., 2] + node_ground[last, 0][:, None, None]
    moved[..., 1] = rel[..., 1]
    moved[..., 2] = -s * rel[..., 0] + c * rel[..., 2] + node_ground[last, 1][:, None, None]
    moved_rot = quat.mul(quat.about_y(turn)[:, None, None], after_rot)
    # One pool of poses: the frames of a before each bridge, the bridges' nodes, then the
    # moved frames of b after each.
    M = node_rot.shape[0]
    before_rot, before_pos = ctx_world(before.ravel())
    pool_rot = np.concatenate([before_rot, node_rot, moved_rot.reshape((-1,) + before_rot.shape[1:])])
    pool_pos = np.concatenate([before_pos, node_pos, moved.reshape((-1,) + before_pos.shape[1:])])
    N = B * BEFORE
    length = BEFORE + count + AFTER
    groups: dict = {}
    for bi in range(B):
        groups.setdefault(id(placements[bi]), []).append(bi)
    for members in groups.values():
        members = np.asarray(members)
        n = length[members]
        starts = np.zeros(members.size, dtype=np.int64)
        np.cumsum(n[:-1], out=starts[1:])
        owner = np.repeat(np.arange(members.size), n)
        k = np.arange(int(n.sum())) - starts[owner]  # position within its bridge's sequence
        bm = members[owner]
        seq = np.where(k < BEFORE, bm * BEFORE + np.minimum(k, BEFORE - 1), 0)
        in_nodes = (k >= BEFORE) & (k < BEFORE + count[bm])
        seq = np.where(in_nodes, N + first[bm] + (k - BEFORE), seq)
        in_after = k >= BEFORE + count[bm]
        seq = np.where(in_after, N + M + bm * AFTER + np.clip(k - BEFORE - count[bm], 0, AFTER - 1), seq)
        readings = simulate_accelerations(pool_rot[seq], pool_pos[seq], placements[members[0]], rate_hz)
        # Rows BEFORE … BEFORE + count of each sequence: the nodes, then b's first frame.
        keep = (k >= BEFORE) & (k <= BEFORE + count[bm])
        out[(first[bm] + bm + k - BEFORE)[keep]] = readings[keep]
    return out


def recompute_accelerations(graph, layout) -> np.ndarray:
    """(E, S, 3) float32 edge readings of `layout` for an existing graph, from the
    poses it stores (no knowledge base needed). Equal to the built metadata up to
    the float32 rounding of the stored poses (≈ 1e-3 m/s²)."""
    sk = graph.skeleton
    N = graph.num_nodes
    S = len(layout.sensors)
    normal = np.zeros((N, S, 3), np.float32)  # reading on arrival at normal speed
    half = np.zeros((N, S, 3), np.float32)  # ... through the half-speed timeline
    double = np.zeros((N, S, 3), np.float32)  # ... through a speed-up edge
    clip_of, frame_of = graph.node_clip, graph.node_frame
    kind = graph.node_kind
    slow_nodes = np.nonzero(kind == NODE_SLOW)[0]
    placements = []
    for c, info in enumerate(graph.clips):
        nodes = info["first_node"] + np.arange(info["frames"])
        rot = node_rotations(graph, nodes)
        trans = node_translations(graph, nodes)
        half_rot, half_trans = half_speed_poses(rot, trans)
        world_rot, world_pos = forward_kinematics(rot, trans, sk.parents)
        placement = clip_placement(graph, layout, c, ANATOMICAL, (world_rot, world_pos))
        placements.append(placement)
        r = speed_readings(
            world_rot, world_pos, *forward_kinematics(half_rot, half_trans, sk.parents), placement, graph.rate_hz
        )
        normal[nodes], double[nodes], half[nodes] = r.normal, r.double, r.half[0::2]
        slow = slow_nodes[clip_of[slow_nodes] == c]
        half[slow] = r.half[(2 * frame_of[slow]).astype(np.int64)]
    for seg in graph.segments:
        nodes = seg["first_node"] + np.arange(seg["count"])
        world_rot, world_pos = forward_kinematics(
            node_rotations(graph, nodes),
            node_translations(graph, nodes),
            sk.parents,
        )
        normal[nodes] = simulate_accelerations(world_rot, world_pos, placements[seg["clip_a"]], graph.rate_hz)
    dst, ekind = graph.edge_dst, graph.edge_kind
    out = normal[dst]
    slow_edges = ekind == EDGE_SLOW
    out[slow_edges] = half[dst[slow_edges]]
    fast = ekind == EDGE_SPEEDUP
    out[fast] = double[dst[fast]]
    if len(graph.bridges):
        _bridge_accelerations(graph, placements, out)
    return out


def _bridge_accelerations(graph, placements, out) -> None:
    """Bridge edges' readings, in place on out (E, S, 3), from the stored poses of the
    bridges and of the clip frames around them (`bridge_readings`); placements: the
    layout on each clip."""
    sk = graph.skeleton
    N0 = sum(int(c["frames"]) for c in graph.clips)  # the original nodes, clip after clip
    recs = graph.bridges
    first_node, count = recs.column("first_node").astype(np.int64), recs.column("count").astype(np.int64)
    clip_start = np.array([c["first_node"] for c in graph.clips] + [N0], dtype=np.int64)
    ca, cb = recs.column("clip_a").astype(np.int64), recs.column("clip_b").astype(np.int64)
    nodes = ranges(first_node, count)
    node_rot, node_pos = forward_kinematics(node_rotations(graph, nodes), node_translations(graph, nodes), sk.parents)
    first = np.zeros(len(recs), dtype=np.int64)
    np.cumsum(count[:-1], out=first[1:])
    readings = bridge_readings(
        lambda f: forward_kinematics(*node_poses(graph, f), sk.parents),
        graph.node_ground[:N0].astype(np.float64),
        graph.node_heading[:N0].astype(np.float64),
        node_rot,
        node_pos,
        graph.node_ground[nodes].astype(np.float64),
        graph.node_heading[nodes].astype(np.float64),
        first,
        count,
        clip_start[ca] + recs.column("a_entry"),
        clip_start[cb] + recs.column("b_exit"),
        clip_start[ca],
        clip_start[ca + 1],
        clip_start[cb],
        clip_start[cb + 1],
        [placements[int(c)] for c in ca],
        graph.rate_hz,
    )
    # Row of each bridge node's entering edge, and of each bridge's exit edge.
    row_of_node = np.full(graph.num_nodes, -1, dtype=np.int64)
    row_of_node[nodes] = np.arange(nodes.size) + np.repeat(np.arange(len(recs)), count)
    exit_row = first + np.arange(len(recs)) + count
    bridge_of_last = np.full(graph.num_nodes, -1, dtype=np.int64)
    bridge_of_last[first_node + count - 1] = np.arange(len(recs))
    edges = np.flatnonzero(graph.edge_kind == EDGE_BRIDGE)
    into = graph.node_kind[graph.edge_dst[edges]] == NODE_BRIDGE
    out[edges[into]] = readings[row_of_node[graph.edge_dst[edges[into]]]]
    out[edges[~into]] = readings[exit_row[bridge_of_last[graph.edge_src[edges[~into]]]]]


# Frames of a graph's clips sampled for its graph-wide sensor frames (`graph_placement`).
PLACEMENT_SAMPLE = 20000


def graph_placement(graph, layout=None):
    """The graph's layout (or `layout`) placed on its skeleton, in the sensor-frame
    convention of the graph's readings (params["sensor_frames"]; graphs without it are
    `rest-pose`): for anatomical frames, estimated from up to PLACEMENT_SAMPLE frames of
    its clips, evenly spread. What the searches use to turn a measured reading into the
    world (OLNG's pose model, the rest-pose readings a live bridge calibrates against);
    each clip's own readings were simulated with its own estimate."""
    layout = layout or layout_from_dict(graph.layout)
    sk = graph.skeleton
    mapping = graph.params.get("mapping")
    if graph.params.get("sensor_frames") != ANATOMICAL:
        return place(layout, sk, mapping)
    n0 = sum(int(c["frames"]) for c in graph.clips) or graph.num_nodes
    nodes = np.unique(np.linspace(0, n0 - 1, min(n0, PLACEMENT_SAMPLE)).round().astype(np.int64))
    world_rot, world_pos = forward_kinematics(node_rotations(graph, nodes), node_translations(graph, nodes), sk.parents)
    return anatomical_placement(layout, sk, mapping, world_rot, world_pos)


# Nodes whose world poses are computed at a time (bounds the FK's memory on large graphs).
_UP_CHUNK = 8192


def edge_up_vectors(graph, layout) -> np.ndarray:
    """(E, S, W) float16: each edge's sensor orientation cue (`sensors.orientation`) for
    `layout`, from the graph's stored poses: the sensors' rotations relative to the
    root sensor's heading (W = 9) where the layout has a root sensor
    (`sensors.layout.root_sensor`), else their "up" vectors, world +Y in each sensor's
    frame (W = 3). An edge plays its destination node's pose whatever its speed (a
    slow-down edge the slerped pose its slow-down node stores, a bridge's exit edge clip
    b's frame turned about the vertical, which leaves either cue alone), so every
    edge's is its destination's, placed as that node's readings are: on its clip's
    skeleton, a bridge's or an interpolated segment's on clip a's (`clip_placements`).
    Both cues are yaw-free (a rotation of the whole body about the vertical leaves them
    unchanged); float16 keeps them to 5e-4 (0.03°)."""
    sk = graph.skeleton
    N, S = graph.num_nodes, len(layout.sensors)
    root = root_sensor(layout)
    width = TILT_WIDTH if root is None else RELATIVE_WIDTH
    owner = np.asarray(graph.node_clip, dtype=np.int64).copy()  # the clip whose skeleton places each node's sensors
    for recs in (graph.segments, graph.bridges):
        owner[ranges(recs.column("first_node"), recs.column("count"))] = np.repeat(
            recs.column("clip_a"), recs.column("count")
        )
    node_cue = np.zeros((N, S, width), np.float16)
    placements = clip_placements(graph, layout)
    # Nodes grouped by owner, each group in node order (one sort, not a scan of every
    # node for each of thousands of clips).
    by_owner = np.argsort(owner, kind="stable")
    clips, starts = np.unique(owner[by_owner], return_index=True)
    for c, lo, hi in zip(clips.tolist(), starts.tolist(), [*starts[1:].tolist(), N]):
        placement = placements[c]
        nodes = by_owner[lo:hi]
        for k in range(0, nodes.size, _UP_CHUNK):
            part = nodes[k : k + _UP_CHUNK]
            world_rot, world_pos = forward_kinematics(
                node_rotations(graph, part),
                node_translations(graph, part),
                sk.parents,
            )
            node_cue[part] = orientation_cue(sensor_poses(world_rot, world_pos, placement)[1], width, root)
    return node_cue[np.asarray(graph.edge_dst, dtype=np.int64)]


def clip_placements(graph, layout) -> list:
    """The layout on each of the graph's clips in anatomical frames, each estimated from
    the clip's stored poses, as `recompute_accelerations` places them."""
    return [clip_placement(graph, layout, c, ANATOMICAL) for c in range(len(graph.clips))]


def clip_placement(graph, layout, c: int, convention: str | None = None, poses=None):
    """The layout on clip c of the graph in a sensor-frame convention (default: that of
    the graph's readings): anatomical frames estimated from the clip's stored poses
    (`clip_placements`; poses: their world rotations and positions when the caller has
    them), or the rest-pose frames of a graph built before them."""
    sk = graph.skeleton
    skeleton = Skeleton(sk.names, sk.parents, graph.clip_offsets[c], sk.channels, sk.end_site)
    if (convention or graph.params.get("sensor_frames", REST_POSE)) != ANATOMICAL:
        return place(layout, skeleton, graph.params.get("mapping"))
    if poses is None:
        info = graph.clips[c]
        nodes = info["first_node"] + np.arange(info["frames"])
        poses = forward_kinematics(
            node_rotations(graph, nodes),
            node_translations(graph, nodes),
            sk.parents,
        )
    world_rot, world_pos = poses
    return anatomical_placement(layout, skeleton, graph.params.get("mapping"), world_rot, world_pos)
