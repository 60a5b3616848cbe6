"""The piecewise strategy (graphsvc/strategies/piecewise/): its model reproduces the
knowledge base it learned, learns nothing of a hidden clip, picks its clusters by BIC;
live against batch; its cache; bad options."""

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import InputError
from graphsvc.evaluate.loo import EvalSetup, evaluate_clip
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.holdout import performance_clips
from graphsvc.pipeline import Options, open_session, reconstruct
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies import get
from graphsvc.strategies.base import prepared_index
from graphsvc.strategies.index import index_path
from graphsvc.strategies.piecewise import PiecewiseOptions
from graphsvc.strategies.piecewise.model import Model, learn, training_rows
from graphsvc.strategies.piecewise.strategy import learned_model
from tests.graph.test_connectivity import mixed_kb

LAYOUT = PRESETS["kelly6"]


@pytest.fixture(scope="module")
def kb():
    return mixed_kb(5)  # walking, running, standing, punching: two clips each


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb, BuildOptions(layout=LAYOUT, progress=False))
    return g


def _rec(graph, motion, noise="none", seed=0):
    return simulate_recording(motion, LAYOUT, NOISE[noise], seed=seed, rate_hz=graph.rate_hz)


def test_the_model_gives_back_the_poses_it_learned(graph):
    """At a learned frame's own readings its cluster's map returns that frame's reduced
    pose: not exactly, the weights are a ridge-regularised least-squares fit (RIDGE)
    over centres whose Gaussian kernel matrix is near singular. Measured here, within
    0.02 of reduced-pose units whose spread over the knowledge base is ~0.5."""
    data = prepared_index(get("piecewise"), graph)
    own = PiecewiseOptions(dims=12, clusters="4")
    arrays = learned_model(graph, data, own)
    rows = training_rows(data, None)
    readings = np.asarray(data["readings"], np.float64)
    m = Model(arrays, readings[rows])
    poses = np.asarray(data["poses"], np.float64)
    truth = (poses - m.mean) @ m.components.T  # (the PCA's own projection: orthonormal components)
    picks = rows[::37]
    got = np.array([m.rbf(m.cluster(readings[i]), readings[i])[0][: m.d] for i in picks])
    err = np.linalg.norm(got - truth[picks], axis=1)
    assert np.median(err) < 0.02, np.median(err)
    assert np.std(truth[picks, 0]) > 0.2
    # The cluster a reading is given is mostly the one its frame was learned in.
    assert m.K == 4 and arrays["centres"].shape[0] == arrays["centre_nodes"].size


def test_the_optimised_pose_is_the_minimum_of_xies_objective(graph):
    """Model.optimise's linear solve against scipy's minimiser of eq. 6.2–6.4 written
    out term by term, with the cluster's prior and readings model taken from the
    mixture's arrays directly. Without the smoothness term and with ω_c = 1 it is the
    mixture component's own conditional mean E[r | c]."""
    from scipy.optimize import minimize

    data = prepared_index(get("piecewise"), graph)
    arrays = learned_model(graph, data, PiecewiseOptions(dims=6, clusters="3"))
    m = Model(arrays, np.asarray(data["readings"])[training_rows(data, None)], 0.2, 0.8)
    d = m.d
    rng = np.random.default_rng(3)
    c = np.asarray(data["readings"], np.float64)[100] + 0.05 * rng.standard_normal(m.read_mean.shape[1])
    k = m.cluster(c)
    mu, cov = arrays["mix_means"][k], arrays["mix_covariances"][k]
    prior = np.linalg.inv(cov[:d, :d])
    G = cov[d:, :d] @ prior
    spread = np.linalg.inv(cov[d:, d:] - cov[d:, :d] @ prior @ cov[:d, d:])  # (the readings' about E[c | r])
    r1, r2 = rng.standard_normal(d) * 0.1, rng.standard_normal(d) * 0.1

    def objective(r, smooth):
        miss = mu[d:] + G @ (r - mu[:d]) - c
        e = (r - mu[:d]) @ prior @ (r - mu[:d]) + 0.8 * miss @ spread @ miss
        return e + (0.2 * np.sum((r - 2 * r1 + r2) ** 2) if smooth else 0.0)

    for smooth in (False, True):
        want = minimize(objective, mu[:d], args=(smooth,), method="BFGS", options={"gtol": 1e-10}).x
        got = m.optimise(k, c, r1 if smooth else None, r2 if smooth else None)
        np.testing.assert_allclose(got, want, atol=1e-5)
        assert objective(got, smooth) <= objective(want, smooth) + 1e-9
    posterior = mu[:d] + cov[:d, d:] @ np.linalg.solve(cov[d:, d:], c - mu[d:])
    m1 = Model(arrays, np.asarray(data["readings"])[training_rows(data, None)], 0.2, 1.0)
    np.testing.assert_allclose(m1.optimise(k, c, None, None), posterior, atol=1e-8)
    # With its mean given, the prior is centred there: the same objective about it.
    centre = mu[:d] + 0.1
    want = minimize(
        lambda r: objective(r, False) - (r - mu[:d]) @ prior @ (r - mu[:d]) + (r - centre) @ prior @ (r - centre),
        centre,
        method="BFGS",
        options={"gtol": 1e-10},
    ).x
    np.testing.assert_allclose(m.optimise(k, c, None, None, centre), want, atol=1e-5)


def test_a_sample_takes_the_cluster_of_its_nearest_frame_and_their_weighted_outputs(graph):
    """assign = nearest: the cluster of the training frame with the nearest readings
    (brute force here); method rbf: the normalised Gaussian weights of the cluster's
    LOCAL_NEIGHBOURS frames nearest the readings, σ their median distance, applied to
    their outputs — written out here from the model's stored rows."""
    from graphsvc.strategies.piecewise.model import LOCAL_NEIGHBOURS

    data = prepared_index(get("piecewise"), graph)
    arrays = learned_model(graph, data, PiecewiseOptions(dims=8, clusters="4"))
    rows = training_rows(data, None)
    X = np.asarray(data["readings"], np.float64)[rows]
    m = Model(arrays, X)
    rng = np.random.default_rng(5)
    for i in rng.choice(rows.size, 20, replace=False):
        c = X[i] + 0.1 * rng.standard_normal(X.shape[1])
        dist = np.linalg.norm(X - c, axis=1)
        k = m.cluster(c)
        assert k == arrays["row_labels"][np.argmin(dist)]
        own = np.flatnonzero(arrays["row_labels"] == k)
        near = own[np.argsort(dist[own])[:LOCAL_NEIGHBOURS]]
        w = np.exp(-((dist[near] / np.median(dist[near])) ** 2))
        want = (w / w.sum()) @ np.asarray(arrays["row_outputs"], np.float64)[near]
        got, node = m.local(k, c)
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9)
        assert node == arrays["row_nodes"][near[0]]
    assert Model(arrays, X, assign="mixture").tree is None


@pytest.mark.parametrize("method", ["rbf", "rbf-fit", "optimise"])
def test_a_knowledge_base_clip_is_reconstructed(graph, kb, method):
    """Noise-free readings, positions and heading of knowledge-base clips. Not exact:
    40 of the 97 pose dimensions keep what PCA keeps, the RBF fit is regularised, and
    the pose filter and the root's predicted steps blur it (here 0.9–1.3 cm for rbf);
    the optimisation weighs the readings against its cluster's Gaussian prior, whose
    linear readings model is coarser than the RBF map (1.3–1.4 cm here). With Xie's 7
    dimensions PCA alone costs this mixed knowledge base about 4 cm."""
    bound = {"rbf": 2.0, "rbf-fit": 2.0, "optimise": 2.5}[method]
    for clip in (kb[0], kb[6]):
        options = Options(strategy="piecewise", piecewise=PiecewiseOptions(dims=40, method=method))
        row = evaluate_clip(graph, clip, None, EvalSetup(NOISE["none"], True, options))
        assert row["joint_err_cm"] < bound, (clip.name, row["joint_err_cm"])
        assert row["root_err_cm"] < 10.0, (clip.name, row["root_err_cm"])


def test_lle_reduces_poses_and_gives_them_back_by_their_neighbours_weights(graph, kb):
    """Landmark LLE: a landmark's own embedding comes back near its own pose — not to
    it: the reconstruction weights from its nearest landmarks are regularised (LLE_REG),
    so its neighbours in the embedding share in it, and an embedding may fold poses
    apart onto each other (median largest quaternion component error 0.033 here); and
    a knowledge-base clip from noise-free readings, punching (0.3–0.6 cm here with 7 or
    20 dimensions)."""
    data = prepared_index(get("piecewise"), graph)
    arrays = learned_model(graph, data, PiecewiseOptions(reduce="lle", dims=7, clusters="4"))
    assert "pca_mean" not in arrays and arrays["lle_embedding"].shape == (arrays["lle_poses"].shape[0], 7)
    m = Model(arrays, np.asarray(data["readings"])[training_rows(data, None)])
    picks = np.arange(0, arrays["lle_poses"].shape[0], 97)
    back = np.array([m.pose(arrays["lle_embedding"][i]) for i in picks])
    err = np.abs(back - arrays["lle_poses"][picks]).max(axis=1)
    assert np.median(err) < 0.05, np.median(err)
    options = Options(strategy="piecewise", piecewise=PiecewiseOptions(reduce="lle", dims=7))
    row = evaluate_clip(graph, kb[6], None, EvalSetup(NOISE["none"], True, options))
    assert row["joint_err_cm"] < 1.5, row["joint_err_cm"]


def test_a_hidden_clip_is_left_out_of_the_learning(graph, kb):
    """A model learned with the last performance hidden is the model learned on a
    knowledge base without it: the same arrays."""
    strategy = get("piecewise")
    allowed = strategy.allowed_mask(graph, [len(graph.clips) - 1])
    hidden = {graph.clips[int(c)]["name"] for c in performance_clips(graph, len(graph.clips) - 1)}
    assert hidden and len(hidden) < len(kb)
    smaller, _ = build_graph([m for m in kb if m.name not in hidden], BuildOptions(layout=LAYOUT, progress=False))
    for own in (PiecewiseOptions(), PiecewiseOptions(reduce="lle", clusters="3")):
        with_mask = learned_model(graph, prepared_index(strategy, graph), own, allowed)
        without = learned_model(smaller, prepared_index(strategy, smaller), own)
        everything = learned_model(graph, prepared_index(strategy, graph), own)
        assert set(with_mask) == set(without)
        for k in with_mask:
            np.testing.assert_array_equal(with_mask[k], without[k], err_msg=k)
        assert with_mask["centres"].shape != everything["centres"].shape  # (the hidden frames did count before)


def test_bic_picks_more_clusters_for_two_actions_than_for_one(kb):
    walk, _ = build_graph(kb[0:2], BuildOptions(layout=LAYOUT, progress=False))
    both, _ = build_graph(kb[0:2] + kb[6:8], BuildOptions(layout=LAYOUT, progress=False))
    counts = []
    for g in (walk, both):
        data = get("piecewise").prepare(g)
        counts.append(learn(data, training_rows(data, None), PiecewiseOptions())["mix_weights"].size)
    assert counts[1] > counts[0], counts


@pytest.mark.parametrize("method", ["rbf", "rbf-fit", "optimise"])
def test_live_equals_batch_frame_for_frame(graph, kb, method):
    rec = _rec(graph, kb[2], "default", seed=4)
    options = Options(strategy="piecewise", piecewise=PiecewiseOptions(method=method), latency_s=0.5)
    batch = reconstruct(graph, rec, options)  # (with a latency: what a live client gets)
    whole = reconstruct(graph, rec, Options(strategy="piecewise", piecewise=PiecewiseOptions(method=method)))
    assert np.abs(whole.motion.translations[:, 0] - batch.motion.translations[:, 0]).max() > 1e-3  # smoothed
    live = open_session(graph, options, rec.sensor_names)
    assert live.lag_frames == 0
    for t in range(rec.num_samples):
        out = live.push(float(rec.timestamps_s[t]), rec.accelerations[t], rec.ground_position[t], rec.heading[t])
        assert len(out) == 1 and out[0].index == t
    assert live.flush() == []
    m = live.motion()
    np.testing.assert_allclose(m.rotations, batch.motion.rotations, atol=1e-6)  # (float32 frames)
    np.testing.assert_allclose(m.translations, batch.motion.translations, atol=1e-6)
    assert batch.report["piecewise"]["method"] == method and batch.node_path is None


def test_a_missing_sensor_repeats_the_previous_frame(graph, kb):
    rec = _rec(graph, kb[1])
    acc = rec.accelerations.copy()
    acc[0, 1] = np.nan
    acc[10, 2] = np.nan
    from dataclasses import replace

    r = reconstruct(graph, replace(rec, accelerations=acc), Options(strategy="piecewise", latency_s=0.5))
    assert r.report["incomplete_samples"] == 2 and np.all(np.isfinite(r.motion.rotations))
    np.testing.assert_allclose(r.motion.rotations[10, 1:], r.motion.rotations[9, 1:], atol=1e-12)


def test_models_are_cached_beside_the_graph_one_per_hold_out(graph, tmp_path):
    path = tmp_path / "kb.graph"
    save_graph(graph, path)
    g = load_graph(path)
    strategy = get("piecewise")
    data = prepared_index(strategy, g)
    assert index_path(path, "piecewise").is_file()
    own = PiecewiseOptions(dims=10, clusters="3")
    a = learned_model(g, data, own)
    b = learned_model(g, data, own, strategy.allowed_mask(g, [0]))
    files = sorted(p.name for p in tmp_path.glob("kb.graph.piecewise-*.index"))
    assert len(files) == 2
    again = learned_model(load_graph(path), get("piecewise").prepare(load_graph(path)), own)  # read back
    for k in a:
        np.testing.assert_array_equal(again[k], a[k])
    assert not np.asarray(again["centres"]).flags.writeable and b["centres"].shape != a["centres"].shape


@pytest.mark.parametrize(
    "own, message",
    [
        (PiecewiseOptions(dims=97), "must be below the pose dimension"),
        (PiecewiseOptions(clusters="100000"), "clusters must be a whole number"),
        (PiecewiseOptions(clusters="2000"), "exceeds the knowledge base's"),
        (PiecewiseOptions(clusters="two"), "clusters must be a whole number"),
        (PiecewiseOptions(width=float("inf")), "width must be a finite width"),
        (PiecewiseOptions(width=0.0), "width must be"),
    ],
)
def test_bad_options_are_refused(graph, kb, own, message):
    with pytest.raises(InputError, match=message):
        reconstruct(graph, _rec(graph, kb[0].slice(0, 20)), Options(strategy="piecewise", piecewise=own))


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
                "piecewise",
                "--piecewise-method",
                "optimise",
                "--piecewise-dims",
                "9",
                "--piecewise-clusters",
                "3",
                "--piecewise-width",
                "1.5",
                "-o",
                str(out),
            ]
        )
        == 0
    )
    assert out.is_file()
    for bad, message in (
        (["--piecewise-dims", "97"], "below the pose dimension"),
        (["--piecewise-clusters", "2000"], "exceeds the knowledge base's"),
        (["--piecewise-width", "nan"], "width"),
        (["--piecewise-reduce", "tsne"], "reduce"),
    ):
        capsys.readouterr()
        try:
            code = main(["synthesize", str(g), str(r), "--strategy", "piecewise", *bad, "-o", str(out)])
        except SystemExit as e:
            code = e.code
        assert code == 2
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, err
