"""Where a reconstruction starts: estimated from the first second's measurements, the
heading from the direction of travel when none is measured, and never moved again by
the evaluation once the track has placed it."""

import math
from dataclasses import replace

import numpy as np
import pytest

from graphsvc.evaluate.loo import EvalSetup, evaluate_clip
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion import quat, signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.motion.skeleton import Motion
from graphsvc.pipeline import Options, open_session, reconstruct
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.options import Weights
from graphsvc.strategies.start import START_TRAVEL_M, start_placement, start_samples

RATE = 30.0


def test_the_start_is_the_line_fitted_to_the_first_second():
    t = np.arange(90.0)
    track = np.stack([1.0 + 0.03 * t, 2.0 - 0.04 * t], axis=1)  # 1.5 m/s along (0.6, −0.8)
    p0, h0 = start_placement(track, None, RATE)
    np.testing.assert_allclose(p0, [1.0, 2.0], atol=1e-9)
    assert h0 == pytest.approx(math.atan2(0.6, -0.8), abs=1e-9)  # facing the direction of travel
    # A heading measured wins over the track's; its fit unwraps across ±π.
    heading = np.pi - 0.1 + 0.01 * t
    heading = heading - 2 * np.pi * (heading > np.pi)
    assert start_placement(track, heading, RATE)[1] == pytest.approx(np.pi - 0.1, abs=1e-9)
    # Only the first second is read; gaps are skipped; fewer than three: the first measured.
    late = track.copy()
    late[start_samples(RATE) :] += 50.0
    late[:5] = np.nan
    np.testing.assert_allclose(start_placement(late, None, RATE)[0], [1.0, 2.0], atol=1e-9)
    few = np.full_like(track, np.nan)
    few[[7, 12]] = track[[7, 12]]
    np.testing.assert_array_equal(start_placement(few, None, RATE)[0], track[7])
    assert start_placement(few, None, RATE)[1] is None  # (no line: no direction of travel)
    assert start_placement(np.full_like(track, np.nan), None, RATE) == (None, None)


def test_a_standing_track_says_nothing_of_the_facing():
    t = np.arange(30.0)
    drift = (START_TRAVEL_M * 0.8 / 29) * t  # 0.24 m over the window
    p0, h0 = start_placement(np.stack([drift, np.zeros(30)], axis=1), None, RATE)
    assert h0 is None and p0 is not None


def test_the_fitted_start_carries_less_tracker_noise_than_the_first_sample():
    # Independent check over many noisy tracks: the fit's error against the first
    # sample's (σ 10 cm, 10°); a straight-line fit over n samples has about 2 / √n of
    # one sample's error at its end.
    first, fitted, first_h, fitted_h = [], [], [], []
    t = np.arange(30.0)
    for seed in range(200):
        rng = np.random.default_rng(seed)
        true = np.stack([0.04 * t, 0.02 * t], axis=1)
        noisy = true + rng.normal(0, 0.1, true.shape)
        heading = 0.3 + 0.002 * t + rng.normal(0, math.radians(10), 30)
        p0, h0 = start_placement(noisy, heading, RATE)
        first.append(np.hypot(*noisy[0]))
        fitted.append(np.hypot(*p0))
        first_h.append(abs(heading[0] - 0.3))
        fitted_h.append(abs(h0 - 0.3))
    assert np.mean(fitted) < 0.5 * np.mean(first)
    assert np.mean(fitted_h) < 0.5 * np.mean(first_h)


@pytest.fixture(scope="module")
def kb():
    return generate_knowledge_base(seed=2, minutes=1.0)  # (the first with a walk)


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb, BuildOptions(layout=load_layout("kelly6"), progress=False))
    return g


def _turned(motion, angle: float):
    """The motion turned by `angle` about +Y through the origin (root rotation and
    translation), as a performer facing another way would perform it."""
    r, t = motion.rotations.copy(), motion.translations.copy()
    r[:, 0] = quat.mul(quat.about_y(np.full(r.shape[0], angle)), r[:, 0])
    c, s = math.cos(angle), math.sin(angle)
    x, z = t[:, 0, 0].copy(), t[:, 0, 2].copy()
    t[:, 0, 0], t[:, 0, 2] = c * x + s * z, -s * x + c * z
    return replace(motion, rotations=r, translations=t)


def _walk_facing_away(kb):
    """A walking clip of the knowledge base turned to face about 180° from +Z."""
    walk = next(m for m in kb if m.labels and m.labels[0] == "walk")
    table = joint_map(walk.skeleton)
    h = signals.heading(motion_fk(walk)[1], table)[0]
    return _turned(walk, math.pi - h), table


def _track(motion, table):
    world = motion_fk(motion)[1]
    return signals.ground_position(world, table["pelvis"]), signals.heading(world, table)


def test_positions_without_heading_start_facing_the_direction_of_travel(graph, kb):
    walk, table = _walk_facing_away(kb)
    rec = simulate_recording(walk, load_layout("kelly6"), NOISE["none"], seed=0)
    rec = replace(rec, heading=None)
    true_ground, true_heading = _track(walk, table)
    assert abs(abs(true_heading[0]) - math.pi) < 0.05
    for options in (Options(weights=Weights(0.5, 1, 1)), Options(weights=Weights(0.5, 1, 1), latency_s=1.0)):
        r = reconstruct(graph, rec, options)
        ground, heading = _track(r.motion, joint_map(graph.skeleton))
        start_error = abs((heading[0] - true_heading[0] + math.pi) % (2 * math.pi) - math.pi)
        assert start_error < math.radians(20), math.degrees(start_error)  # (facing +Z: 180° off)
        assert np.hypot(*(ground - true_ground).T).mean() < 0.15
    # Live: the same start, once the first second has arrived.
    session = open_session(graph, Options(weights=Weights(0.5, 1, 1), latency_s=0.5))
    frames = [
        f
        for k in range(rec.num_samples)
        for f in session.push(rec.timestamps_s[k], rec.accelerations[k], rec.ground_position[k])
    ]
    frames += session.flush()
    assert len(frames) == rec.num_samples
    live = Motion(
        graph.skeleton, np.stack([f.rotations for f in frames]), np.stack([f.translations for f in frames]), RATE
    )
    ground, heading = _track(live, joint_map(graph.skeleton))
    assert abs((heading[0] - true_heading[0] + math.pi) % (2 * math.pi) - math.pi) < math.radians(20)
    assert np.hypot(*(ground - true_ground).T).mean() < 0.15


def test_evaluation_never_turns_a_reconstruction_placed_by_the_track(graph, kb):
    walk, _ = _walk_facing_away(kb)
    setup = EvalSetup(
        noise=replace(NOISE["none"], heading="none"), positions=True, options=Options(weights=Weights(0.5, 1, 1))
    )
    row = evaluate_clip(graph, walk, None, setup)
    assert row["start_placed"] == []
    assert row["root_err_cm"] < 15 and row["heading_err_deg"] < 15
    # Without positions either, the evaluation places the start (and says so).
    bare = evaluate_clip(graph, walk, None, replace(setup, positions=False))
    assert bare["start_placed"] == ["position", "heading"]
