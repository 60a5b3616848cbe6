"""The report's arrays (graphsvc.report.gather) on hand-checked cases, and the page's
self-containment (graphsvc.report.html)."""

import base64
import re

import numpy as np
import pytest

from graphsvc.graph.model import EDGE_ORIGINAL, EDGE_SLOW, EDGE_TRANSITION, NODE_SLOW, graph_from_edges
from graphsvc.motion import quat
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.skeleton import Motion, Skeleton
from graphsvc.report.gather import centre_joint, constraint_arrays, drawn_joints, figure_arrays
from graphsvc.report.html import data_json, render_html, three_script
from graphsvc.strategies.results import Provenance
from graphsvc.strategies.sources import (
    compact_sources,
    path_edges,
    path_readings,
    source_readings,
    timeline_from_nodes,
    timeline_from_sources,
)
from tests.conftest import tpose_skeleton


def _decode(text, dtype):
    return np.frombuffer(base64.b64decode(text), dtype=np.dtype(dtype).newbyteorder("<"))


def test_figure_positions_are_the_motions_to_half_a_millimetre():
    sk = tpose_skeleton()
    rng = np.random.default_rng(3)
    T, J = 7, sk.num_joints
    rot = quat.normalize(quat.identity((T, J)) + 0.3 * rng.normal(size=(T, J, 4)))
    trans = np.broadcast_to(sk.offsets, (T, J, 3)).copy()
    trans[:, 0] = [[12.3456 + t, 0.9, -40.1234] for t in range(T)]  # (far from the origin)
    motion = Motion(sk, rot, trans, 30.0, name="m")
    fig = figure_arrays(motion, "reconstruction")
    root = _decode(fig["root_mm"], np.int32).reshape(T, 3)
    rel = _decode(fig["rel_mm"], np.int16).reshape(T, J, 3)
    _, world = motion_fk(motion)
    page = (root[:, None, :] + rel) / 1000.0
    assert np.abs(page - world).max() <= 0.0005 + 1e-12
    assert fig["parents"] == sk.parents.tolist() and fig["joints"] == list(sk.names)
    assert fig["feet"] == [sk.names.index("l_ankle"), sk.names.index("r_ankle")]
    assert len(fig["contacts"][0]) == T and set(fig["contacts"][0]) <= {"0", "1"}


def _under_a_fixed_root(prefix: str = "") -> Motion:
    """The T-pose skeleton (joint names prefixed) under a root joint "world" that stays
    at the origin while the pelvis walks from x = 5 m along +Z (Bandai-Namco's
    `joint_Root` above `Hips`), 6 frames."""
    sk = tpose_skeleton()
    J = sk.num_joints + 1
    names = ("world",) + tuple(prefix + n for n in sk.names)
    parents = np.array([-1, 0] + [int(p) + 1 for p in sk.parents[1:]])
    channels = (("Xposition", "Yposition", "Zposition"),) + sk.channels
    under = Skeleton(names, parents, np.vstack([np.zeros(3), sk.offsets]), channels, np.zeros(J, bool))
    T = 6
    trans = np.broadcast_to(under.offsets, (T, J, 3)).copy()
    trans[:, 1] = [[5.0, 0.96, 0.1 * t] for t in range(T)]
    return Motion(under, quat.identity((T, J)), trans, 30.0, name="fixed root")


def test_the_page_follows_the_pelvis_and_draws_no_bone_from_a_fixed_root_above_it():
    motion = _under_a_fixed_root()
    J = motion.skeleton.num_joints
    fig = figure_arrays(motion, "truth")  # (a skeleton of the procedural map: its pelvis is joint 1)
    assert fig["centre"] == 1 and motion.skeleton.names[1] == "pelvis"
    assert fig["drawn"] == list(range(1, J))  # (every joint but "world")
    assert fig["contacts"] is not None
    # The encoding is unchanged: joint 0 (the fixed root) and every joint relative to it.
    root = _decode(fig["root_mm"], np.int32).reshape(-1, 3)
    rel = _decode(fig["rel_mm"], np.int16).reshape(-1, J, 3)
    assert (root == 0).all()
    assert rel[:, 1].tolist() == [[5000, 960, 100 * t] for t in range(6)]
    # A skeleton no joint map knows: the first joint that moves (the pelvis, whose
    # parent stays put), and the same joints drawn.
    unknown = _under_a_fixed_root(prefix="x_")
    fig = figure_arrays(unknown, "truth")
    assert fig["contacts"] is None and fig["centre"] == 1 and fig["drawn"] == list(range(1, J))
    _, world = motion_fk(unknown)
    assert centre_joint(world) == 1
    assert centre_joint(world[:1]) == 0  # (one frame: nothing moves)
    assert centre_joint(np.full((3, J, 3), np.nan)) == 0  # (bad input: no crash)


def test_drawn_joints_leave_out_the_centres_ancestors_only():
    #        0
    #        |
    #        1
    #      / | \
    #     2  4  5
    #     |
    #     3
    parents = [-1, 0, 1, 2, 1, 1]
    assert drawn_joints(parents, 0) == [0, 1, 2, 3, 4, 5]
    assert drawn_joints(parents, 1) == [1, 2, 3, 4, 5]
    assert drawn_joints(parents, 3) == [3, 4, 5]
    assert drawn_joints(parents, 4) == [2, 3, 4, 5]


def _path_graph():
    # nodes 0-3 clip 0 (frames 0-3), 4-6 clip 1 (frames 0, 0.5, 1: node 5 a slow-down node)
    src = [0, 1, 2, 2, 4, 5]
    dst = [1, 2, 3, 4, 5, 6]
    kinds = [EDGE_ORIGINAL, EDGE_ORIGINAL, EDGE_ORIGINAL, EDGE_TRANSITION, EDGE_SLOW, EDGE_SLOW]
    acc = np.arange(6 * 2 * 3, dtype=np.float64).reshape(6, 2, 3)
    g = graph_from_edges(src, dst, acc, kinds=kinds)
    g.node_clip[:] = [0, 0, 0, 0, 1, 1, 1]
    g.node_frame[:] = [0, 1, 2, 3, 0, 0.5, 1]
    g.node_kind[5] = NODE_SLOW
    g.node_label[:] = [0, 0, 0, 0, 1, 1, 1]
    g.clips = [{"name": "walk_01"}, {"name": "run_01"}]
    return g, acc


def test_timeline_of_a_node_path_names_clips_kinds_and_transitions():
    g, acc = _path_graph()
    nodes = [0, 1, 2, 4, 5, 6]
    assert path_edges(g, nodes).tolist() == [-1, 0, 1, 3, 4, 5]  # (edges sorted by destination: 2→4 is 3rd)
    tl = timeline_from_nodes(g, nodes)
    assert [(s["start"], s["frames"], s["clip"], s["label"], s["kind"], s["from_frame"]) for s in tl["segments"]] == [
        (0, 3, "walk_01", "a", "original", 0.0),
        (3, 1, "run_01", "b", "original", 0.0),
        (4, 2, "run_01", "b", "speed", 0.5),
    ]
    assert tl["transitions"] == [3]
    assert tl["labels"] == [
        {"label": "a", "start_frame": 0, "frames": 3},
        {"label": "b", "start_frame": 3, "frames": 3},
    ]
    readings = path_readings(g, nodes)
    assert np.isnan(readings[0]).all()
    by_pair = {(s, d): acc[k] for k, (s, d) in enumerate(zip([0, 1, 2, 2, 4, 5], [1, 2, 3, 4, 5, 6]))}
    for t in range(1, 6):
        np.testing.assert_array_equal(readings[t], by_pair[(nodes[t - 1], nodes[t])])
    # A jump no edge makes (nearest may play any frame next) is a transition too.
    assert timeline_from_nodes(g, [0, 1, 6])["transitions"] == [2]


def test_sources_readings_are_the_weighted_mean_of_their_frames():
    g, acc = _path_graph()
    # clip 0 frame 2 is node 2, entered by edge 1→2 (index 1); clip 0 frame 1 is node 1 (edge 0).
    clip = np.array([[0, 0], [0, -1], [1, -1]])
    frame = np.array([[2.0, 1.0], [3.0, 0.0], [0.0, 0.0]])
    weight = np.array([[0.25, 0.75], [1.0, 0.0], [1.0, 0.0]])
    out = source_readings(g, clip, frame, weight)
    np.testing.assert_allclose(out[0], 0.25 * acc[1] + 0.75 * acc[0])
    np.testing.assert_allclose(out[1], acc[2])
    assert np.isnan(out[2]).all()  # (clip 1 frame 0 is entered by no original edge)


def test_timeline_of_blended_sources_lists_the_heaviest_clips():
    names = ["walk_01", "run_01", "idle_01"]
    clip = np.array([[0, 1], [0, 1], [1, -1], [2, 0]])
    frame = np.array([[5, 9], [6, 10], [11, 0], [0, 7]], float)
    weight = np.array([[0.6, 0.4], [0.5, 0.5], [1.0, 0.0], [0.8, 0.2]])
    tl = timeline_from_sources(names, ["walk", "walk", "run", "idle"], clip, frame, weight, rows=2)
    assert [(s["start"], s["frames"], s["clip"], s["kind"]) for s in tl["segments"]] == [
        (0, 2, "walk_01", "blend"),
        (2, 1, "run_01", "original"),
        (3, 1, "idle_01", "blend"),
    ]
    assert tl["transitions"] == [2, 3]
    # total weights: walk 1.3, run 1.9, idle 0.8 → run, walk
    assert tl["neighbours"]["clips"] == ["run_01", "walk_01"]
    assert tl["neighbours"]["weights"] == ["4490", "5402"]  # (weight × 9, rounded; 4.5 rounds to even)
    prov = Provenance(clip, frame, weight, np.array(["walk", "walk", "run", "idle"], object))
    c = compact_sources(prov, top=1)
    assert c == {
        "clip": [[0], [0], [1], [2]],
        "frame": [[5.0], [6.0], [11.0], [0.0]],
        "weight": [[0.6], [0.5], [1.0], [0.8]],
    }


def test_constraints_marked_met_frame_by_frame():
    labels = ["walk"] * 4 + ["run"] * 4
    contacts = np.zeros((8, 2), bool)
    contacts[:3, 0] = True
    sets = [
        [{"start_s": 0.1, "end_s": 0.5, "require": {"contact": "left"}}],
        [{"start_s": 0.2, "end_s": 10.0, "require": {"label": "run"}}],
    ]
    out = constraint_arrays(sets, labels, contacts, rate_hz=10.0)
    assert [(c["set"], c["first_frame"], c["met"]) for c in out] == [(0, 1, "1100"), (1, 2, "001111")]


def test_page_is_self_contained_and_its_data_cannot_close_the_script():
    doc = {"title": "t <b>", "clips": [{"name": "</script><script>alert(1)</script>"}], "table": None}
    text = data_json(doc)
    assert "</script" not in text and "<" not in text
    page = render_html(doc)
    assert page.count("</script>") == 3  # (the data's, three.js's and the viewer's own)
    assert "t &lt;b&gt;" in page
    # nothing loaded from the network: no src, href, import or fetch of an http(s) URL
    network = re.compile(
        r"""(src|href)\s*=\s*["']?\s*https?:|import\s*\(?\s*["']https?:|from\s*["']https?:|fetch\(\s*["']https?:""",
        re.I,
    )
    assert not network.search(page)
    assert "<link" not in page and not re.search(r"<script[^>]*\bsrc=", page)
    three = three_script()
    assert three.startswith("/**\n * @license") and "SPDX-License-Identifier: MIT" in three[:200]
    assert "export{" not in three and three.rstrip().endswith("})();")


def test_three_namespace_runs_without_a_module_loader():
    import shutil

    node = shutil.which("node")
    if node is None:
        pytest.skip("node not found: cannot run three.js outside a browser")
    import subprocess

    script = three_script() + "\nconsole.log(typeof THREE.WebGLRenderer, typeof THREE.LineSegments, THREE.REVISION);"
    out = subprocess.run([node, "-"], input=script, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-500:]
    assert out.stdout.split() == ["function", "function", "168"]
