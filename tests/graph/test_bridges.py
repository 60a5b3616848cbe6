"""Bridges between actions (graph/bridges.py) on a procedural knowledge base of walking,
running, standing and punching: what they join, what they play, what they read."""

import numpy as np
import pytest

from graphsvc.evaluate.loo import held_out_mask
from graphsvc.graph import bridges as br
from graphsvc.graph import interpolation as interp
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.metadata import recompute_accelerations
from graphsvc.graph.model import EDGE_BRIDGE, NODE_BRIDGE, NODE_ORIGINAL
from graphsvc.graph.poses import node_rotations, node_translations
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.sensors.layout import PRESETS
from graphsvc.synthesis.path import synthesize_motion
from tests.graph.test_connectivity import mixed_kb


@pytest.fixture(scope="module")
def kb():
    return mixed_kb(5)


@pytest.fixture(scope="module")
def graph(kb):
    g, report = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False))
    assert report.bridges == len(g.bridges) > 0
    return g


def _frame_node(g, clip: int, frame: int) -> int:
    return g.clips[clip]["first_node"] + frame


def test_bridges_join_different_actions_and_every_clip_end(graph):
    g = graph
    labels = [g.labels[g.node_label[g.clips[c]["first_node"]]] for c in range(len(g.clips))]
    kinds = {b["kind"] for b in g.bridges}
    assert kinds == {"label", "end", "start"}
    pairs = {(labels[b["clip_a"]], labels[b["clip_b"]]) for b in g.bridges if b["kind"] == "label"}
    assert ("walk", "run") in pairs and ("run", "walk") in pairs
    assert ("walk", "idle") in pairs and ("idle", "punch") in pairs
    assert all(labels[b["clip_a"]] != labels[b["clip_b"]] for b in g.bridges if b["kind"] == "label")
    # Every clip is left from its last frame with a foot down, and entered right after its first.
    for c, clip in enumerate(g.clips):
        nodes = clip["first_node"] + np.arange(clip["frames"])
        grounded = np.flatnonzero(g.node_contacts[nodes].any(axis=1))
        ends = [b for b in g.bridges if b["kind"] == "end" and b["clip_a"] == c]
        starts = [b for b in g.bridges if b["kind"] == "start" and b["clip_b"] == c]
        assert ends and all(b["a_entry"] == grounded[-1] for b in ends), clip["name"]
        assert starts and all(b["b_exit"] == grounded[0] + 1 for b in starts), clip["name"]


def test_bridges_respect_foot_contacts_and_never_start_in_flight(graph):
    g = graph
    for b in g.bridges:
        i = _frame_node(g, b["clip_a"], b["a_match"])
        j = _frame_node(g, b["clip_b"], b["b_match"])
        common = g.node_contacts[i] & g.node_contacts[j]
        assert common.any(), b  # the matched frames share a planted foot: neither is in flight
        entry = _frame_node(g, b["clip_a"], b["a_entry"])
        nodes = b["first_node"] + np.arange(b["count"])
        assert np.all(g.node_kind[nodes] == NODE_BRIDGE)
        # A bridge's node is in contact only where both clips' frames it blends are.
        k = np.arange(1, b["count"] + 1)
        fa = np.clip(b["a_entry"] + k, 0, g.clips[b["clip_a"]]["frames"] - 1)
        fb = np.clip(b["b_exit"] - b["count"] - 1 + k, 0, g.clips[b["clip_b"]]["frames"] - 1)
        both = (
            g.node_contacts[_frame_node(g, b["clip_a"], 0) + fa] & g.node_contacts[_frame_node(g, b["clip_b"], 0) + fb]
        )
        np.testing.assert_array_equal(g.node_contacts[nodes], both)
        # Entered from a frame of a, left to a frame of b, one edge per step.
        e_in = np.flatnonzero((g.edge_dst == nodes[0]) & (g.edge_kind == EDGE_BRIDGE))
        assert e_in.size == 1 and g.edge_src[e_in[0]] == entry
        e_out = np.flatnonzero((g.edge_src == nodes[-1]) & (g.edge_kind == EDGE_BRIDGE))
        assert e_out.size == 1 and g.edge_dst[e_out[0]] == _frame_node(g, b["clip_b"], b["b_exit"])
        assert g.node_kind[entry] == NODE_ORIGINAL


def test_bridge_blends_from_one_clip_into_the_other(graph):
    """The first node is nearly a's frame after the entry, the last nearly b's frame
    before the exit (relative to their own root placement), weights rising between:
    each within a tenth of its distance from the frame it is blended with (node k of L
    pairs a's frame p + k with b's q − L − 1 + k, weighing b by smoothstep(k / (L + 1)):
    0.028 for the first node of a 9-node bridge, 0.972 for its last)."""
    g = graph
    sk = g.skeleton
    pelvis = joint_map(sk)["pelvis"]

    def local(nodes):
        _, pos = forward_kinematics(node_rotations(g, nodes), node_translations(g, nodes), sk.parents)
        c, s = np.cos(g.node_heading[nodes]), np.sin(g.node_heading[nodes])
        x = pos[..., 0] - pos[:, pelvis : pelvis + 1, 0]
        z = pos[..., 2] - pos[:, pelvis : pelvis + 1, 2]
        return np.stack([c[:, None] * x - s[:, None] * z, pos[..., 1], s[:, None] * x + c[:, None] * z], axis=-1)

    for b in g.bridges[:: max(1, len(g.bridges) // 12)]:
        if b["count"] < 8:
            continue
        L = b["count"]
        nodes = b["first_node"] + np.arange(L)

        def a_frame(f):
            return _frame_node(g, b["clip_a"], int(np.clip(f, 0, g.clips[b["clip_a"]]["frames"] - 1)))

        def b_frame(f):
            return _frame_node(g, b["clip_b"], int(np.clip(f, 0, g.clips[b["clip_b"]]["frames"] - 1)))

        blend = local(nodes)
        # the first node: a's frame after the entry, blended with b's q − L
        a_next, first_partner = local(np.array([a_frame(b["a_entry"] + 1), b_frame(b["b_exit"] - L)]))
        # the last: b's frame before the exit, blended with a's p + L
        b_prev, last_partner = local(np.array([b_frame(b["b_exit"] - 1), a_frame(b["a_entry"] + L)]))
        first_err = np.abs(blend[0] - a_next).max()
        last_err = np.abs(blend[-1] - b_prev).max()
        assert first_err <= 0.1 * np.abs(a_next - first_partner).max() + 1e-3, b
        assert last_err <= 0.1 * np.abs(b_prev - last_partner).max() + 1e-3, b


def test_bridge_readings_are_what_its_poses_play(graph):
    """Relayout recomputes every edge reading from the stored poses: for bridge edges
    the same blend-with-context simulation, equal up to the poses' float32 storage."""
    g = graph
    again = recompute_accelerations(g, PRESETS["wrists-ankles"])
    e = g.edge_kind == EDGE_BRIDGE
    assert np.abs(again[e] - g.edge_acc[e]).max() < 0.05  # m/s²; readings span ±100
    # and another layout gets readings of its own sensors
    six = recompute_accelerations(g, PRESETS["kelly6"])
    assert six.shape == (g.num_edges, 6, 3) and np.all(np.isfinite(six[e]))


def test_synthesis_plays_through_a_bridge_without_jumps(graph):
    g = graph
    b = max(g.bridges, key=lambda r: r["count"])
    entry = _frame_node(g, b["clip_a"], b["a_entry"])
    exit_node = _frame_node(g, b["clip_b"], b["b_exit"])
    before = np.arange(entry - 5, entry + 1)
    nodes = np.concatenate([before, b["first_node"] + np.arange(b["count"]), exit_node + np.arange(6)])
    edges = []
    for s, d in zip(nodes[:-1], nodes[1:]):
        edges.append(int(np.flatnonzero((g.edge_src == s) & (g.edge_dst == d))[0]))
    motion = synthesize_motion(g, nodes, np.array(edges), np.zeros(2), 0.0)

    def fastest(rot, trans):  # the fastest joint's step per frame, m
        _, pos = forward_kinematics(rot, trans, g.skeleton.parents)
        return np.linalg.norm(np.diff(pos, axis=0), axis=-1).max(axis=1)

    step = fastest(motion.rotations, motion.translations)
    # The two clips as recorded, over the frames the bridge blends and a bit around.
    own = max(
        fastest(node_rotations(g, r), node_translations(g, r)).max()
        for r in (
            np.arange(
                entry - 5,
                min(entry + b["count"] + 6, g.clips[b["clip_a"]]["first_node"] + g.clips[b["clip_a"]]["frames"]),
            ),
            np.arange(max(exit_node - b["count"] - 6, g.clips[b["clip_b"]]["first_node"]), exit_node + 6),
        )
    )
    assert step.max() < 1.25 * own, (step.max(), own)  # no teleport anywhere on the way


def test_held_out_clip_hides_its_bridges(graph):
    g = graph
    allowed = held_out_mask(g, 0)
    for b in g.bridges:
        nodes = slice(b["first_node"], b["first_node"] + b["count"])
        if 0 in (b["clip_a"], b["clip_b"]):
            assert not allowed[nodes].any()
    assert allowed.sum() < g.num_nodes


def test_graph_file_keeps_bridges(graph, tmp_path):
    save_graph(graph, tmp_path / "g.graph")
    again = load_graph(tmp_path / "g.graph")
    assert again.bridges == graph.bridges
    np.testing.assert_array_equal(again.node_kind, graph.node_kind)


def test_blend_length_rule():
    rate = 30.0
    # 0.3 s at least; 3 s per metre of pose difference; Δv / 2 m/s²; 1.2 s at most.
    np.testing.assert_array_equal(
        br.blend_length(np.array([0.0, 0.2, 0.05, 1.0]), np.array([0.0, 0.0, 1.4, 0.0]), rate), [9, 18, 21, 36]
    )


def test_match_features_ignore_where_and_which_way_a_clip_goes(kb):
    """Turning and moving a whole clip on the ground leaves its match features alone
    (they are in each frame's own ground frame)."""
    clip = kb[0]
    sk = clip.skeleton
    table = joint_map(sk)
    from graphsvc.graph.metadata import ground_and_heading
    from graphsvc.motion import quat
    from graphsvc.motion.joints import CANONICAL

    def feats(rot0, trans0):
        _, pos = forward_kinematics(rot0, trans0, sk.parents)
        ground, heading = ground_and_heading(pos, table)
        canon = pos[:, [table[c] for c in CANONICAL]]
        return br.match_features(canon, ground, heading, np.array([0, clip.num_frames]), 30.0)

    rot, trans = clip.rotations.copy(), clip.translations.copy()
    turned_rot = rot.copy()
    turned_rot[:, 0] = quat.mul(quat.about_y(np.full(rot.shape[0], 1.1)), rot[:, 0])
    turned_trans = trans.copy()
    c, s = np.cos(1.1), np.sin(1.1)
    x, z = trans[:, 0, 0], trans[:, 0, 2]
    turned_trans[:, 0, 0], turned_trans[:, 0, 2] = c * x + s * z + 3.0, -s * x + c * z - 2.0
    np.testing.assert_allclose(feats(turned_rot, turned_trans), feats(rot, trans), atol=1e-4)


def test_reachable_span_and_trimming():
    contacts = np.zeros((10, 2), dtype=bool)
    contacts[2:8, 0] = True  # clip 0: frames 2 … 7 grounded
    contacts[:, 1] = np.r_[np.zeros(5), np.ones(5)].astype(bool)  # … and 5 … 9 on the other foot
    first, last = br.reachable_span(np.concatenate([contacts, np.ones((4, 2), bool)]), np.array([0, 10, 14]))
    np.testing.assert_array_equal(first, [3, 1])
    np.testing.assert_array_equal(last, [9, 3])
    path = np.stack([np.arange(0, 10), np.arange(0, 10)], axis=1)
    # Entered from frame ≥ 3 of a or ≥ 3 of b, left to frame ≤ 6 of a or ≤ 6 of b.
    out = interp.trim_to_reachable(path, (3, 6), (3, 6), rate_hz=30.0, min_seconds=0.03)
    assert out[0].tolist() == [4, 4] and out[-1].tolist() == [5, 5]
    assert interp.trim_to_reachable(path, (3, 6), (3, 6), rate_hz=30.0, min_seconds=0.5) is None
    untouched = interp.trim_to_reachable(path[2:8], (1, 20), (1, 20), rate_hz=30.0, min_seconds=0.1)
    np.testing.assert_array_equal(untouched, path[2:8])


def _masked_nearest(points, state, performance, label, num_labels, performer):
    """The candidate search written out plainly: for each point and label, the
    nearest (float64) point of that label sharing a contact bit, of another
    performance (and, second, of the point's own performer)."""
    d2 = ((points[:, None, :].astype(np.float64) - points[None, :, :]) ** 2).sum(-1)
    ok = ((state[:, None] & state[None, :]) != 0) & (performance[:, None] != performance[None, :])
    out = np.full((len(points), num_labels, 2), -1)
    for v, mask in enumerate((ok, ok & (performer[:, None] == performer[None, :]))):
        for lab in range(num_labels):
            d = np.where(mask & (label[None, :] == lab), d2, np.inf)
            k = np.argmin(d, axis=1)
            some = np.isfinite(d[np.arange(len(points)), k])
            out[some, lab, v] = k[some]
    return out


def test_candidate_search_finds_the_masked_nearest_on_any_number_of_threads():
    """`best_per_label` (BLAS products, one compiled pass of masks and minima, row
    blocks on threads) against the plain masked nearest, on points spread far enough
    apart that float32 rounding cannot swap two; the same on 1 and 3 threads."""
    rng = np.random.default_rng(4)
    M, L = 1300, 5  # (more than two row blocks of 512)
    points = rng.normal(size=(M, 6)).astype(np.float32) * 10.0
    state = rng.integers(1, 4, M)
    performance = rng.integers(0, 40, M)
    performer = performance % 3
    label = rng.integers(0, L, M)
    label[label == 4] = 3  # (a label without points: no candidate)
    one = br.best_per_label(points, state, performance, label, L, performer, jobs=1)
    three = br.best_per_label(points, state, performance, label, L, performer, jobs=3)
    np.testing.assert_array_equal(one[0], three[0])
    np.testing.assert_array_equal(one[1], three[1])
    want = _masked_nearest(points, state, performance, label, L, performer)
    np.testing.assert_array_equal(one[0], want)
    assert (one[0][:, 4] == -1).all() and np.isinf(one[1][:, 4]).all()
    found = one[0] >= 0
    rows = np.nonzero(found)[0]
    exact = ((points[rows].astype(np.float64) - points[one[0][found]]) ** 2).sum(-1)
    np.testing.assert_allclose(one[1][found], exact, rtol=1e-4)
    alone = br.best_per_label(points, state, performance, label, L)  # without performers: one variant
    np.testing.assert_array_equal(alone[0][..., 0], want[..., 0])


def test_features_at_some_frames_are_those_of_every_frame(kb):
    """The candidates' features computed at their frames only are, bit for bit, the
    rows of every frame's (each frame's window and clamping within its own clip)."""
    from graphsvc.graph.metadata import ground_and_heading
    from graphsvc.motion.joints import CANONICAL

    clips = kb[:3]
    sk = clips[0].skeleton
    table = joint_map(sk)
    canon, ground, heading = [], [], []
    for clip in clips:
        _, pos = forward_kinematics(clip.rotations, clip.translations, sk.parents)
        g, h = ground_and_heading(pos, table)
        canon.append(pos[:, [table[c] for c in CANONICAL]])
        ground.append(g)
        heading.append(h)
    canon, ground, heading = np.concatenate(canon), np.concatenate(ground), np.concatenate(heading)
    start = np.r_[0, np.cumsum([c.num_frames for c in clips])]
    frames = np.array([0, 1, 5, start[1] - 1, start[1], start[1] + 2, start[2] + 3, start[3] - 1])
    full = br.match_features(canon, ground, heading, start, 30.0)
    np.testing.assert_array_equal(br.match_features(canon, ground, heading, start, 30.0, frames), full[frames])
    every = br.body_features(canon, ground, start, 7)
    some = br.body_features(canon, ground, start, 7, frames)
    for name in ("x", "z", "y", "norm2", "mean_xz"):
        np.testing.assert_array_equal(getattr(some, name), getattr(every, name)[frames])
    # Every frame's clouds are those `pose_features` makes of each clip alone.
    from graphsvc.graph.distance import pose_features

    rel = canon.copy()
    rel[..., 0] -= ground[:, None, 0]
    rel[..., 2] -= ground[:, None, 1]
    second = pose_features(rel[start[1] : start[2]], 7)
    np.testing.assert_array_equal(every.x[start[1] : start[2]], second.x)


def test_world_summaries_chunk_by_chunk_are_those_of_all_frames(kb):
    from graphsvc.motion.placement import relative_pose

    clip = kb[1]
    sk = clip.skeleton
    heading = np.linspace(0.0, 2.0, clip.num_frames)
    rot, pos = forward_kinematics(clip.rotations, clip.translations, sk.parents)
    rel, height = relative_pose(rot, pos, heading, 1)
    canon, rel_c, height_c = br.world_summaries(clip.rotations, clip.translations, heading, sk.parents, 1, [0, 3], 17)
    np.testing.assert_array_equal(canon, pos[:, [0, 3]])
    np.testing.assert_array_equal(rel_c, rel)
    np.testing.assert_array_equal(height_c, height)
