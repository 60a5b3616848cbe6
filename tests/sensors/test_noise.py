import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.noise import (
    PRESETS,
    NoiseModel,
    corrupt_accelerations,
    corrupt_positions,
    heading_from_track,
    parse_noise,
)


def test_parse_presets_and_overrides():
    assert parse_noise("none") == NoiseModel()
    d = parse_noise("default")
    assert (d.sigma, d.bias, d.misalign, d.range, d.position) == (0.5, 0.2, 5.0, 12.0, 0.10)
    assert parse_noise("default,drop=0.1").drop == 0.1
    assert parse_noise("sigma=0.3").sigma == 0.3 and parse_noise("sigma=0.3").bias == 0.0
    for bad in ("loud", "sigma=abc", "drop=2", "colour=1", "heading=sideways", ""):
        with pytest.raises(InputError):
            parse_noise(bad)


def test_none_preset_leaves_readings_exact():
    rng = np.random.default_rng(0)
    acc = rng.standard_normal((50, 3, 3)).astype(np.float32)
    np.testing.assert_array_equal(corrupt_accelerations(acc, PRESETS["none"], rng), acc)


def test_noise_statistics_bias_clipping_and_drops():
    T, S = 20000, 2
    acc = np.zeros((T, S, 3), np.float32)
    out = corrupt_accelerations(acc, NoiseModel(sigma=0.5, bias=0.2), np.random.default_rng(1))
    deviation = out - out.mean(axis=0)
    assert np.std(deviation) == pytest.approx(0.5, rel=0.02)
    assert np.all(np.abs(out.mean(axis=0)) <= 0.2 + 0.02)
    big = np.full((10, 1, 3), 30 * GRAVITY, np.float32)
    clipped = corrupt_accelerations(big, NoiseModel(range=12.0), np.random.default_rng(2))
    np.testing.assert_allclose(clipped, 12 * GRAVITY, rtol=1e-6)
    dropped = corrupt_accelerations(acc, NoiseModel(drop=0.1), np.random.default_rng(3))
    frac = np.isnan(dropped[..., 0]).mean()
    assert 0.09 < frac < 0.11
    assert np.array_equal(np.isnan(dropped[..., 0]), np.isnan(dropped[..., 2]))  # a sample is lost whole


def test_misalignment_rotates_about_x_only_and_preserves_norm():
    acc = np.tile(np.array([1.0, 0.0, GRAVITY], np.float32), (5, 4, 1))
    out = corrupt_accelerations(acc, NoiseModel(misalign=10.0), np.random.default_rng(5))
    np.testing.assert_allclose(out[..., 0], 1.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), np.linalg.norm(acc, axis=-1), rtol=1e-6)
    tilt = np.degrees(np.arctan2(np.abs(out[..., 1]), out[..., 2]))
    assert tilt.max() <= 10.0 + 1e-4 and tilt.max() > 0.1


def test_same_seed_same_noise():
    acc = np.zeros((30, 2, 3), np.float32)
    a = corrupt_accelerations(acc, PRESETS["default"], np.random.default_rng(9))
    b = corrupt_accelerations(acc, PRESETS["default"], np.random.default_rng(9))
    assert a.tobytes() == b.tobytes()
    pos = np.zeros((30, 2))
    assert corrupt_positions(pos, PRESETS["default"], np.random.default_rng(9)).std() == pytest.approx(0.1, rel=0.3)


def test_heading_rule_faces_travel_when_fast_else_rest():
    rate = 30.0
    t = np.arange(90) / rate
    pos = np.zeros((90, 2))
    pos[:45, 0] = 3.0 * t[:45]  # running +X at 3 m/s: heading +π/2
    pos[45:, 0] = pos[44, 0]  # then standing still
    h = heading_from_track(pos, rate, speed_threshold=2.0, rest_heading=0.25)
    np.testing.assert_allclose(h[:35], np.pi / 2, atol=1e-6)
    np.testing.assert_allclose(h[60:], 0.25)
    pos[10:20] = np.nan  # tracker dropouts are bridged
    assert np.isfinite(heading_from_track(pos, rate)).all()


def test_tracker_offset_and_wander_leave_the_other_draws_alone():
    from dataclasses import replace

    from graphsvc.sensors.noise import NoiseModel

    T = 600  # 20 s at 30 Hz
    pos = np.zeros((T, 2))
    base = PRESETS["default"]
    plain = corrupt_positions(pos, base, np.random.default_rng(4), 30.0)
    offset = corrupt_positions(pos, replace(base, position_offset=0.137), np.random.default_rng(4), 30.0)
    shift = offset - plain  # the white noise is the same draw: what differs is the offset alone
    np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-12)
    assert np.hypot(*shift[0]) == pytest.approx(0.137)
    # The wander: a random walk of 0.03 m/√s, so after t seconds σ = 0.03·√t per axis.
    walk = np.stack(
        [corrupt_positions(pos, NoiseModel(position_walk=0.03), np.random.default_rng(s), 30.0) for s in range(400)]
    )
    assert walk[:, -1].std() == pytest.approx(0.03 * np.sqrt(T / 30.0), rel=0.1)
    assert walk[:, 29].std() == pytest.approx(0.03 * np.sqrt(1.0), rel=0.1)
    assert PRESETS["tracker"].position_offset == 0.137 and parse_noise("tracker,position_walk=0").position_walk == 0
