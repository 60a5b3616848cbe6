"""Leave-one-clip-out evaluation: the node mask hides exactly one performance, the
held-out search cannot find the clip, and the run is deterministic whatever --jobs."""

import numpy as np
import pytest

from graphsvc.evaluate import loo
from graphsvc.graph.build import BuildOptions, _performance, build_graph
from graphsvc.graph.model import NODE_BRIDGE, NODE_INTERP, NODE_ORIGINAL, NODE_SLOW
from graphsvc.motion.augment import mirror_motion, reverse_motion
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.pipeline import Options
from graphsvc.sensors.layout import layout_from_dict
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.strategies.options import Weights

# No noise and no poses' filter (a low-pass also blurs a noise-free run by about a
# centimetre): what is left is the search's own error.
EXACT = loo.EvalSetup(noise=NOISE["none"], positions=True, options=Options(weights=Weights(0.5, 1, 1), smooth_s=0.0))


@pytest.fixture(scope="module")
def kb_graph():
    # 1.1 min: nine clips, two of them punches, which blend with each other and with
    # each other's mirror images (interpolated segments with the clip as clip_a and
    # as clip_b).
    kb = generate_knowledge_base(seed=0, minutes=1.1)
    graph, _ = build_graph(kb + [mirror_motion(m) for m in kb], BuildOptions(progress=False))
    return kb, graph


def test_performance_key_agrees_with_the_builder():
    m = generate_knowledge_base(seed=3, minutes=0.1)[0]
    for copy in (m, mirror_motion(m), reverse_motion(m), reverse_motion(mirror_motion(m))):
        assert loo.performance_key(copy.source, copy.name) == _performance(copy)
        assert loo.is_augmented(copy.name) == (copy is not m)


def test_mask_hides_exactly_the_clip_its_slow_downs_its_blends_and_its_mirror(kb_graph):
    kb, graph = kb_graph
    names = [c["name"] for c in graph.clips]
    k = names.index("punch_01")
    mirror = names.index("punch_01_mirror")
    assert set(loo.performance_clips(graph, k).tolist()) == {k, mirror}

    allowed = loo.held_out_mask(graph, k)
    assert allowed.shape == (graph.num_nodes,) and allowed.dtype == bool
    hidden = ~allowed
    kind = np.asarray(graph.node_kind)
    clip = np.asarray(graph.node_clip)
    mine = np.isin(clip, [k, mirror])

    # Original frames: exactly the two clips' frame ranges.
    expected_original = np.zeros(graph.num_nodes, dtype=bool)
    for c in (k, mirror):
        first, frames = graph.clips[c]["first_node"], graph.clips[c]["frames"]
        expected_original[first : first + frames] = True
    assert np.array_equal(hidden & (kind == NODE_ORIGINAL), expected_original)
    # Slow-down nodes: all of the two clips', no other clip's.
    slow = kind == NODE_SLOW
    assert slow[mine].any()
    assert np.array_equal(hidden & slow, slow & mine)
    # Interpolated nodes: those of every segment involving either clip (as the
    # first or the second clip), nothing else.
    involved = np.zeros(graph.num_nodes, dtype=bool)
    as_b = False
    for seg in graph.segments:
        if {seg["clip_a"], seg["clip_b"]} & {k, mirror}:
            involved[seg["first_node"] : seg["first_node"] + seg["count"]] = True
            as_b |= seg["clip_b"] in (k, mirror) and seg["clip_a"] not in (k, mirror)
    assert as_b, "fixture should blend another clip with this one as its second clip"
    assert np.array_equal(hidden & (kind == NODE_INTERP), involved)
    # Bridge nodes: those of every bridge from or to either clip, nothing else.
    bridged = np.zeros(graph.num_nodes, dtype=bool)
    for b in graph.bridges:
        if {b["clip_a"], b["clip_b"]} & {k, mirror}:
            bridged[b["first_node"] : b["first_node"] + b["count"]] = True
    assert bridged.any(), "fixture should bridge this clip to others"
    assert np.array_equal(hidden & (kind == NODE_BRIDGE), bridged)
    # Other clips' original and slow-down nodes all stay.
    assert allowed[np.isin(kind, (NODE_ORIGINAL, NODE_SLOW)) & ~mine].all()
    # And the search never walks through a hidden node.
    row = loo.evaluate_clip(graph, kb[names.index("punch_01")], k, EXACT)
    assert allowed[row["node_path"]].all()
    assert row["hidden_nodes"] == int(hidden.sum())


def test_reversed_copies_are_one_performance():
    clips = [{"name": n, "source": "a.bvh"} for n in ("walk", "walk_mirror", "walk_reverse", "walk_mirror_reverse")]
    clips.append({"name": "walk", "source": "b.bvh"})  # same name, another file: another performance

    class G:
        pass

    g = G()
    g.clips = clips
    assert loo.performance_clips(g, 2).tolist() == [0, 1, 2, 3]


def test_held_out_clip_without_a_twin_is_harder_and_in_graph_is_exact(kb_graph):
    kb, graph = kb_graph
    names = [c["name"] for c in graph.clips]
    k = names.index("run_01")  # the only running clip: nothing like it once hidden
    in_graph = loo.evaluate_clip(graph, kb[k], None, EXACT)
    held_out = loo.evaluate_clip(graph, kb[k], k, EXACT)
    assert in_graph["joint_err_cm"] < 0.5 and in_graph["label_acc"] == 1.0 and in_graph["hidden_nodes"] == 0
    assert held_out["joint_err_cm"] > in_graph["joint_err_cm"] + 2.0
    # No other clip is labelled run: no path can get the label right, so label
    # accuracy does not apply (null), rather than 0.
    assert held_out["label_acc"] is None and held_out["label"] == "run"
    for key in ("samples_per_s", "search_s"):
        assert held_out[key] > 0


def test_without_tracker_streams_the_start_is_placed_at_the_truth(kb_graph):
    kb, graph = kb_graph
    setup = loo.EvalSetup(noise=NOISE["none"], positions=False, options=Options(weights=Weights(1, 0, 0)))
    rec = loo.simulate_test_input(kb[0], layout_from_dict(graph.layout), setup, graph.rate_hz)
    assert rec.ground_position is None and rec.heading is not None
    row = loo.evaluate_clip(graph, kb[0], None, setup)
    assert row["start_placed"] == ["position"]
    assert row["root_err_cm"] < 5.0  # in the graph: the right clip, started in the right place


def test_place_start_moves_the_first_frame_onto_the_truth():
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(5, 3, 3))
    ground = rng.normal(size=(5, 2))
    heading = rng.normal(size=5)
    p, g, h = loo.place_start(pos, ground, heading, np.array([2.0, -1.0]), 0.3, True, True)
    np.testing.assert_allclose(g[0], [2.0, -1.0])
    assert h[0] == pytest.approx(0.3)
    # Rigid: distances within and between frames are kept.
    np.testing.assert_allclose(np.linalg.norm(g - g[0], axis=1), np.linalg.norm(ground - ground[0], axis=1))
    np.testing.assert_allclose(np.linalg.norm(p[1] - p[3], axis=-1), np.linalg.norm(pos[1] - pos[3], axis=-1))
    p2, g2, _ = loo.place_start(pos, ground, heading, np.zeros(2), 0.0, False, False)
    np.testing.assert_allclose(p2, pos)
    np.testing.assert_allclose(g2, ground)


def test_clip_seed_is_stable_and_selection_matches_file_names():
    assert loo.clip_seed(0, "walk_001") == loo.clip_seed(0, "walk_001")
    assert loo.clip_seed(0, "walk_001") != loo.clip_seed(1, "walk_001")
    assert loo.clip_seed(0, "walk_001") != loo.clip_seed(0, "walk_004")
    files = ["a_walk_001.bvh", "a_walk_002.bvh", "a_run_004.bvh", "A_RUN_001.BVH"]
    assert loo.select_clips(files, "*_00[14].bvh") == [0, 2]
    assert loo.select_clips(files, "*_run_*,*walk_002*") == [1, 2]  # (several patterns)
    assert loo.clip_file_name("/data/x/a_walk_001.bvh", "a_walk_001") == "a_walk_001.bvh"
    assert loo.clip_file_name("procedural:seed=0", "walk_01") == "walk_01"


def test_parallel_run_gives_the_same_rows_in_the_same_order(kb_graph):
    kb, graph = kb_graph
    names = [c["name"] for c in graph.clips]
    tests = [(kb[names.index(n)], names.index(n)) for n in ("idle_01", "walk_01")]
    setup = loo.EvalSetup(noise=NOISE["default"], positions=True, options=Options(weights=Weights(0.5, 1, 1)), seed=7)
    serial = loo.run_leave_one_out(graph, tests, setup, jobs=1, progress=False)
    parallel = loo.run_leave_one_out(graph, tests, setup, jobs=2, progress=False)
    assert [r["name"] for r in parallel] == ["idle_01", "walk_01"]
    for a, b in zip(serial, parallel):
        for key in ("joint_err_cm", "root_err_cm", "heading_err_deg", "label_acc", "hidden_nodes", "frames"):
            assert a[key] == b[key], key
    out = loo.summarize_run(parallel)
    assert set(out) == {"clips", "mean", "groups"}  # (groups: locomotion and gestures apart)
    assert {"joint_err_cm", "root_err_cm", "heading_err_deg", "label_acc", "samples_per_s"} <= set(out["mean"])
    assert "per_frame" not in out["clips"][0] and "node_path" not in out["clips"][0]


def test_label_accuracy_with_per_frame_truth():
    # metrics.label_acc/evaluate_frames also take per-frame true labels (the demo's
    # performance changes activity); None frames are not scored.
    from graphsvc.evaluate.metrics import evaluate_frames, label_acc

    per, acc = label_acc(["walk", "run", "idle", "idle"], ["walk", "walk", "idle", None])
    assert per.tolist() == [1.0, 0.0, 1.0, 0.0] and acc == pytest.approx(2 / 3)
    with pytest.raises(Exception, match="per-frame true labels"):
        label_acc(["walk"], ["walk", "run"])
    z = np.zeros((4, 2, 3))
    r = evaluate_frames(
        z,
        z[:3],
        np.zeros((4, 2)),
        np.zeros(4),
        np.zeros((3, 2)),
        np.zeros(3),
        pred_labels=["a", "b", "a", "a"],
        true_label=["a", "a", "a"],
    )
    assert r["frames"] == 3 and r["label_acc"] == pytest.approx(2 / 3)


def test_label_accuracy_counts_only_labels_the_searchable_graph_offers(kb_graph):
    _, graph = kb_graph
    k = [c["name"] for c in graph.clips].index("run_01")
    from graphsvc.strategies import get as get_strategy

    everything = np.ones(graph.num_nodes, dtype=bool)
    hidden = get_strategy("viterbi").allowed_mask(graph, k)
    offered = loo.offered_labels(graph, everything)
    assert offered == set(graph.labels) and "run" not in loo.offered_labels(graph, hidden)
    assert loo.scored_labels("run", offered) == "run" and loo.scored_labels("run", {"walk"}) is None
    # Per-frame truth: the frames whose label is not offered are left out, all of them → n/a.
    assert loo.scored_labels(["walk", "run", None], {"walk"}) == ["walk", None, None]
    assert loo.scored_labels(["run", "run"], {"walk"}) is None


def test_table_and_json_say_not_applicable_for_label_accuracy():
    from graphsvc.evaluate.metrics import summarize
    from graphsvc.evaluate.report import format_table

    row = {
        "name": "run_01",
        "frames": 10,
        "joint_err_cm": 3.0,
        "root_err_cm": 9.0,
        "heading_err_deg": 2.0,
        "label_acc": None,
        "per_frame": {},
    }
    summary = summarize([row])
    assert summary["mean"]["label_acc"] is None  # null in the JSON
    lines = format_table(summary).splitlines()
    assert lines[0].split()[-3:-1] == ["label", "%"]
    assert all("n/a" in line for line in lines[1:] if "run_01" in line or "mean" in line)


def test_the_pose_oracle_is_exact_in_the_graph_and_a_floor_under_nearest_outside(kb_graph):
    kb, graph = kb_graph
    k = [c["name"] for c in graph.clips].index("run_01")
    setup = loo.EvalSetup(noise=NOISE["none"], positions=True, options=Options(strategy="nearest"), pose_oracle=True)
    in_graph = loo.evaluate_clip(graph, kb[k], None, setup)
    held_out = loo.evaluate_clip(graph, kb[k], k, setup)
    assert in_graph["oracle_joint_err_cm"] < 0.05  # (its own frames are there, float32)
    # Hidden, no pose is the run's: a real floor, and under the retrieval's own error.
    assert 0.5 < held_out["oracle_joint_err_cm"] < held_out["joint_err_cm"]
    assert np.all(held_out["per_frame"]["oracle_joint_err_cm"] <= held_out["per_frame"]["joint_err_cm"] + 0.01)
    summary = loo.summarize_run([in_graph, held_out])
    assert "oracle_joint_err_cm" in summary["mean"] and "oracle_joint_err_cm" not in loo.evaluate_clip(
        graph, kb[k], k, EXACT
    )
