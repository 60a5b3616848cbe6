"""Synthesis from a node path on a small procedural graph."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.graph import metadata as meta
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.model import EDGE_ORIGINAL, EDGE_TRANSITION
from graphsvc.graph.poses import node_poses, node_rotations, node_translations
from graphsvc.motion import quat, signals
from graphsvc.motion.bvh import read_bvh, write_bvh
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.synthesis.path import (
    _between,
    _qexp,
    _qlog,
    _qmul,
    _qrot,
    _two_bone_ik,
    contact_spans,
    path_world_positions,
    predecessor_nodes,
    synthesize_motion,
)


@pytest.fixture(scope="module")
def graph():
    g, _ = build_graph(generate_knowledge_base(seed=3, minutes=0.6), BuildOptions(interp=False, progress=False))
    return g


def _edge(g, src, dst):
    return int(np.nonzero((g.edge_src == src) & (g.edge_dst == dst))[0][0])


def _clip_path(g, first, last):
    """Nodes first..last (inclusive, one clip) and the original edges between them."""
    nodes = np.arange(first, last + 1)
    edges = np.array([_edge(g, n, n + 1) for n in nodes[:-1]])
    assert np.all(g.edge_kind[edges] == EDGE_ORIGINAL)
    return nodes, edges


@pytest.fixture(scope="module")
def transition_path(graph):
    """~1.3 s of one clip, a transition, ~1.3 s of another clip."""
    g = graph
    margin = 40
    first = np.array([c["first_node"] for c in g.clips])[g.node_clip]
    frames = np.array([c["frames"] for c in g.clips])[g.node_clip]
    e = np.nonzero(g.edge_kind == EDGE_TRANSITION)[0]
    src, dst = g.edge_src[e], g.edge_dst[e]
    ok = (
        (src - first[src] >= margin)
        & (first[dst] + frames[dst] - 1 - dst >= margin)
        & (g.node_clip[src] != g.node_clip[dst])
    )
    k = int(e[ok][0])
    a_nodes, a_edges = _clip_path(g, g.edge_src[k] - margin, g.edge_src[k])
    b_nodes, b_edges = _clip_path(g, g.edge_dst[k], g.edge_dst[k] + margin)
    return np.concatenate([a_nodes, b_nodes]), np.concatenate([a_edges, [k], b_edges]), margin + 1


def _source_positions(g, nodes):
    return forward_kinematics(*node_poses(g, nodes), g.skeleton.parents)[1]


def test_original_path_reproduces_the_clip(graph):
    g = graph
    c = 1
    first, F = g.clips[c]["first_node"], g.clips[c]["frames"]
    nodes, edges = _clip_path(g, first, first + F - 1)
    start = g.node_ground[first].astype(float), float(g.node_heading[first])
    want = _source_positions(g, nodes)
    for fix in (False, True):  # feet already planted: clean-up changes nothing
        got = path_world_positions(synthesize_motion(g, nodes, edges, *start, fix_feet=fix))
        assert got.shape == want.shape
        assert np.max(np.linalg.norm(got - want, axis=-1)) < 1e-3


def test_root_placed_on_the_integrated_path(graph, transition_path):
    g = graph
    nodes, edges, cut = transition_path
    start = np.array([3.0, -2.0]), 1.2
    motion = synthesize_motion(g, nodes, edges, *start)
    assert motion.num_frames == nodes.size and motion.rate_hz == g.rate_hz
    pos = path_world_positions(motion)
    table = joint_map(g.skeleton)
    ground, heading = meta.integrate_path(
        start[0], start[1], g.edge_offset[edges].astype(float), g.edge_heading[edges].astype(float)
    )
    np.testing.assert_allclose(signals.ground_position(pos, table["pelvis"]), ground, atol=1e-9)
    # Away from the blend window the pose heading is the integrated heading, to the
    # stored rotations' precision (4e-6 rad, `graph.poses`).
    far = np.abs(np.arange(nodes.size) - cut) > 0.5 * 0.7 * g.rate_hz + 1
    dh = np.angle(np.exp(1j * (signals.heading(pos, table) - heading)))[far]
    assert np.max(np.abs(dh)) < 1e-5


def test_transition_is_blended_continuously(graph, transition_path):
    g = graph
    nodes, edges, cut = transition_path
    pos = path_world_positions(synthesize_motion(g, nodes, edges, np.zeros(2), 0.0, fix_feet=False))
    # Per-frame joint displacement with the root travel removed (pose change only).
    local = pos - pos[:, :1]
    jump = np.max(np.linalg.norm(np.diff(local, axis=0), axis=-1), axis=1)  # (T-1,)
    across = jump[cut - 1]
    elsewhere = np.delete(jump, cut - 1).max()
    assert across <= 2.0 * elsewhere
    # Without blending the raw jump is the pose difference at the transition; the
    # blend must not be worse.
    raw = _source_positions(g, nodes)
    raw_local = raw - raw[:, :1]
    assert across <= np.max(np.linalg.norm(raw_local[cut] - raw_local[cut - 1], axis=-1)) + 1e-9


def _skate(g, nodes, edges, start, pos, joint, side):
    """Largest drift (m) of a joint during its contact spans relative to how it
    moved in its source clip (heel/toe roll is the source's own motion, not skate)."""
    pred = nodes.copy()
    cont = g.edge_kind[edges] != EDGE_TRANSITION
    pred[1:] = np.where(cont, nodes[:-1], predecessor_nodes(g, nodes[1:]))
    _, heading = meta.integrate_path(
        start[0], start[1], g.edge_offset[edges].astype(float), g.edge_heading[edges].astype(float)
    )
    turn = quat.about_y(heading - g.node_heading[nodes])
    step = quat.rotate(turn, _source_positions(g, nodes)[:, joint] - _source_positions(g, pred)[:, joint])
    worst = 0.0
    for s, e in contact_spans(g.node_contacts[nodes, side]):
        if e - s > 1:
            drift = np.cumsum(pos[s + 1 : e, joint] - pos[s : e - 1, joint] - step[s + 1 : e], axis=0)
            worst = max(worst, float(np.max(np.linalg.norm(drift, axis=-1))))
    return worst


def test_feet_are_pinned_across_a_transition(graph, transition_path):
    g = graph
    nodes, edges, _ = transition_path
    table = joint_map(g.skeleton)
    start = (np.zeros(2), 0.0)
    fixed = path_world_positions(synthesize_motion(g, nodes, edges, *start))
    loose = path_world_positions(synthesize_motion(g, nodes, edges, *start, fix_feet=False))
    for side, s in enumerate(("l", "r")):
        for joint in (table[f"{s}_ankle"], table[f"{s}_toe"]):
            skate = _skate(g, nodes, edges, start, fixed, joint, side)
            assert skate < 0.01  # measured ~1e-7 m; the blend alone leaves ~3.5 mm
            assert skate <= _skate(g, nodes, edges, start, loose, joint, side)
    # Leg lengths are kept: IK only rotates.
    hip, ankle = table["l_hip"], table["l_ankle"]
    assert np.all(np.linalg.norm(fixed[:, ankle] - fixed[:, hip], axis=-1) <= 0.84 + 1e-6)


def test_bvh_round_trip(graph, transition_path, tmp_path):
    g = graph
    nodes, edges, _ = transition_path
    motion = synthesize_motion(g, nodes, edges, np.array([1.0, 2.0]), -0.5)
    write_bvh(tmp_path / "out.bvh", motion, scale=100.0)
    back = read_bvh(tmp_path / "out.bvh", scale=0.01)
    assert back.num_frames == motion.num_frames
    err = np.linalg.norm(path_world_positions(back) - path_world_positions(motion), axis=-1)
    assert err.max() < 1e-3


def test_rejects_a_broken_path(graph):
    g = graph
    with pytest.raises(InputError):
        synthesize_motion(g, np.array([0, 5]), np.array([_edge(g, 0, 1)]), np.zeros(2), 0.0)


def test_quaternion_kernels_agree_with_the_quat_module():
    rng = np.random.default_rng(5)
    q = quat.normalize(rng.normal(size=(50, 4)))
    p = quat.normalize(rng.normal(size=(50, 4)))
    v = rng.normal(size=(50, 3))
    u = rng.normal(size=(50, 3))
    u[:3] = -v[:3] * np.array([[0.5], [2.0], [1.0]])  # opposite directions
    u[3], v[3] = [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]  # opposite along an axis ⟂ x
    for k in range(50):
        np.testing.assert_allclose(_qmul(*q[k], *p[k]), quat.mul(q[k], p[k]), atol=1e-15)
        np.testing.assert_allclose(_qrot(*q[k], *v[k]), quat.rotate(q[k], v[k]), atol=1e-15)
        back = np.array(_qexp(*_qlog(*q[k])))
        np.testing.assert_allclose(back * np.sign(back[0] * q[k, 0]), q[k], atol=1e-12)  # q and −q: one rotation
        turn = np.array(_between(*u[k], *v[k]))
        np.testing.assert_allclose(np.linalg.norm(turn), 1.0, atol=1e-12)
        direction = quat.rotate(turn, u[k] / np.linalg.norm(u[k]))
        np.testing.assert_allclose(direction, v[k] / np.linalg.norm(v[k]), atol=1e-9)
    assert _qlog(1.0, 0.0, 0.0, 0.0) == (0.0, 0.0, 0.0) and _qexp(0.0, 0.0, 0.0) == (1.0, 0.0, 0.0, 0.0)


def test_two_bone_ik_puts_the_ankle_and_toe_on_reachable_targets(graph):
    g = graph
    table = joint_map(g.skeleton)
    parents = g.skeleton.parents.astype(np.int64)
    rot = node_rotations(g, [40])
    trans = node_translations(g, [40])
    world_rot, world_pos = forward_kinematics(rot, trans, parents)
    hip, knee, ankle, toe = (table[f"l_{n}"] for n in ("hip", "knee", "ankle", "toe"))
    ankle_target = world_pos[0, ankle] + [0.04, 0.05, -0.03]  # the knee is bent: within reach
    toe_dir = world_pos[0, toe] - world_pos[0, ankle] + [0.0, -0.02, 0.01]
    toe_target = ankle_target + toe_dir
    lateral = np.array([1.0, 0.0, 0.0])
    _two_bone_ik(rot, world_rot, world_pos, parents, hip, knee, ankle, toe, ankle_target, toe_target, lateral, 0)
    _, after = forward_kinematics(rot, trans, parents)
    np.testing.assert_allclose(after[0, ankle], ankle_target, atol=1e-9)
    foot = after[0, toe] - after[0, ankle]
    np.testing.assert_allclose(foot / np.linalg.norm(foot), toe_dir / np.linalg.norm(toe_dir), atol=1e-9)
    np.testing.assert_allclose(after[0, hip], world_pos[0, hip], atol=1e-12)  # only the leg below it moved
    for a, b in ((hip, knee), (knee, ankle), (ankle, toe)):  # bones keep their lengths
        length = np.linalg.norm(world_pos[0, b] - world_pos[0, a])
        np.testing.assert_allclose(np.linalg.norm(after[0, b] - after[0, a]), length, atol=1e-12)
    right = table["r_ankle"]
    np.testing.assert_array_equal(after[0, right], world_pos[0, right])
    # The knee bends the way it bent (a mirrored knee reaches the same ankle position).
    before_plane, after_plane = (np.cross(p[knee] - p[hip], p[ankle] - p[knee]) for p in (world_pos[0], after[0]))
    assert before_plane @ after_plane / np.linalg.norm(before_plane) / np.linalg.norm(after_plane) > 0.9


def test_a_track_moves_the_whole_body_onto_it_and_keeps_every_pose(graph, transition_path):
    # synthesize_motion(track=...) places the path's motion (clean-up included) on its
    # own integrated track, then shifts each frame's whole body onto the given track:
    # every joint moves by the same ground-plane offset, so every rotation and every
    # joint's position relative to the root are the own-track synthesis', and the root
    # stands on the track wherever the own-track synthesis stood on its own.
    from graphsvc.motion.kinematics import motion_fk
    from graphsvc.synthesis.track import TrackModel, fused_track

    g = graph
    nodes, edges, _ = transition_path
    start = np.array([0.2, 0.1]), 0.5
    own = synthesize_motion(g, nodes, edges, *start)
    rng = np.random.default_rng(0)
    positions = np.cumsum(rng.normal(0.0, 0.05, (nodes.size, 2)), axis=0) + 1.0
    track = fused_track(g, nodes, edges, *start, positions, TrackModel(0.1, 0.3, float(g.rate_hz)))
    ground, _ = meta.integrate_path(
        start[0], start[1], g.edge_offset[edges].astype(float), g.edge_heading[edges].astype(float)
    )
    moved = synthesize_motion(g, nodes, edges, *start, track=track)
    np.testing.assert_array_equal(moved.rotations, own.rotations)
    _, own_world = motion_fk(own)
    _, moved_world = motion_fk(moved)
    shift = moved_world - own_world
    np.testing.assert_allclose(shift[..., 0], (track[:, 0] - ground[:, 0])[:, None] + 0 * shift[..., 0], atol=1e-9)
    np.testing.assert_allclose(shift[..., 2], (track[:, 1] - ground[:, 1])[:, None] + 0 * shift[..., 2], atol=1e-9)
    np.testing.assert_allclose(shift[..., 1], 0.0, atol=1e-9)
    assert np.abs(track - ground).max() > 0.5  # (the track is far from the path's own)
    with pytest.raises(InputError, match="track"):
        synthesize_motion(g, nodes, edges, *start, track=track[:-1])
