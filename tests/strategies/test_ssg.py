"""The SSG strategy (graphsvc/strategies/ssg/): a performance in the knowledge base comes
back as a copy of itself whatever the sparsity, gaps and flicker leave the output
continuous, live equals batch at the same lag, real markers' offsets are fitted, and
bad input is refused with one line."""

import json
from dataclasses import replace

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import InputError, LayoutError
from graphsvc.evaluate.loo import _global_signals
from graphsvc.evaluate.metrics import evaluate_frames
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import save_graph
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base, generate_performance
from graphsvc.pipeline import Options, open_session, reconstruct
from graphsvc.sensors.markers import PRESETS as MARKERS
from graphsvc.sensors.markers import MarkerSet
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import MarkerPattern, simulate_marker_recording
from graphsvc.strategies.ssg.options import SsgOptions


@pytest.fixture(scope="module")
def kb():
    return generate_knowledge_base(seed=3, minutes=0.6)


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb, BuildOptions(msv=False, interp=False, bridges=False, progress=False))
    return g


def _score(graph, truth, result):
    tc, tg, th = _global_signals(motion_fk(truth)[1], joint_map(truth.skeleton))
    pc, pg, ph = _global_signals(motion_fk(result.motion)[1], joint_map(graph.skeleton))
    return evaluate_frames(pc, tc, pg, ph, tg, th, pred_labels=result.provenance.label, true_label="x", name="t")


def _max_step(motion):
    pos = motion_fk(motion)[1]
    return float(np.linalg.norm(np.diff(pos, axis=0), axis=-1).max())


@pytest.mark.parametrize(
    "markers, pattern, clips",
    [
        ("hands-feet", MarkerPattern(), "all"),
        ("head-back", MarkerPattern(), "all"),
        ("left-foot", MarkerPattern(), "locomotion"),
        ("hands-feet", MarkerPattern(gaps=((20, 40), (100, 12)), flicker=0.2), "longest"),
        ("head-back", MarkerPattern(gaps=((50, 80),), flicker=0.3), "longest"),
    ],
)
def test_a_performance_in_the_knowledge_base_comes_back_as_a_copy(graph, kb, markers, pattern, clips):
    """Tautges 2012, §4.4: 'if the original motion was included in the knowledge base, the
    synthesized motion would always be an identical copy of it, no matter how sparse'.
    One foot marker tells nothing while the foot stands (it matches every stance of
    every clip equally): that holds while it moves, on the locomotion clips."""
    chosen = {
        "all": kb,
        "longest": [max(kb, key=lambda m: m.num_frames)],
        "locomotion": [m for m in kb if m.labels[0] in ("walk", "run")],
    }[clips]
    assert chosen
    for clip in chosen:
        rec = simulate_marker_recording(clip, markers, NOISE["none"], seed=1, pattern=pattern)
        result = reconstruct(graph, rec, Options(strategy="ssg"))
        row = _score(graph, clip, result)
        assert row["joint_err_cm"] < 0.5 and row["root_err_cm"] < 0.5, clip.name
        assert result.motion.num_frames == clip.num_frames
        assert result.report["ssg"]["offsets"]["mode"] == "nominal"  # (simulated: the set's own offsets)
        if pattern.gaps:
            assert result.report["blind_windows"] > 0 and result.report["nodes"]["forward"] > 0


@pytest.fixture(scope="module")
def performance():
    motion, _ = generate_performance(seed=11, seconds=14.0)
    return motion


@pytest.mark.parametrize("gaps", [((10, 5),), ((30, 80),), ((5, 20), (60, 7), (120, 45), (200, 80))])
def test_gaps_and_changing_marker_sets_leave_the_output_continuous(graph, performance, gaps):
    """Gaps of 5 to 80 frames and, between them, markers flickering so that the set seen
    changes every few frames: a whole motion, no joint moving between frames more than
    1.5 times the truth's largest step and 2 cm."""
    rec = simulate_marker_recording(
        performance, "hands-feet", NOISE["default"], seed=3, pattern=MarkerPattern(gaps=gaps, flicker=0.3)
    )
    seen = np.isfinite(rec.marker_positions[..., 0])
    changes = np.flatnonzero((seen[1:] != seen[:-1]).any(axis=1))
    assert np.median(np.diff(changes)) <= 3  # (the set seen changes every few frames)
    result = reconstruct(graph, rec, Options(strategy="ssg"))
    assert result.motion.num_frames == performance.num_frames
    assert np.isfinite(result.motion.rotations).all() and np.isfinite(result.motion.translations).all()
    assert _max_step(result.motion) <= 1.5 * _max_step(performance) + 0.02
    assert _score(graph, performance, result)["joint_err_cm"] < 10.0


def test_live_equals_batch_at_the_same_lag(graph, performance):
    rec = simulate_marker_recording(
        performance.slice(0, 200),
        "hands-feet",
        NOISE["default"],
        seed=5,
        pattern=MarkerPattern(gaps=((40, 30),), flicker=0.1),
    )
    options = Options(strategy="ssg", latency_s=0.8, ssg=SsgOptions(markers="hands-feet"))
    batch = reconstruct(graph, rec, options)
    session = open_session(graph, options, marker_names=rec.marker_names)
    frames, released = [], []
    for t in range(rec.num_samples):
        got = session.push(float(rec.timestamps_s[t]), markers=rec.marker_positions[t])
        frames += got
        released += [t] * len(got)
    frames += session.flush()
    live = session.motion()
    np.testing.assert_array_equal(live.rotations, batch.motion.rotations)
    np.testing.assert_array_equal(live.translations, batch.motion.translations)
    assert [f.index for f in frames] == list(range(rec.num_samples))
    # Each frame out within the session's lag of its sample.
    assert max(t - f.index for f, t in zip(frames, released)) <= session.lag_frames
    assert frames[10].sources and abs(sum(w for _, _, w in frames[10].sources) - 1.0) < 1e-9
    # The whole-input path is at least as cheap as the lagged one.
    whole = reconstruct(graph, rec, replace(options, latency_s=None))
    assert whole.report["cost"] <= batch.report["cost"] + 1e-12


def test_offsets_of_real_markers_are_fitted(graph, kb):
    """Markers 6 cm off the set's nominal spots (the skin, not the bone): fitted from the
    input, they come back within 1.5 cm, and the reconstruction is a copy again."""
    clip = max(kb, key=lambda m: m.num_frames)
    shift = {
        "l_hand": (0.0, 0.06, 0.0),
        "r_hand": (0.0, 0.0, 0.06),
        "l_foot": (0.06, 0.0, 0.0),
        "r_foot": (-0.04, 0.04, 0.0),
    }
    worn = MarkerSet(
        "worn",
        tuple(replace(m, offset_m=tuple(np.add(m.offset_m, shift[m.name]))) for m in MARKERS["hands-feet"].markers),
    )
    rec = simulate_marker_recording(clip, worn, NOISE["none"], seed=2)
    rec = replace(rec, meta={"source": "a capture"})  # (not simulated: offsets are fitted by default)
    options = Options(strategy="ssg", ssg=SsgOptions(markers="hands-feet"))
    nominal = reconstruct(graph, rec, replace(options, ssg=replace(options.ssg, offsets="nominal")))
    fitted = reconstruct(graph, rec, options)
    offsets = fitted.report["ssg"]["offsets"]
    assert offsets["mode"] == "fit"
    for name, d in shift.items():
        assert offsets["moved_cm"][name] == pytest.approx(100 * np.linalg.norm(d), abs=1.5)
    assert _score(graph, clip, fitted)["joint_err_cm"] < 0.5
    assert _score(graph, clip, fitted)["joint_err_cm"] <= _score(graph, clip, nominal)["joint_err_cm"]
    # The fitted set reads back as a marker set, and with it the nominal reconstruction is a copy.
    again = reconstruct(
        graph,
        rec,
        replace(options, ssg=SsgOptions(markers=json.dumps(offsets["fitted_marker_set"]), offsets="nominal")),
    )
    assert _score(graph, clip, again)["joint_err_cm"] < 0.5


def test_windows_options_and_the_report(graph, kb):
    clip = kb[0]
    rec = simulate_marker_recording(clip, "head-back", NOISE["none"], seed=0)
    r = reconstruct(graph, rec, Options(strategy="ssg"))
    s = r.report["ssg"]
    assert (s["window_frames"], s["overlap_frames"], s["k"], s["weight"]) == (
        8,
        3,
        16,
        4.0,
    )  # head and trunk: 0.25, 0.1 s
    r = reconstruct(graph, rec, Options(strategy="ssg", ssg=SsgOptions(window_s=0.5, overlap_s=0.2, k=3, weight=2.0)))
    s = r.report["ssg"]
    assert (s["window_frames"], s["overlap_frames"], s["k"], s["weight"]) == (15, 6, 3, 2.0)
    assert r.report["nodes"]["retrieved"] <= 2 * 3 * r.report["windows"]  # (k best, and the previous k going on)
    assert r.report["labels"] and r.report["path"][0]["start_frame"] == 0
    assert sum(p["frames"] for p in r.report["path"]) >= clip.num_frames
    assert r.node_path is None and r.provenance.clip.shape == (clip.num_frames, 2)
    # Weight 0: node costs alone (the structural non-edges stay non-edges).
    gappy = simulate_marker_recording(clip, "hands-feet", NOISE["none"], pattern=MarkerPattern(gaps=((10, 40),)))
    r = reconstruct(graph, gappy, Options(strategy="ssg", ssg=SsgOptions(weight=0.0)))
    assert np.isfinite(r.report["cost"]) and np.isfinite(r.motion.rotations).all()
    assert r.report["terms"]["transition_m2"] >= 0 and r.report["blind_windows"] > 0


def test_markers_the_set_does_not_define_are_ignored_and_kept_ones_chosen(graph, kb):
    clip = kb[1]
    rec = simulate_marker_recording(clip, "vicon", NOISE["none"], seed=0, keep=("LFHD", "LTOE", "RTOE", "LWRA"))
    rec = replace(rec, marker_names=("LFHD", "LTOE", "RTOE", "mystery"), meta={"simulated": True})
    r = reconstruct(graph, rec, Options(strategy="ssg", ssg=SsgOptions(markers="vicon", keep=("LTOE", "RTOE", "RWRA"))))
    assert r.report["ssg"]["markers"] == ["LTOE", "RTOE"]
    assert r.report["ignored_markers"] == ["LFHD", "mystery"] and r.report["missing_markers"] == ["RWRA"]


def test_bad_input_is_refused(graph, kb):
    clip = kb[0].slice(0, 60)
    rec = simulate_marker_recording(clip, "hands-feet", NOISE["none"], seed=0)
    with pytest.raises(InputError, match="every kept marker .* is missing for the whole input"):
        reconstruct(
            graph, replace(rec, marker_positions=np.full_like(rec.marker_positions, np.nan)), Options(strategy="ssg")
        )
    with pytest.raises(InputError, match="needs a marker set"):
        reconstruct(graph, replace(rec, meta={}), Options(strategy="ssg"))
    with pytest.raises(InputError, match="none of the markers of set 'head-back'"):
        reconstruct(graph, rec, Options(strategy="ssg", ssg=SsgOptions(markers="head-back")))
    with pytest.raises(InputError, match="defines no marker nose"):
        reconstruct(graph, rec, Options(strategy="ssg", ssg=SsgOptions(keep=("nose",))))
    with pytest.raises(LayoutError, match="unknown marker set"):
        reconstruct(graph, rec, Options(strategy="ssg", ssg=SsgOptions(markers="elbows")))
    with pytest.raises(LayoutError, match="segment must be a canonical joint"):
        reconstruct(
            graph,
            rec,
            Options(
                strategy="ssg",
                ssg=SsgOptions(markers=json.dumps({"name": "x", "markers": [{"name": "l_hand", "segment": "l_paw"}]})),
            ),
        )
    for bad, needle in (
        (SsgOptions(window_s=0.2, overlap_s=0.15), "at most half"),
        (SsgOptions(k=0), "SSG k"),
        (SsgOptions(weight=-1.0), "weight"),
        (SsgOptions(offsets="guess"), "offsets"),
    ):
        with pytest.raises(InputError, match=needle):
            reconstruct(graph, rec, Options(strategy="ssg", ssg=bad))
    with pytest.raises(InputError, match="offsets 'fit' needs the whole input"):
        open_session(
            graph,
            Options(strategy="ssg", ssg=SsgOptions(markers="hands-feet", offsets="fit")),
            marker_names=rec.marker_names,
        )


def test_cli_simulate_and_synthesize_markers(graph, kb, tmp_path, capsys):
    gpath, clip_path = tmp_path / "g.graph", tmp_path / "clip.bvh"
    save_graph(graph, gpath)
    from graphsvc.motion.bvh import write_bvh

    write_bvh(clip_path, kb[2])
    rec = tmp_path / "m.csv"
    assert (
        main(
            [
                "simulate",
                str(clip_path),
                "--markers",
                "vicon",
                "--keep",
                "LFHD,RFHD,LWRA,RWRA,LTOE,RTOE",
                "--gaps",
                "10:20",
                "--flicker",
                "0.1",
                "--noise",
                "default,marker=2",
                "-o",
                str(rec),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "6 markers" in out and "marker noise 2 mm" in out
    assert rec.read_text().startswith("# graphsvc markers v1")
    bvh, report = tmp_path / "o.bvh", tmp_path / "r.json"
    assert (
        main(
            [
                "synthesize",
                str(gpath),
                str(rec),
                "--strategy",
                "ssg",
                "--markers",
                "vicon",
                "--ssg-offsets",
                "nominal",
                "-o",
                str(bvh),
                "--report",
                str(report),
            ]
        )
        == 0
    )
    r = json.loads(report.read_text())
    assert r["strategy"] == "ssg" and r["ssg"]["markers"] == ["LFHD", "RFHD", "LWRA", "RWRA", "LTOE", "RTOE"]
    assert bvh.is_file()
    capsys.readouterr()
    for argv, needle in (
        (["simulate", str(clip_path), "-o", str(tmp_path / "x.rec")], "--layout (accelerometers) or --markers"),
        (
            ["simulate", str(clip_path), "--markers", "hands-feet", "--gaps", "10-20", "-o", str(tmp_path / "x.rec")],
            "START:LEN",
        ),
        (
            ["simulate", str(clip_path), "--markers", "hands-feet", "--flicker", "1.2", "-o", str(tmp_path / "x.rec")],
            "flicker",
        ),
        (
            ["simulate", str(clip_path), "--layout", "kelly6", "--gaps", "1:2", "-o", str(tmp_path / "x.rec")],
            "apply to --markers",
        ),
        (
            [
                "synthesize",
                str(gpath),
                str(rec),
                "--strategy",
                "ssg",
                "--markers",
                "vicon",
                "--keep",
                "LELB",
                "-o",
                str(tmp_path / "y.bvh"),
            ],
            "none of the markers",
        ),
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "x.rec").exists() and not (tmp_path / "y.bvh").exists()
    # A ragged marker CSV: its line named.
    ragged = tmp_path / "ragged.csv"
    ragged.write_text("time,a_x,a_y,a_z\n0,1,2,3\n0.1,1,2\n")
    assert (
        main(
            [
                "synthesize",
                str(gpath),
                str(ragged),
                "--strategy",
                "ssg",
                "--markers",
                "hands-feet",
                "-o",
                str(tmp_path / "y.bvh"),
            ]
        )
        == 2
    )
    assert "ragged.csv:3: expected 4 columns, got 3" in capsys.readouterr().err
    native = tmp_path / "m.rec"
    save_recording(simulate_marker_recording(kb[2], "left-foot", NOISE["none"]), native)
    assert main(["synthesize", str(gpath), str(native), "--strategy", "ssg", "-o", str(tmp_path / "z.bvh")]) == 0


def test_a_live_session_holds_constant_memory_and_the_frames_of_one_that_keeps_everything():
    """Ten minutes of two markers (one-second windows: 750 of them) through a live
    session: what its decoder holds stops growing after the first minute, while a
    decoder that keeps every layer grows with the input; and over the first two
    minutes (with ten prunings) the two sessions give the same frames, bit for bit."""
    kb = generate_knowledge_base(seed=3, minutes=0.15)
    graph, _ = build_graph(kb, BuildOptions(msv=False, interp=False, bridges=False, progress=False))
    motion, _ = generate_performance(seed=11, seconds=20.0)
    rec = simulate_marker_recording(
        motion, "hands-feet", NOISE["default"], seed=3, pattern=MarkerPattern(gaps=((100, 25),), flicker=0.1)
    )
    options = Options(
        strategy="ssg",
        latency_s=1.0,
        ssg=SsgOptions(markers="hands-feet", keep=("l_hand", "r_foot"), window_s=1.0, overlap_s=0.2),
    )
    pruned = open_session(graph, options, marker_names=rec.marker_names, keep_motion=False)
    whole = open_session(graph, options, marker_names=rec.marker_names, keep_motion=False)
    whole.decoder.prune = False
    assert pruned.decoder.prune
    n, rate = rec.num_samples, graph.rate_hz
    minute = int(60 * rate)
    held, grown = [], []
    for t in range(10 * minute):
        m = rec.marker_positions[t % n]  # (the recording looped: its track jumps back every 20 s)
        a = pruned.push(t / rate, markers=m)
        if t < 2 * minute:
            b = whole.push(t / rate, markers=m)
            assert [f.index for f in a] == [f.index for f in b]
            for f, g in zip(a, b):
                np.testing.assert_array_equal(f.rotations, g.rotations)
                np.testing.assert_array_equal(f.translations, g.translations)
                assert f.sources == g.sources
        if t % (minute // 6) == 0:  # every 10 s
            held.append(pruned.decoder.retained_bytes)
            if t < 2 * minute:
                grown.append(whole.decoder.retained_bytes)
    assert pruned.decoder.layers.base > 0 and pruned.decoder.base > 0  # (it did prune)
    assert max(held[12:]) <= 1.25 * max(held[6:12])  # flat after the first minute
    assert grown[-1] > 3 * grown[2]  # (what is measured does grow without pruning)
    assert len(pruned.flush()) > 0
