"""Recording → motion through `graphsvc.pipeline`, the path the CLI, evaluation and
service share: input checks, rate conversion, heading from the track, batch vs live."""

import json
from dataclasses import replace

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import InputError
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import save_graph
from graphsvc.graph.model import READING_DTYPE
from graphsvc.motion.bvh import read_bvh
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.pipeline import Options, open_session, parse_weights, readings_at_rate, reconstruct
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.options import Weights


@pytest.fixture(scope="module")
def kb():
    return generate_knowledge_base(seed=2, minutes=0.5)


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb, BuildOptions(layout=load_layout("kelly6"), progress=False))
    return g


@pytest.fixture(scope="module")
def rec(kb):
    """Noise-free recording of a knowledge-base clip with positions and heading."""
    return simulate_recording(kb[1], load_layout("kelly6"), NOISE["none"], seed=0)


def test_noise_free_clip_comes_back_as_itself(graph, rec):
    # (the graph stores the clip's readings in float16: the same bits in, zero cost out)
    rec = replace(rec, accelerations=rec.accelerations.astype(READING_DTYPE).astype(np.float32))
    r = reconstruct(graph, rec, Options(weights=Weights(0.5, 1, 1)))
    first = graph.clips[1]["first_node"]
    np.testing.assert_array_equal(r.node_path, first + np.arange(rec.num_samples))
    assert r.motion.num_frames == rec.num_samples
    assert r.report["node_path"] == r.node_path.tolist()
    assert r.report["terms"]["acc_g2"] < 1e-9 and r.report["compression"] > 1


def test_layout_mismatch_names_the_sensors(graph, kb):
    other = simulate_recording(kb[1], load_layout("wrists-ankles"), NOISE["none"])
    with pytest.raises(InputError, match="missing .*(back|chest)"):
        reconstruct(graph, other, Options())


def test_other_rates_are_resampled_to_the_graph_rate(graph, kb, rec):
    fast = simulate_recording(kb[1], load_layout("kelly6"), NOISE["none"], rate_hz=60.0)
    r = reconstruct(graph, fast, Options(weights=Weights(1, 0, 0)))
    assert r.report["resampled"] and r.report["input_rate_hz"] == 60.0
    assert abs(r.motion.num_frames - rec.num_samples) <= 1
    # The 30 Hz grid falls on every other 60 Hz sample: those values, untouched.
    acc, position, heading, resampled = readings_at_rate(fast, 30.0)
    assert resampled and acc.shape[0] == r.motion.num_frames
    np.testing.assert_allclose(acc, fast.accelerations[::2][: acc.shape[0]], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(position, fast.ground_position[::2][: acc.shape[0]], atol=1e-12)
    # 15 Hz → 30 Hz: half-way values, headings the short way round (3.1 → −3.1 via π).
    slow = replace(
        fast,
        rate_hz=15.0,
        timestamps_s=np.array([0.0, 1 / 15]),
        accelerations=fast.accelerations[:2],
        ground_position=np.array([[0.0, 0.0], [1.0, np.nan]]),
        heading=np.array([3.1, -3.1]),
    )
    acc, position, heading, _ = readings_at_rate(slow, 30.0)
    np.testing.assert_allclose(acc[1], fast.accelerations[:2].astype(float).mean(axis=0), rtol=1e-6)
    assert position[1, 0] == pytest.approx(0.5) and np.isnan(position[1, 1])  # a gap stays a gap
    assert abs(heading[1]) == pytest.approx(np.pi)


def test_bad_options_and_constraints(graph, rec):
    with pytest.raises(InputError, match="strategy 'ssg' needs markers, and the recording has none"):
        reconstruct(graph, rec, Options(strategy="ssg"))
    with pytest.raises(InputError, match="unknown strategy"):
        reconstruct(graph, rec, Options(strategy="magic"))
    with pytest.raises(InputError, match="weights"):
        parse_weights("1,2")
    with pytest.raises(InputError, match="weights"):
        parse_weights("1,-1,0")
    with pytest.raises(InputError, match="overlap"):
        reconstruct(
            graph,
            rec,
            Options(
                constraints=(
                    [
                        {"start_s": 0, "end_s": 2, "require": {"contact": "left"}},
                        {"start_s": 1, "end_s": 3, "require": {"contact": "both"}},
                    ],
                )
            ),
        )
    with pytest.raises(InputError, match="start_s"):
        reconstruct(graph, rec, Options(constraints=([{"start_s": -1, "end_s": 2, "require": {"contact": "left"}}],)))
    with pytest.raises(InputError, match="unknown label"):
        reconstruct(graph, rec, Options(constraints=([{"start_s": 0, "end_s": 2, "require": {"label": "swim"}}],)))
    duration = rec.num_samples / rec.rate_hz
    with pytest.raises(InputError, match="starts after the recording ends"):
        reconstruct(
            graph,
            rec,
            Options(
                constraints=([{"start_s": duration + 50, "end_s": duration + 60, "require": {"contact": "left"}}],)
            ),
        )
    with pytest.raises(InputError, match="all 0"):
        parse_weights("0,0,0")
    with pytest.raises(InputError, match="all 0"):
        reconstruct(graph, rec, Options(weights=Weights(0, 0, 0, 0)))
    assert parse_weights("0,0,0,1") == Weights(0, 0, 0, 1)
    with pytest.raises(InputError, match="ground positions"):
        reconstruct(graph, replace(rec, ground_position=None), Options(heading_from_track=True))
    empty = replace(
        rec, timestamps_s=np.zeros(0), accelerations=np.zeros((0, 6, 3), np.float32), ground_position=None, heading=None
    )
    with pytest.raises(InputError, match="zero samples"):
        reconstruct(graph, empty, Options())


def test_heading_from_track_replaces_the_heading(graph, rec):
    r = reconstruct(graph, replace(rec, heading=None), Options(heading_from_track=True, rest_heading_deg=90))
    assert r.report["heading_source"] == "track"


@pytest.mark.parametrize("drift", [0.0, 0.3], ids=["constant-offset", "fused"])
def test_live_session_equals_batch_with_the_same_lag(graph, rec, drift):
    opts = Options(weights=Weights(0.5, 1, 1), latency_s=0.5, track_drift=drift)
    # A tracker offset the path cannot follow by itself, speeding up: fused, the root
    # follows it; with a drift of 0 the offset's rate cannot change.
    rec = replace(
        rec, ground_position=rec.ground_position + np.linspace(0, 1, rec.num_samples)[:, None] ** 2 * [0.6, 0]
    )
    batch = reconstruct(graph, rec, opts)
    live = open_session(graph, opts, rec.sensor_names)
    frames = []
    for k in range(rec.num_samples):
        frames += live.push(float(rec.timestamps_s[k]), rec.accelerations[k], rec.ground_position[k], rec.heading[k])
        # Frames come out in order, each at most the announced lag after its sample.
        assert not frames or frames[-1].index >= k - live.lag_frames
    frames += live.flush()
    assert [f.index for f in frames] == list(range(rec.num_samples))
    assert [f.node for f in frames] == batch.node_path.tolist()
    np.testing.assert_array_equal(live.motion().rotations, batch.motion.rotations)
    np.testing.assert_array_equal(live.motion().translations, batch.motion.translations)
    if drift:
        constant = reconstruct(graph, rec, replace(opts, shared=replace(opts.shared, track_drift=0.0)))
        gap = [
            np.linalg.norm(m.translations[-20:, 0, [0, 2]] - rec.ground_position[-20:], axis=1).mean()
            for m in (batch.motion, constant.motion)
        ]
        assert gap[0] < 0.6 * gap[1], gap


def test_a_live_session_keeping_no_motion_emits_the_same_frames(graph, rec):
    opts = Options(weights=Weights(0.5, 1, 1), latency_s=0.5)
    sessions = [open_session(graph, opts, rec.sensor_names, keep_motion=keep) for keep in (True, False)]
    frames = [[], []]
    for k in range(rec.num_samples):
        sample = float(rec.timestamps_s[k]), rec.accelerations[k], rec.ground_position[k], rec.heading[k]
        for session, out in zip(sessions, frames):
            out += session.push(*sample)
    for session, out in zip(sessions, frames):
        out += session.flush()
    assert len(frames[0]) == rec.num_samples
    for kept, lean in zip(*frames):
        assert (kept.index, kept.node, kept.label) == (lean.index, lean.node, lean.label)
        np.testing.assert_array_equal(kept.rotations, lean.rotations)
        np.testing.assert_array_equal(kept.translations, lean.translations)
    with pytest.raises(InputError, match="keep_motion"):
        sessions[1].motion()


def test_paths_start_where_the_track_starts_when_its_first_samples_lack_it(graph, rec):
    # The tracker's first samples are missing (and the track is far from the origin):
    # batch and live reconstructions both start where the track first reports, and agree.
    position = rec.ground_position + np.array([30.0, 20.0])
    position[:3] = np.nan
    heading = rec.heading.copy()
    heading[:2] = np.nan
    gappy = replace(rec, ground_position=position, heading=heading)
    for weights in (Weights(0.5, 1, 1), Weights(1, 0, 0)):  # with the track searched, and only placing the output
        opts = Options(weights=weights, latency_s=0.5)
        batch = reconstruct(graph, gappy, opts)
        live = open_session(graph, opts, rec.sensor_names)
        frames = []
        for k in range(rec.num_samples):
            frames += live.push(float(rec.timestamps_s[k]), rec.accelerations[k], position[k], heading[k])
        frames += live.flush()
        assert [f.node for f in frames] == batch.node_path.tolist()
        np.testing.assert_array_equal(live.motion().translations, batch.motion.translations)
        # The root at frame 3 stands where the track first reports (within the root's own
        # offset from the ground point, a few cm), not 36 m away at the origin.
        root = batch.motion.translations[3, 0]
        assert np.hypot(root[0] - position[3, 0], root[2] - position[3, 1]) < 0.3


def test_live_session_with_a_long_lag_equals_the_whole_input_search(graph, rec):
    whole = reconstruct(graph, rec, Options(weights=Weights(0.5, 1, 1)))
    live = open_session(graph, Options(weights=Weights(0.5, 1, 1), latency_s=1000.0), rec.sensor_names)
    frames = []
    for k in range(rec.num_samples):
        # Before the lag, a frame comes out only once every surviving path agrees on it
        # (the converged prefix), which a connected graph reaches on exact input.
        new = live.push(float(rec.timestamps_s[k]), rec.accelerations[k], rec.ground_position[k], rec.heading[k])
        assert all(f.index < k + 1 for f in new)
        frames += new
    frames += live.flush()
    assert [f.index for f in frames] == list(range(rec.num_samples))
    assert [f.node for f in frames] == whole.node_path.tolist()
    # Same path, synthesized in overlapping stretches instead of at once.
    np.testing.assert_allclose(live.motion().translations, whole.motion.translations, atol=1e-6)


def test_live_session_rejects_bad_samples(graph, rec):
    live = open_session(graph, Options(), rec.sensor_names)
    live.push(0.0, rec.accelerations[0])
    with pytest.raises(InputError, match="increase"):
        live.push(0.0, rec.accelerations[1])
    with pytest.raises(InputError, match="finite"):
        live.push(float("nan"), rec.accelerations[1])
    with pytest.raises(InputError, match=r"\(6, 3\)"):
        live.push(0.1, rec.accelerations[1][:3])
    with pytest.raises(InputError, match="infinite"):
        live.push(0.1, np.full((6, 3), np.inf))
    with pytest.raises(InputError, match="layout"):
        open_session(graph, Options(), ("a", "b"))


def test_live_session_resamples_irregular_timestamps(graph, rec):
    live = open_session(graph, Options(latency_s=0.2), rec.sensor_names)
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.01, 0.05, 200))  # 20–100 Hz jitter
    frames = []
    for k in range(len(t)):
        frames += live.push(float(t[k]), rec.accelerations[k % rec.num_samples])
    frames += live.flush()
    assert [f.index for f in frames] == list(range(len(frames)))
    assert len(frames) == int(np.floor((t[-1] - t[0]) * graph.rate_hz + 1e-6)) + 1
    assert np.allclose([f.time_s for f in frames], t[0] + np.arange(len(frames)) / graph.rate_hz)


def test_cli_synthesize(graph, rec, tmp_path, capsys):
    gpath, rpath = tmp_path / "g.graph", tmp_path / "r.rec"
    save_graph(graph, gpath)
    save_recording(rec, rpath)
    out, report = tmp_path / "out.bvh", tmp_path / "report.json"
    assert (
        main(["synthesize", str(gpath), str(rpath), "-o", str(out), "--weights", "0.5,1,1", "--report", str(report)])
        == 0
    )
    motion = read_bvh(out)
    assert motion.num_frames == rec.num_samples
    r = json.loads(report.read_text())
    assert len(r["node_path"]) == rec.num_samples and {"acc_g2", "position_m", "heading_rad"} <= set(r["terms"])
    assert {"search", "synthesis"} <= set(r["timings_s"]) and r["compression"] > 1
    assert "wrote" in capsys.readouterr().out
    # Bad input: one line, exit 2, nothing written.
    bad = tmp_path / "bad.bvh"
    assert main(["synthesize", str(gpath), str(rpath), "-o", str(bad), "--weights", "x"]) == 2
    cfile = tmp_path / "c.json"
    cfile.write_text('[[{"start_s": 1, "end_s": 0.5, "require": {"contact": "left"}}]]')
    assert main(["synthesize", str(gpath), str(rpath), "-o", str(bad), "--constraints", str(cfile)]) == 2
    assert main(["synthesize", str(gpath), str(rpath), "-o", str(bad), "--strategy", "ssg"]) == 2
    cfile.write_text('[[{"start_s": 0.5, "end_s": 1, "require": {"contact": "left"}}]]')
    assert main(["synthesize", str(gpath), str(rpath), "-o", str(bad), "--constraints", str(cfile), "--beam", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("graphsvc: error:") for line in err)
    assert "constraint sets" in err[-1]
    assert not bad.exists()
    # With a beam: the report names it.
    assert (
        main(
            [
                "synthesize",
                str(gpath),
                str(rpath),
                "-o",
                str(out),
                "--weights",
                "0.5,1,1",
                "--beam",
                "2",
                "--report",
                str(report),
            ]
        )
        == 0
    )
    assert json.loads(report.read_text())["options"]["beam"] == 2.0


def test_cli_synthesize_writes_glTF_with_the_bvh_s_motion(graph, rec, tmp_path, capsys):
    """`-o OUT.glb` / `.gltf`: the same reconstruction as `-o OUT.bvh`, its joints where
    the BVH's are (within 0.1 mm), the report naming it; a file the validator accepts."""
    from graphsvc.motion.kinematics import motion_fk
    from tests.motion.test_gltf import TOLERANCE_M, gltf_positions, validate

    gpath, rpath = tmp_path / "g.graph", tmp_path / "r.rec"
    save_graph(graph, gpath)
    save_recording(rec, rpath)
    args = ["--strategy", "nearest", "--report"]
    assert (
        main(["synthesize", str(gpath), str(rpath), "-o", str(tmp_path / "o.bvh"), *args, str(tmp_path / "b.json")])
        == 0
    )
    _, want = motion_fk(read_bvh(tmp_path / "o.bvh"))
    for name in ("o.glb", "o.gltf"):
        out = tmp_path / name
        assert main(["synthesize", str(gpath), str(rpath), "-o", str(out), *args, str(tmp_path / "r.json")]) == 0
        assert f"wrote {out}" in capsys.readouterr().out
        assert json.loads((tmp_path / "r.json").read_text())["files"]["output"] == str(out.resolve())
        _, got = gltf_positions(out, graph.rate_hz, want.shape[0])
        assert np.abs(got - want).max() < TOLERANCE_M
    # `graphsvc report` reads the glTF output back (motion.gltf_read) as it reads a BVH.
    assert main(["report", str(tmp_path / "r.json"), "-o", str(tmp_path / "page.html")]) == 0
    assert (tmp_path / "page.html").stat().st_size > 0
    assert all(r["errors"] == 0 for r in validate([tmp_path / "o.glb", tmp_path / "o.gltf"]))


def test_reconstruct_warms_up_the_search_once_per_graph_and_thread_mode(graph, rec, monkeypatch):
    # The first reconstruction on a graph (in each thread mode) runs the search's
    # warm-up — numba compiles or loads the kernels — and times it apart from the
    # search; later ones skip it. The results do not depend on it.
    import copy

    from graphsvc.strategies.viterbi import batch

    runs = []
    warm = batch._warm_up
    monkeypatch.setattr(batch, "_warm_up", lambda g, threads: (runs.append(threads), warm(g, threads)))
    fresh = copy.copy(graph)
    options = Options(weights=Weights(0.5, 1, 1))
    first = reconstruct(fresh, rec, options, threads=False).report
    assert runs == [False] and first["timings_s"]["warm_up"] > 0
    again = reconstruct(fresh, rec, options, threads=False).report
    assert runs == [False]  # (not run again for this graph and mode)
    threaded = reconstruct(fresh, rec, options, threads=True).report
    assert runs == [False, True] and threaded["timings_s"]["warm_up"] > 0
    assert first["node_path"] == again["node_path"] == threaded["node_path"]


def test_a_graph_in_other_sensor_frames_is_refused_and_relayout_converts_it(graph, rec, tmp_path, capsys):
    """A graph built before anatomical sensor frames (no params["sensor_frames"]) and a
    recording simulated now: refused, never compared axis by axis; `relayout` turns
    the old graph's readings into anatomical ones, which match the built graph's."""
    assert graph.params["sensor_frames"] == "anatomical" and rec.meta["sensor_frames"] == "anatomical"
    old = replace(graph, params={k: v for k, v in graph.params.items() if k != "sensor_frames"})
    with pytest.raises(InputError, match="anatomical sensor frames, the graph's in rest-pose"):
        reconstruct(old, rec, Options())
    save_graph(old, tmp_path / "old.graph")
    save_recording(rec, tmp_path / "r.rec")
    assert (
        main(["synthesize", str(tmp_path / "old.graph"), str(tmp_path / "r.rec"), "-o", str(tmp_path / "o.bvh")]) == 2
    )
    assert "relayout" in capsys.readouterr().err
    assert main(["relayout", str(tmp_path / "old.graph"), "--layout", "kelly6", "-o", str(tmp_path / "new.graph")]) == 0
    from graphsvc.graph.file import load_graph

    new = load_graph(tmp_path / "new.graph")
    assert new.params["sensor_frames"] == "anatomical"
    np.testing.assert_allclose(new.edge_acc, graph.edge_acc, atol=0.08)  # (packed poses, as test_build)
    assert (
        main(["synthesize", str(tmp_path / "new.graph"), str(tmp_path / "r.rec"), "-o", str(tmp_path / "o.bvh")]) == 0
    )


def test_the_poses_filter_steadies_the_output_and_zero_turns_it_off(graph, rec):
    from graphsvc.evaluate.metrics import motion_plausibility
    from graphsvc.synthesis.smooth import smooth_poses

    raw = reconstruct(graph, rec, Options(smooth_s=0.0))
    default = reconstruct(graph, rec, Options())
    assert default.node_path.tolist() == raw.node_path.tolist()  # (the same path, its poses filtered)
    rot, trans = smooth_poses(raw.motion.rotations, raw.motion.translations, graph.rate_hz / 30.0)
    np.testing.assert_array_equal(default.motion.rotations, rot)
    np.testing.assert_array_equal(default.motion.translations, trans)
    jitter = [motion_plausibility(r.motion)["jitter_km_s3"] for r in (default, raw)]
    assert jitter[0] < 0.8 * jitter[1], jitter
