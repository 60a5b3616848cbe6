"""The sensor-orientation term C_R of the Viterbi search: yaw-free, chosen by it where
the accelerations cannot tell paths apart, and equal in every place it is computed."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.graph.model import graph_from_edges
from graphsvc.motion import quat
from graphsvc.strategies.options import Weights, parse_weights
from graphsvc.strategies.viterbi.batch import viterbi_search
from graphsvc.strategies.viterbi.reference import reference_viterbi
from graphsvc.strategies.viterbi.search import ViterbiSearch

UPRIGHT = np.array([0.0, 1.0, 0.0])


def tilted(deg):
    """World +Y seen by a sensor tilted by deg about its x axis."""
    return quat.rotate(quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(-deg)), UPRIGHT)


def two_paths(S=2):
    """Node 0 forks into two self-looping chains, 1 and 2, whose edges read the same
    accelerations; chain 1's sensors are upright, chain 2's tilted by 40°."""
    src, dst = [0, 0, 1, 2], [1, 2, 1, 2]
    acc = np.tile([0.0, 9.81, 0.0], (4, S, 1))
    up = np.stack([np.tile(u, (S, 1)) for u in (UPRIGHT, tilted(40), UPRIGHT, tilted(40))])
    return graph_from_edges(np.array(src), np.array(dst), acc, up=up)


@pytest.mark.parametrize("chain", (1, 2))
def test_measured_orientations_pick_the_path_whose_sensors_they_match(chain):
    g = two_paths()
    T = 12
    acc = np.tile([0.0, 9.81, 0.0], (T, 2, 1)) + np.random.default_rng(0).normal(0, 0.05, (T, 2, 3))
    want = UPRIGHT if chain == 1 else tilted(40)
    up = np.broadcast_to(want, (T, 2, 3)).copy()
    up[3, 1] = np.nan  # a missing orientation: the mean over the sensors present
    r = viterbi_search(g, acc, weights=Weights(1, 0, 0, 1.0), up=up)
    assert set(r.node_path[1:].tolist()) == {chain}
    assert r.terms["orientation_chord2"] == pytest.approx(0.0, abs=1e-6)
    # the other chain costs its chord² a sample more: 2 − 2·cos 40° per sensor present
    other = 3 - chain
    ref_path, ref_cost = reference_viterbi(g, acc, weights=Weights(1, 0, 0, 1.0), up=up)
    np.testing.assert_array_equal(ref_path, r.node_path)
    assert r.cost == pytest.approx(ref_cost, rel=1e-6)
    forced = viterbi_search(
        g, acc, weights=Weights(1, 0, 0, 1.0), up=up, allowed=np.array([True, other == 1, other == 2])
    )
    assert forced.terms["orientation_chord2"] == pytest.approx((T - 1) * (2 - 2 * np.cos(np.radians(40))), rel=1e-3)
    # with W_R = 0 the two chains tie: the costs are equal, either may be taken
    tie = viterbi_search(g, acc, weights=Weights(1, 0, 0, 0.0), up=up)
    tied = viterbi_search(
        g, acc, weights=Weights(1, 0, 0, 0.0), up=up, allowed=np.array([True, other == 1, other == 2])
    )
    assert tie.cost == tied.cost
    assert "orientation_chord2" not in tie.terms


def test_the_term_is_yaw_free_and_chord_squared():
    g = two_paths(S=1)
    T = 6
    acc = np.tile([0.0, 9.81, 0.0], (T, 1, 1))
    base = viterbi_search(
        g, acc, weights=Weights(0, 0, 0, 2.0), up=np.tile(tilted(25), (T, 1, 1)), allowed=np.array([True, True, False])
    )
    # C_R of an upright chain against a 25° tilt: 2 − 2 cos 25° a sample, weighted by W_R (W_A = 0)
    assert base.cost == pytest.approx(2.0 * (T - 1) * (2 - 2 * np.cos(np.radians(25))), rel=1e-5)
    # a device's yaw drift turns its reported orientation about the world vertical
    # (q → R_y(δ)·q): its "up", and so the input and the cost, do not change
    from graphsvc.sensors.orientation import sensor_up

    q0 = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.radians(-25))
    drifted = quat.mul(quat.about_y(np.linspace(0.0, 1.5, T)), np.broadcast_to(q0, (T, 4)))
    up = sensor_up(drifted)[:, None]
    again = viterbi_search(g, acc, weights=Weights(0, 0, 0, 2.0), up=up, allowed=np.array([True, True, False]))
    assert again.cost == pytest.approx(base.cost, rel=1e-6)


def test_search_refuses_an_oriented_search_without_metadata_or_weight():
    g = two_paths()
    g.edge_up = None
    with pytest.raises(InputError, match="orientation metadata"):
        ViterbiSearch(g, Weights(1, 0, 0, 1.0), oriented=True)
    with pytest.raises(InputError, match="orientation weight"):
        ViterbiSearch(two_paths(), Weights(1, 0, 0, 0.0), oriented=True)
    # batch: without metadata the term is simply off (the report lists orientations as ignored)
    r = viterbi_search(
        g, np.tile([0.0, 9.81, 0.0], (4, 2, 1)), weights=Weights(1, 0, 0, 1.0), up=np.tile(UPRIGHT, (4, 2, 1))
    )
    assert "orientation_chord2" not in r.terms


def test_batch_reading_costs_equal_the_per_sample_kernel_with_orientations():
    from tests.search.problems import random_graph, random_up

    rng = np.random.default_rng(8)
    g = random_graph(rng, N=200, out=4, S=3)
    g.edge_up = random_up(rng, g.edge_acc.shape)
    acc = rng.normal(0, 9.81, (21, 3, 3))
    up = random_up(rng, acc.shape)
    acc[:6][rng.random((6, 3)) < 0.3] = np.nan
    up[5:12][rng.random((7, 3)) < 0.4] = np.nan
    acc[14] = np.nan  # no accelerometer: the orientations alone
    for w in (Weights(1, 0, 0, 2.0), Weights(0, 0, 0, 1.0)):
        s = ViterbiSearch(g, w, oriented=True)
        assert s.readings_t.shape[0] == 18
        batch = s.reading_costs(acc, up=up)
        for t in range(21):
            s._set_measurement(acc[t], up[t])
            expected = np.zeros_like(s.reading_cost)
            if s._scale:
                s._kernels[0](s.readings_t, s._meas, s._mask, s._scale, expected)
            np.testing.assert_array_equal(batch[t], expected)
            # …and against W_A·C_A + W_R·C_R computed directly, over each distinct reading
            r = s.readings_t.T.astype(np.float64)
            a = (acc[t].astype(np.float32).astype(np.float64) / 9.81).astype(np.float32).reshape(-1)
            va = np.repeat(np.isfinite(acc[t]).all(axis=1), 3)
            vr = np.repeat(np.isfinite(up[t]).all(axis=1), 3)
            u = up[t].astype(np.float32).reshape(-1)
            ca = np.sum((r[:, :9][:, va] - a[va]) ** 2, axis=1) / max(va.sum() / 3, 1)
            cr = np.sum((r[:, 9:][:, vr] - u[vr]) ** 2, axis=1) / max(vr.sum() / 3, 1)
            direct = (w.acc * ca + w.orientation * cr) / s.w_reading
            np.testing.assert_allclose(batch[t], direct, rtol=2e-5, atol=1e-6)


def test_weights_take_an_optional_orientation_weight():
    assert parse_weights("0.5,1,1") == Weights(0.5, 1, 1)
    assert parse_weights("0.5,1,1,3") == Weights(0.5, 1, 1, 3.0)
    for bad in ("1,1", "1,1,1,1,1", "1,1,1,-1", "1,1,1,nan"):
        with pytest.raises(InputError):
            parse_weights(bad)


def _build(layout: str):
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.motion.procedural import generate_knowledge_base
    from graphsvc.sensors.layout import PRESETS

    kb = generate_knowledge_base(seed=5, minutes=0.4)
    g, _ = build_graph(kb, BuildOptions(interp=False, progress=False, layout=PRESETS[layout]))
    return kb, g


@pytest.fixture(scope="module")
def built():
    return _build("wrists-ankles")


@pytest.fixture(scope="module")
def built6():
    """kelly6: a root sensor (lower_back), so the cue is the rotations relative to it."""
    return _build("kelly6")


def relative_two_paths(S=3):
    """As `two_paths` with the cue relative to a root sensor (width 9): chain 2's sensor
    1 is turned 40° about the vertical relative to the root, which no tilt shows."""
    from graphsvc.sensors.orientation import relative_orientations

    src, dst = [0, 0, 1, 2], [1, 2, 1, 2]
    acc = np.tile([0.0, 9.81, 0.0], (4, S, 1))
    q = np.tile([1.0, 0.0, 0.0, 0.0], (4, S, 1))
    q[[1, 3], 1] = quat.about_y(np.radians(np.array([40.0, 40.0])))
    g = graph_from_edges(np.array(src), np.array(dst), acc, up=relative_orientations(q, 0))
    return g, q


@pytest.mark.parametrize("chain", (1, 2))
def test_orientations_relative_to_the_root_pick_the_path_whose_sensors_turned_as_measured(chain):
    from graphsvc.sensors.orientation import relative_orientations, sensor_up

    g, q = relative_two_paths()
    assert g.edge_up.shape[-1] == 9
    np.testing.assert_allclose(sensor_up(q[1]), sensor_up(q[2]), atol=1e-12)  # (the tilt cannot tell them apart)
    T = 10
    acc = np.tile([0.0, 9.81, 0.0], (T, 3, 1)) + np.random.default_rng(1).normal(0, 0.05, (T, 3, 3))
    measured = np.broadcast_to(q[chain - 1], (T, 3, 4)).copy()  # (edge 0 → 1 is upright, 0 → 2 turned)
    heading = quat.about_y(np.linspace(0.0, 2.0, T))[:, None]  # the whole body turns: nothing relative changes
    up = relative_orientations(quat.mul(heading, measured), 0)
    w = Weights(1, 0, 0, 1.0)
    r = viterbi_search(g, acc, weights=w, up=up)
    assert set(r.node_path[1:].tolist()) == {chain}
    ref_path, ref_cost = reference_viterbi(g, acc, weights=w, up=up)
    np.testing.assert_array_equal(ref_path, r.node_path)
    assert r.cost == pytest.approx(ref_cost, rel=1e-6)
    forced = viterbi_search(g, acc, weights=w, up=up, allowed=np.array([True, chain == 2, chain == 1]))
    # one sensor of three off by 40°: the mean chord² is (2 − 2·cos 40°) / 3 a sample
    assert forced.terms["orientation_chord2"] == pytest.approx((T - 1) * (2 - 2 * np.cos(np.radians(40))) / 3, rel=2e-3)


def test_old_graph_files_search_as_before_and_list_orientations_ignored(built, tmp_path):
    from dataclasses import replace

    from graphsvc.graph.file import load_graph, save_graph
    from graphsvc.pipeline import Options, reconstruct
    from graphsvc.sensors.layout import layout_from_dict
    from graphsvc.sensors.noise import PRESETS as NOISE
    from graphsvc.sensors.simulate import simulate_recording

    kb, g = built
    rec = simulate_recording(kb[2], layout_from_dict(g.layout), NOISE["real"], seed=4, rate_hz=g.rate_hz)
    assert rec.orientations is not None
    save_graph(replace(g, edge_up=None), tmp_path / "old.graph")
    old = load_graph(tmp_path / "old.graph")
    options = Options(weights=Weights(0.5, 1, 1, 1.0))
    before = reconstruct(old, rec, options)
    assert before.report["ignored_inputs"] == ["orientations"]
    plain = reconstruct(g, replace(rec, orientations=None), options)  # (no orientations: as before)
    np.testing.assert_array_equal(before.node_path, plain.node_path)
    assert before.report["cost"] == plain.report["cost"]
    assert "orientation_chord2" not in plain.report["terms"]
    # the same graph with its metadata weighs them, and its terms add up to the cost
    on = reconstruct(g, rec, options)
    assert "ignored_inputs" not in on.report
    t = on.report["terms"]
    assert t["orientation_chord2"] > 0
    assert (0.5 * t["acc_g2"] + t["position_m"] + t["heading_rad"] + t["orientation_chord2"]) == pytest.approx(
        on.report["cost"], rel=1e-6
    )
    # W_R = 0: the orientations count for nothing, bit for bit
    zero = reconstruct(g, rec, Options(weights=Weights(0.5, 1, 1, 0.0)))
    np.testing.assert_array_equal(zero.node_path, plain.node_path)
    assert zero.report["cost"] == plain.report["cost"]


def test_a_beam_of_inf_and_a_fixed_lag_decoder_weigh_orientations_as_the_exact_search():
    from graphsvc.strategies.viterbi.stream import FixedLagDecoder
    from tests.search.problems import random_up, random_walk_problem

    g, meas, position, heading = random_walk_problem(4, T=60)
    rng = np.random.default_rng(9)
    g.edge_up = random_up(rng, g.edge_acc.shape)
    up = random_up(rng, meas.shape)
    up[rng.random(up.shape[:2]) < 0.1] = np.nan
    w = Weights(0.5, 1, 1, 2.0)
    exact = viterbi_search(g, meas, position, heading, w, up=up)
    beam = viterbi_search(g, meas, position, heading, w, up=up, beam=np.inf)
    np.testing.assert_array_equal(beam.node_path, exact.node_path)
    assert beam.cost == exact.cost
    plain = viterbi_search(g, meas, position, heading, Weights(0.5, 1, 1, 0.0), up=up)
    assert not np.array_equal(plain.node_path, exact.node_path)  # (the term changed the path)
    # a fixed-lag decoder whose lag spans the input emits the batch search's path
    decoder = FixedLagDecoder(g, w, lag=len(meas), oriented=True)
    nodes = [decoder.push(meas[t], position[t], heading[t], up[t])[0] for t in range(len(meas))]
    nodes.append(decoder.flush()[0])
    np.testing.assert_array_equal(np.concatenate(nodes), exact.node_path)


def test_the_sliding_window_decoder_weighs_orientations_as_a_fresh_search_over_each_window():
    from graphsvc.strategies.viterbi.stream import SlidingWindowDecoder
    from tests.search.problems import random_up, random_walk_problem

    g, meas, position, heading = random_walk_problem(5, T=30)
    rng = np.random.default_rng(3)
    g.edge_up = random_up(rng, g.edge_acc.shape)
    up = random_up(rng, meas.shape)
    w = Weights(0.5, 1, 1, 2.0)
    window, lag = 8, 2
    emitted, differs = [], False
    for oriented in (True, False):
        decoder = SlidingWindowDecoder(
            g, w if oriented else Weights(0.5, 1, 1, 0.0), window=window, lag=lag, oriented=oriented
        )
        out = []
        for t in range(len(meas)):
            out.extend(decoder.push(meas[t], position[t], heading[t], up[t] if oriented else None)[0].tolist())
            if oriented and t >= lag:
                lo = max(0, t - window + 1)
                fresh = viterbi_search(
                    g, meas[lo : t + 1], position[lo : t + 1], heading[lo : t + 1], w, up=up[lo : t + 1]
                ).node_path
                assert out[t - lag] == fresh[t - lag - lo]
        out.extend(decoder.flush()[0].tolist())
        differs = differs or (emitted and out != emitted)
        emitted = out
    assert differs  # (the orientation term changed what was emitted)


@pytest.mark.parametrize(
    "strategy,layout",
    [
        ("viterbi", "wrists-ankles"),
        ("olng", "wrists-ankles"),
        ("viterbi", "kelly6"),
        ("olng", "kelly6"),
        ("nearest", "kelly6"),
    ],
)
def test_a_live_session_given_orientations_equals_the_batch_reconstruction(built, built6, strategy, layout):
    from dataclasses import replace

    from graphsvc.pipeline import Options, open_session, reconstruct
    from graphsvc.sensors.layout import layout_from_dict
    from graphsvc.sensors.noise import PRESETS as NOISE
    from graphsvc.sensors.simulate import simulate_recording

    kb, g = built if layout == "wrists-ankles" else built6
    assert g.edge_up.shape[-1] == (3 if layout == "wrists-ankles" else 9)
    rec = simulate_recording(kb[2], layout_from_dict(g.layout), NOISE["real"], seed=6, rate_hz=g.rate_hz)
    # (a latency asks OLNG's batch for what a live client gets: the poses not filtered over later frames)
    opts = Options(strategy=strategy, weights=Weights(0.5, 1, 1, 1.0), latency_s=0.5)
    batch = reconstruct(g, rec, opts)
    plain = reconstruct(g, replace(rec, orientations=None), opts)
    assert not np.array_equal(batch.motion.rotations, plain.motion.rotations)  # (they changed the result)
    for orientations, want in ((True, batch), (False, plain)):  # a session not told of them ignores them
        live = open_session(g, opts, rec.sensor_names, orientations=orientations)
        frames = []
        for k in range(rec.num_samples):
            frames += live.push(
                float(rec.timestamps_s[k]),
                rec.accelerations[k],
                rec.ground_position[k],
                rec.heading[k],
                orientations=rec.orientations[k],
            )
        frames += live.flush()
        assert [f.index for f in frames] == list(range(rec.num_samples))
        np.testing.assert_allclose(live.motion().rotations, want.motion.rotations, atol=1e-6)
    with pytest.raises(InputError, match="orientations must be"):
        open_session(g, opts, rec.sensor_names, orientations=True).push(
            0.0, rec.accelerations[0], orientations=np.ones((1, 4))
        )
