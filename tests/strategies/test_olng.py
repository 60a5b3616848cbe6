"""The OLNG strategy (graphsvc/strategies/olng/): the pose energy's gradient, the
weighted PCA, reconstruction of knowledge-base clips at their speed and off it, live
against batch, and bad options."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import minimize

from graphsvc.cli import main
from graphsvc.errors import InputError
from graphsvc.evaluate.loo import EvalSetup, evaluate_clip
from graphsvc.evaluate.metrics import motion_plausibility
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import save_graph
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.motion.resample import resample
from graphsvc.pipeline import Options, open_session, reconstruct
from graphsvc.sensors.layout import layout_from_dict
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.olng.index import load_index
from graphsvc.strategies.olng.options import OlngOptions
from graphsvc.strategies.olng.pose import (
    EnergyTerms,
    energy,
    optimise,
    pose_model,
    pose_positions,
    weighted_pca,
)


@pytest.fixture(scope="module")
def kb():
    return generate_knowledge_base(seed=5, minutes=0.4)


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb, BuildOptions(interp=False, progress=False))
    return g


def _rec(graph, motion, noise="none", seed=0):
    return simulate_recording(motion, layout_from_dict(graph.layout), NOISE[noise], seed=seed, rate_hz=graph.rate_hz)


def test_gradient_matches_finite_differences(graph):
    model = pose_model(graph)
    index = load_index(graph)
    rng = np.random.default_rng(3)
    frames = rng.choice(index.frames, 9, replace=False)
    Q = np.asarray(index.poses[frames], dtype=np.float64)
    w = rng.random(9)
    w /= w.sum()
    mean, basis, _ = weighted_pca(Q, w)
    X = np.asarray(index.positions[frames], dtype=np.float64)
    offsets = np.asarray(graph.skeleton.offsets)[model.active]
    x_t = pose_positions(Q[0], offsets, model)
    S = model.sensor_a.size
    terms = EnergyTerms(
        Q,
        w,
        offsets,
        X + rng.normal(0, 0.02, X.shape),
        rng.normal(0, 3.0, X.shape),
        rng.normal(0, 0.3, (9, S, 3)),
        x_t,
        x_t + 0.01,
        np.array([3.0, 1.0, 0.5, 1.0]),
        30.0,
    )
    for _ in range(3):
        z = rng.normal(0, 0.3, basis.shape[1])
        e, g = energy(z, mean, basis, terms, model)
        h = 1e-6
        fd = np.array(
            [
                (energy(z + h * u, mean, basis, terms, model)[0] - energy(z - h * u, mean, basis, terms, model)[0])
                / (2 * h)
                for u in np.eye(z.size)
            ]
        )
        np.testing.assert_allclose(g, fd, rtol=1e-5, atol=1e-7)
        assert np.isfinite(e) and e > 0


def test_numba_lbfgs_reaches_scipys_minimum(graph):
    """The compiled L-BFGS (`olng.lbfgs`) against scipy's L-BFGS-B on the same energy,
    start and stopping rules, over random neighbourhoods of the procedural knowledge
    base: it takes L-BFGS-B's steps (the same direction without bounds, the same
    Moré-Thuente search), so it stops after the same iterations at the same point, up
    to rounding (1e-9 in z, where the two differ only in the order of floating-point
    sums; 1e-15 to 1e-14 measured)."""
    model = pose_model(graph)
    index = load_index(graph)
    offsets = np.asarray(graph.skeleton.offsets, dtype=np.float64)[model.active]
    S = model.sensor_a.size
    rng = np.random.default_rng(11)
    for _ in range(8):
        I = 16
        frames = np.clip(rng.integers(2, index.frames - 2) + rng.integers(-40, 40, I), 2, index.frames - 1)
        Q = np.asarray(index.poses[frames], dtype=np.float64)
        w = rng.random(I)
        w /= w.sum()
        mean, basis, _ = weighted_pca(Q, w)
        X, X1, X2 = (np.asarray(index.positions[f], dtype=np.float64) for f in (frames, frames - 1, frames - 2))
        x_t = pose_positions(Q[0], offsets, model)
        terms = EnergyTerms(
            Q,
            w,
            offsets,
            x_t[None] + X - X1,
            (X - 2.0 * X1 + X2) * 900.0,
            rng.normal(0, 0.05, (I, S, 3)),
            x_t,
            x_t + 0.01,
            np.array([3.0, 1.0, 1.0, 1.0]),
            30.0,
        )
        start = Q[rng.integers(I)]
        z0 = basis.T @ (start - mean)
        res = minimize(
            energy,
            z0,
            args=(mean, basis, terms, model),
            jac=True,
            method="L-BFGS-B",
            options={"maxiter": 40, "gtol": 1e-7},
        )
        p, e, iterations = optimise(mean, basis, start, terms, model)
        assert iterations == res.nit
        assert e == pytest.approx(res.fun, rel=1e-12)
        np.testing.assert_allclose(basis.T @ (p - mean), res.x, atol=1e-9)
        # And a minimum: no coordinate direction lowers it.
        for u in np.eye(basis.shape[1]) * 1e-4:
            assert energy(basis.T @ (p - mean) + u, mean, basis, terms, model)[0] >= e - 1e-9
    # The iteration limit holds as scipy's maxiter does.
    p, e, iterations = optimise(mean, basis, start, terms, model, max_iterations=2)
    res = minimize(energy, z0, args=(mean, basis, terms, model), jac=True, method="L-BFGS-B", options={"maxiter": 2})
    assert iterations == res.nit == 2 and e == pytest.approx(res.fun, rel=1e-12)


@pytest.mark.parametrize("count", [7, 300])  # fewer poses than dimensions, and more
def test_weighted_pca_keeps_99_percent_of_the_weighted_variance(count):
    rng = np.random.default_rng(count)
    D = 40
    P = rng.normal(size=(count, D)) * np.geomspace(1.0, 1e-3, D)
    w = rng.random(count)
    mean, basis, share = weighted_pca(P, w)
    np.testing.assert_allclose(mean, np.average(P, axis=0, weights=w))
    values = np.sort(np.linalg.eigvalsh(np.cov(P.T, aweights=w, bias=True)))[::-1]
    d = basis.shape[1]
    kept = values[:d].sum() / values.sum()
    assert kept >= 0.99 and values[: d - 1].sum() / values.sum() < 0.99
    assert share == pytest.approx(kept)
    np.testing.assert_allclose(basis.T @ basis, np.eye(d), atol=1e-8)
    # The basis spans the leading directions: the variance it holds is the top d eigenvalues'.
    Y = (P - mean) * np.sqrt(w / w.sum())[:, None]
    assert np.sum((Y @ basis) ** 2) == pytest.approx(values[:d].sum(), rel=1e-8)


def test_a_knowledge_base_clip_is_reconstructed(graph, kb):
    """Noise-free readings, positions and heading, of clips in the knowledge base:
    the neighbourhood blends a few frames, so not exactly (0.1-0.5 cm here)."""
    for clip in (kb[0], kb[1]):
        row = evaluate_clip(graph, clip, None, EvalSetup(NOISE["none"], True, Options(strategy="olng")))
        assert row["joint_err_cm"] < 2.0, (clip.name, row["joint_err_cm"])
        assert row["root_err_cm"] < 10.0, (clip.name, row["root_err_cm"])


def test_speed_changes_are_followed_with_the_extended_steps(graph, kb):
    """The running clip at 0.7 and 1.4 times its speed: the paths stay long (more than
    M / 2 columns on average: 27.0 and 27.7 of 32 here); without the extended steps
    they are shorter (26.0 and 27.68), as in Tautges et al.'s fig. 13."""
    M = 32
    got = {True: [], False: []}
    for speed in (0.7, 1.4):
        m = kb[0]
        played = resample(m, m.rate_hz / speed).copy(rate_hz=m.rate_hz)
        rec = _rec(graph, played)
        for ext in (True, False):
            r = reconstruct(graph, rec, Options(strategy="olng", olng=OlngOptions(k=256, i=16, m=M, extended=ext)))
            got[ext].append(r.report["mean_path_length"])
    assert min(got[True]) > M / 2, got
    assert got[False][0] < got[True][0] and got[False][1] <= got[True][1], got


@pytest.mark.parametrize("fix_feet", [False, True])
def test_live_equals_batch_frame_for_frame(graph, kb, fix_feet):
    rec = _rec(graph, kb[2], "default", seed=4)
    options = Options(strategy="olng", olng=OlngOptions(fix_feet=fix_feet))
    # A batch run with a latency is what a live client gets: the tracker filtered.
    batch = reconstruct(graph, rec, Options(strategy="olng", olng=OlngOptions(fix_feet=fix_feet), latency_s=0.5))
    assert "ignored_options" not in batch.report and batch.report["track"]["smoothed"] is False
    # Without one, the root is smoothed over the whole recording (the poses' filter off
    # here): the same poses, the whole body shifted on the ground, and a steadier root.
    whole = reconstruct(graph, rec, Options(strategy="olng", olng=OlngOptions(fix_feet=fix_feet), smooth_s=0.0))
    assert whole.report["track"]["smoothed"] is True
    np.testing.assert_array_equal(whole.motion.rotations, batch.motion.rotations)
    np.testing.assert_array_equal(whole.motion.translations[:, 1:], batch.motion.translations[:, 1:])
    np.testing.assert_array_equal(whole.motion.translations[:, 0, 1], batch.motion.translations[:, 0, 1])
    shift = whole.motion.translations[:, 0, [0, 2]] - batch.motion.translations[:, 0, [0, 2]]
    assert np.abs(shift).max() > 1e-3
    jerk = [
        np.linalg.norm(np.diff(m.translations[:, 0, [0, 2]], n=3, axis=0), axis=1).mean()
        for m in (whole.motion, batch.motion)
    ]
    assert jerk[0] < jerk[1], jerk
    # With the poses' filter too (the default): every joint steadier.
    filtered = reconstruct(graph, rec, options).motion
    jitter = [motion_plausibility(m)["jitter_km_s3"] for m in (filtered, whole.motion)]
    assert jitter[0] < 0.5 * jitter[1], jitter
    live = open_session(graph, options, rec.sensor_names)
    assert live.lag_frames == 0
    frames = []
    for t in range(rec.num_samples):
        out = live.push(float(rec.timestamps_s[t]), rec.accelerations[t], rec.ground_position[t], rec.heading[t])
        assert len(out) == 1 and out[0].index == t  # each frame as its sample arrives
        frames += out
    assert live.flush() == []
    m = live.motion()
    np.testing.assert_allclose(m.rotations, batch.motion.rotations, atol=1e-6)  # (float32 frames)
    np.testing.assert_allclose(m.translations, batch.motion.translations, atol=1e-6)
    assert [f.label for f in frames] == list(batch.provenance.label)
    assert frames[5].sources == batch.provenance.sources(5)


def test_report_and_a_missing_sensor(graph, kb):
    rec = _rec(graph, kb[1])
    acc = rec.accelerations.copy()
    acc[10, 1] = np.nan
    r = reconstruct(graph, replace(rec, accelerations=acc), Options(strategy="olng"))
    rep = r.report
    assert rep["strategy"] == "olng" and rep["incomplete_samples"] == 1
    assert rep["olng"]["k"] == 16 and rep["olng"]["i"] == 4  # (frames / 150 at least 16; K / 16 at least 4)
    assert len(rep["per_frame"]["path_cost"]) == rec.num_samples == r.motion.num_frames
    assert sum(run["frames"] for run in rep["labels"]) == rec.num_samples
    assert r.node_path is None and r.provenance.clip.shape[0] == rec.num_samples
    np.testing.assert_allclose(r.provenance.weight.sum(axis=1), 1.0)
    assert np.all(np.isfinite(r.motion.rotations))


@pytest.mark.parametrize(
    "olng, message",
    [
        (OlngOptions(k=100_000), "exceeds"),
        (OlngOptions(k=8, i=9), "I must be between 1 and K"),
        (OlngOptions(m=1), "M must be ≥ 2"),
        (OlngOptions(w_pose=float("nan")), "weight pose"),
        (OlngOptions(w_prior=0, w_contr=0), "all zero"),
    ],
)
def test_bad_options_are_refused(graph, kb, olng, message):
    with pytest.raises(InputError, match=message):
        reconstruct(graph, _rec(graph, kb[0].slice(0, 20)), Options(strategy="olng", olng=olng))


def test_cli_options_and_bad_ones(graph, kb, tmp_path, capsys):
    g, r = tmp_path / "g.graph", tmp_path / "r.rec"
    save_graph(graph, g)
    save_recording(_rec(graph, kb[0].slice(0, 30)), r)
    out = tmp_path / "o.bvh"
    assert (
        main(
            [
                "synthesize",
                str(g),
                str(r),
                "--strategy",
                "olng",
                "--olng-k",
                "32",
                "--olng-i",
                "8",
                "--olng-basic-steps",
                "-o",
                str(out),
                "--report",
                str(tmp_path / "rep.json"),
            ]
        )
        == 0
    )
    assert out.is_file()
    for bad, message in (
        (["--olng-m", "1"], "M must be ≥ 2"),
        (["--olng-weights", "5,1,1"], "five numbers"),
        (["--olng-k", "4", "--olng-i", "5"], "I must be between"),
    ):
        capsys.readouterr()
        try:
            code = main(["synthesize", str(g), str(r), "--strategy", "olng", *bad, "-o", str(out)])
        except SystemExit as e:
            code = e.code
        assert code == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err


def test_measured_orientations_join_the_neighbour_query(graph, kb):
    # The oriented tree's features are the readings and √W_R · the sensors' "up": at a
    # large weight a query whose "up" is frame q's finds a frame whose "up" is q's,
    # however far its readings are from the query's.
    index = load_index(graph)
    assert index.up is not None and index.up.shape == index.readings.shape
    p = 5
    far = np.linalg.norm(index.up - index.up[p], axis=1)
    q = int(np.argmax(far))  # the frame whose sensors are tilted most unlike p's
    assert far[q] > 0.5
    plain = index.query(index.readings[p], 4)
    assert plain.frames[0] == p
    weight = 1e4
    nb = index.query(index.readings[p], 4, index.up[q], weight)
    gap = np.linalg.norm(index.readings[q] - index.readings[p])
    assert np.linalg.norm(index.up[nb.frames[0]] - index.up[q]) <= gap / np.sqrt(weight) + 1e-6
    assert nb.frames[0] != p


def test_olng_with_orientations_uses_them_and_without_metadata_lists_them_ignored(graph, kb):
    from graphsvc.strategies.options import Weights

    rec = _rec(graph, kb[1], "real", seed=3)
    assert rec.orientations is not None
    off = reconstruct(graph, rec, Options(strategy="olng", weights=Weights(1, 1, 1, 0.0)))
    on = reconstruct(graph, rec, Options(strategy="olng", weights=Weights(1, 1, 1, 1.0)))
    assert "orientations" not in on.report.get("ignored_inputs", [])
    assert not np.array_equal(on.motion.rotations, off.motion.rotations)
    # a graph file from before orientation metadata: the input is listed ignored, the result is the plain one
    old = replace(graph, edge_up=None)
    plain = reconstruct(old, rec, Options(strategy="olng", weights=Weights(1, 1, 1, 1.0)))
    assert "orientations" in plain.report["ignored_inputs"]
    np.testing.assert_array_equal(plain.motion.rotations, off.motion.rotations)
