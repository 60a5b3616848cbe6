"""The `nearest` baseline: per sample the frame with the nearest readings, its index
cached beside the graph, batch and live alike."""

import json

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.evaluate import loo
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.model import EDGE_ORIGINAL
from graphsvc.motion.bvh import write_bvh
from graphsvc.motion.procedural import make_clip, standard_skeleton
from graphsvc.pipeline import Options, open_session, reconstruct
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies import get
from graphsvc.strategies.base import prepared_index
from graphsvc.strategies.index import index_path
from graphsvc.strategies.nearest.strategy import _index, choose
from tests.graph.test_connectivity import mixed_kb


@pytest.fixture(scope="module")
def kb():
    return mixed_kb(5)  # walking, running, standing, punching: two clips each


@pytest.fixture(scope="module")
def graph_file(kb, tmp_path_factory):
    g, _ = build_graph(kb, BuildOptions(layout=PRESETS["kelly6"], progress=False))
    path = tmp_path_factory.mktemp("g") / "kb.graph"
    save_graph(g, path)
    return path


def test_each_sample_takes_the_frame_with_the_nearest_readings(graph_file):
    g = load_graph(graph_file)
    idx = _index(g, prepared_index(get("nearest"), g))
    # A sample equal to a frame's arrival reading picks that frame (or one reading the same).
    rng = np.random.default_rng(0)
    picks_at = rng.choice(idx.nodes.size, 20, replace=False)
    acc = idx.readings[picks_at].reshape(20, -1, 3).astype(np.float64) * GRAVITY
    picks, cost = choose(idx, acc)
    np.testing.assert_allclose(idx.readings[picks], idx.readings[picks_at], atol=1e-6)
    assert cost == pytest.approx(0.0, abs=1e-9)
    # By hand: the arrival reading of an original frame is its original edge's.
    n = idx.nodes[5]
    e = np.flatnonzero((g.edge_kind == EDGE_ORIGINAL) & (g.edge_dst == n))[0]
    np.testing.assert_allclose(idx.readings[5], g.edge_acc[e].astype(np.float64).ravel() / GRAVITY, rtol=1e-6)
    # A sample with a missing sensor plays on: the next frame of the previous one's clip.
    acc2 = acc[:2].copy()
    acc2[1, 0] = np.nan
    picks2, _ = choose(idx, acc2)
    assert idx.nodes[picks2[1]] == idx.nodes[picks2[0]] + 1 or idx.next_of[idx.nodes[picks2[0]]] < 0


def test_index_is_cached_beside_the_graph_and_rebuilt_for_another(graph_file, kb, tmp_path):
    g = load_graph(graph_file)
    arrays = prepared_index(get("nearest"), g)
    cache = index_path(graph_file, "nearest")
    assert cache.is_file()
    again = get("nearest").prepare(load_graph(graph_file))  # a fresh load reads the cache, memory-mapped
    for k in arrays:
        np.testing.assert_array_equal(again[k], arrays[k])
    assert not again["readings"].flags.writeable
    # Another graph under the same name: the stale cache is not used.
    other, _ = build_graph(kb[:3], BuildOptions(layout=PRESETS["kelly6"], progress=False))
    path = tmp_path / "kb.graph"
    save_graph(other, path)
    (tmp_path / cache.name).write_bytes(cache.read_bytes())  # the first graph's index, now stale
    fresh = get("nearest").prepare(load_graph(path))
    assert fresh["nodes"].size < arrays["nodes"].size


def test_batch_and_live_give_the_same_motion(graph_file):
    g = load_graph(graph_file)
    motion = make_clip("walk", np.random.default_rng(9), standard_skeleton(), 30.0, 3.0, "walk_x", 9)
    rec = simulate_recording(motion, PRESETS["kelly6"], NOISE["default"], seed=3)
    batch = reconstruct(g, rec, Options(strategy="nearest"))
    live = open_session(g, Options(strategy="nearest"), rec.sensor_names)
    frames = []
    for k in range(rec.num_samples):
        frames += live.push(rec.timestamps_s[k], rec.accelerations[k], rec.ground_position[k], rec.heading[k])
    frames += live.flush()
    assert [f.node for f in frames] == batch.node_path.tolist()
    assert all(f.sources and f.sources[0][2] == 1.0 for f in frames)
    np.testing.assert_allclose(live.motion().rotations, batch.motion.rotations, atol=1e-6)
    assert live.lag_frames > 0 and frames[0].index == 0


def test_a_floor_below_15_cm_on_held_out_clips(kb):
    """Held out (leave-one-out): walking and standing still stay below 15 cm joint error."""
    graph, _ = build_graph(kb, BuildOptions(layout=PRESETS["kelly6"], progress=False))
    setup = loo.EvalSetup(NOISE["default"], positions=True, options=Options(strategy="nearest"))
    names = [m.name for m in kb]
    for label in ("walk", "idle"):
        k = next(i for i, n in enumerate(names) if n.startswith(label))
        row = loo.evaluate_clip(graph, kb[k], k, setup)
        assert row["joint_err_cm"] < 15.0, (label, row["joint_err_cm"])
        allowed = loo.held_out_mask(graph, k)
        assert allowed[row["node_path"]].all()  # never a frame of the held-out clip


def test_cli_synthesize_and_evaluate_with_nearest(kb, tmp_path, capsys):
    kb_dir = tmp_path / "kb_dir"
    kb_dir.mkdir()
    for clip in kb:
        write_bvh(kb_dir / f"{clip.name}.bvh", clip, scale=100.0)
    graph = tmp_path / "kb.graph"
    assert main(["build", str(kb_dir), "-o", str(graph), "--layout", "kelly6", "--quiet"]) == 0
    clip = make_clip("walk", np.random.default_rng(5), standard_skeleton(), 30.0, 2.0, "walk_y", 5)
    rec = tmp_path / "walk.rec"
    save_recording(simulate_recording(clip, PRESETS["kelly6"], NOISE["default"], seed=1), rec)
    capsys.readouterr()
    out, report = tmp_path / "out.bvh", tmp_path / "r.json"
    assert (
        main(
            [
                "synthesize",
                str(graph),
                str(rec),
                "-o",
                str(out),
                "--strategy",
                "nearest",
                "--beam",
                "3",
                "--report",
                str(report),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "ignored: beam" in printed and out.is_file()
    r = json.loads(report.read_text())
    assert r["strategy"] == "nearest" and r["ignored_options"] == ["beam"]
    assert r["files"] == {"output": str(out.resolve()), "graph": str(graph.resolve()), "recording": str(rec.resolve())}
    assert (
        main(
            [
                "evaluate",
                str(kb_dir),
                "--test",
                "walk_*.bvh",
                "--graph",
                str(graph),
                "--strategy",
                "nearest",
                "--json",
                str(tmp_path / "e.json"),
                "--quiet",
            ]
        )
        == 0
    )
    e = json.loads((tmp_path / "e.json").read_text())
    assert e["config"]["options"]["strategy"] == "nearest" and e["mean"]["joint_err_cm"] < 15.0


def test_a_floor_below_15_cm_on_held_out_bandai_walking_and_waving(data_dir):
    from graphsvc.graph.build import load_knowledge_base

    folder = data_dir / "bandai" / "dataset-2" / "data"
    files = [str(folder / f"dataset-2_{c}_normal_00{k}.bvh") for c in ("walk", "wave-left-hand") for k in (1, 2, 3)]
    motions = load_knowledge_base(files)
    graph, _ = build_graph(motions, BuildOptions(progress=False))
    setup = loo.EvalSetup(NOISE["default"], positions=True, options=Options(strategy="nearest"))
    for k in (0, 3):  # walk_normal_001, wave-left-hand_normal_001, held out
        row = loo.evaluate_clip(graph, motions[k], k, setup)
        assert row["joint_err_cm"] < 15.0, (motions[k].name, row["joint_err_cm"])
