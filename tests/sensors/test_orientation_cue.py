"""The orientation cue (`sensors.orientation`): rotations relative to the root sensor's
heading, free of a common yaw and of a common yaw drift, compared as 2 − 2·cos θ."""

import numpy as np
import pytest

from graphsvc.motion import quat
from graphsvc.sensors.layout import PRESETS, root_sensor
from graphsvc.sensors.orientation import (
    heading_twist,
    normalised_rows,
    orientation_cue,
    relative_orientations,
    sensor_up,
)


def _random(rng, shape):
    return quat.normalize(rng.normal(size=shape + (4,)))


def test_the_root_sensor_is_the_one_on_the_pelvis():
    assert root_sensor(PRESETS["kelly6"]) == PRESETS["kelly6"].sensor_names.index("lower_back")
    assert root_sensor(PRESETS["wrists-ankles"]) is None


def test_heading_twist_of_a_tilted_turn_is_the_turn():
    # R_y(a)·R_x(b): the twist about world +Y is R_y(a) (hand-checked: (cos a/2, 0, sin a/2, 0)).
    a, b = 0.7, 0.4
    q = quat.mul(quat.about_y(np.array(a)), quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.array(b)))
    np.testing.assert_allclose(heading_twist(q), [np.cos(a / 2), 0.0, np.sin(a / 2), 0.0], atol=1e-12)


def test_relative_orientations_are_free_of_a_common_yaw_and_a_common_yaw_drift():
    rng = np.random.default_rng(5)
    q = _random(rng, (40, 6))
    rel = relative_orientations(q, 4)
    common = quat.about_y(rng.uniform(-np.pi, np.pi))  # one unknown heading
    np.testing.assert_allclose(relative_orientations(quat.mul(common, q), 4), rel, atol=1e-12)
    drift = quat.about_y(np.cumsum(rng.normal(scale=0.05, size=40)))[:, None]  # a heading wandering over time
    np.testing.assert_allclose(relative_orientations(quat.mul(drift, q), 4), rel, atol=1e-12)
    # one sensor's own yaw moves its row and no other
    own = q.copy()
    own[:, 2] = quat.mul(quat.about_y(np.full(40, 0.3)), q[:, 2])
    moved = relative_orientations(own, 4)
    np.testing.assert_allclose(np.delete(moved, 2, axis=1), np.delete(rel, 2, axis=1), atol=1e-12)
    assert np.all(np.linalg.norm(moved[:, 2] - rel[:, 2], axis=-1) > 0.1)


def test_the_cue_compares_as_two_minus_two_cos_theta():
    rng = np.random.default_rng(8)
    q = _random(rng, (30, 3))
    theta = rng.uniform(0.0, np.pi, 30)
    axis = rng.normal(size=(30, 3))
    turned = q.copy()
    turned[:, 1] = quat.mul(q[:, 1], quat.from_axis_angle(axis / np.linalg.norm(axis, axis=-1, keepdims=True), theta))
    a, b = relative_orientations(q, 0), relative_orientations(turned, 0)
    np.testing.assert_allclose(np.sum((a[:, 1] - b[:, 1]) ** 2, axis=-1), 2.0 - 2.0 * np.cos(theta), atol=1e-10)
    # the tilt cue's chord on a tilt is the same quantity
    tilt = quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), theta)
    up0, up1 = sensor_up(np.tile([1.0, 0.0, 0.0, 0.0], (30, 1))), sensor_up(tilt)
    np.testing.assert_allclose(np.sum((up0 - up1) ** 2, axis=-1), 2.0 - 2.0 * np.cos(theta), atol=1e-10)


def test_the_root_row_is_its_tilt_alone_and_missing_sensors_are_nan():
    rng = np.random.default_rng(2)
    q = _random(rng, (10, 3))
    rel = relative_orientations(q, 0)
    np.testing.assert_allclose(np.linalg.norm(rel, axis=-1), np.sqrt(1.5), atol=1e-12)
    # the root's row seen through its own up vector: R_rootᵀ·ŷ is unchanged by removing the yaw
    r = rel[:, 0].reshape(10, 3, 3) * np.sqrt(2.0)
    np.testing.assert_allclose(r[:, 1, :], sensor_up(q[:, 0]), atol=1e-12)
    q[3, 1] = np.nan
    q[5, 0] = np.nan
    out = relative_orientations(q, 0)
    assert np.isnan(out[3, 1]).all() and np.isfinite(out[3, [0, 2]]).all()
    assert np.isnan(out[5]).all()
    cue, valid = normalised_rows(out)
    assert not valid[3, 1] and not valid[5].any() and valid[4].all()
    np.testing.assert_allclose(cue[4], out[4], atol=1e-12)


def test_orientation_cue_picks_by_width():
    q = _random(np.random.default_rng(1), (4, 2))
    np.testing.assert_array_equal(orientation_cue(q, 3, None), sensor_up(q))
    np.testing.assert_array_equal(orientation_cue(q, 9, 1), relative_orientations(q, 1))
    with pytest.raises(ValueError):
        orientation_cue(q, 9, None)
