import numpy as np
import pytest

from graphsvc.motion import quat
from graphsvc.motion.kinematics import motion_fk
from graphsvc.sensors.accelerometer import GRAVITY, second_derivative, sensor_poses, simulate_accelerations
from graphsvc.sensors.layout import PRESETS, place
from tests.conftest import still_motion


def readings(motion, layout="wrists-ankles"):
    placement = place(PRESETS[layout], motion.skeleton)
    rot, pos = motion_fk(motion)
    return simulate_accelerations(rot, pos, placement, motion.rate_hz), placement


def test_at_rest_reads_one_g_up_in_sensor_frame():
    acc, _ = readings(still_motion(20))
    # Hand-checked frames: arm sensors have Z up in the T-pose; leg sensors have X down the shin.
    np.testing.assert_allclose(acc[:, 0], np.broadcast_to([0, 0, GRAVITY], (20, 3)), atol=1e-5)
    np.testing.assert_allclose(acc[:, 1], np.broadcast_to([0, 0, GRAVITY], (20, 3)), atol=1e-5)
    np.testing.assert_allclose(acc[:, 2], np.broadcast_to([-GRAVITY, 0, 0], (20, 3)), atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(acc, axis=-1), GRAVITY, rtol=1e-6)


def test_constant_linear_acceleration_is_exact_at_every_frame_including_edges():
    m = still_motion(40)
    a = np.array([1.5, -0.5, 2.0])
    t = np.arange(40) / m.rate_hz
    m.translations[:, 0] = m.translations[:, 0] + 0.5 * t[:, None] ** 2 * a + 0.3 * t[:, None]
    acc, placement = readings(m, "kelly6")
    _, orientation = sensor_poses(*motion_fk(m), placement)
    expected = quat.inv_rotate(orientation, np.broadcast_to(a + [0, GRAVITY, 0], orientation.shape[:-1] + (3,)))
    np.testing.assert_allclose(acc, expected, atol=2e-4)


def test_uniform_circular_motion_reads_centripetal_acceleration():
    rate, omega = 60.0, 2.0 * np.pi * 0.5  # 0.5 turns/s
    m = still_motion(120, rate)
    t = np.arange(120) / rate
    # Spin the whole body about +Y through its pelvis while the pelvis stays still.
    m.rotations[:, 0] = quat.about_y(omega * t)
    acc, placement = readings(m, "wrists-ankles")
    rot, pos = motion_fk(m)
    position, orientation = sensor_poses(rot, pos, placement)
    r = np.linalg.norm(position[0, 0, [0, 2]] - pos[0, 0, [0, 2]])  # wrist's distance from the spin axis
    world = quat.rotate(orientation, acc.astype(float))
    horizontal = np.linalg.norm(world[..., [0, 2]], axis=-1)
    np.testing.assert_allclose(horizontal[:, 0], omega**2 * r, rtol=2e-3)
    np.testing.assert_allclose(world[..., 1], GRAVITY, atol=1e-3)
    # The horizontal part points from the sensor toward the axis.
    inward = pos[:, 0, [0, 2]] - position[:, 0, [0, 2]]
    cos = np.sum(world[:, 0, [0, 2]] * inward, -1) / (horizontal[:, 0] * np.linalg.norm(inward, axis=-1))
    np.testing.assert_allclose(cos, 1.0, atol=1e-6)


@pytest.mark.parametrize("frames", [1, 2, 3, 5, 6, 7])
def test_short_clips_give_finite_values(frames):
    x = np.arange(frames, dtype=float)[:, None] ** 2
    out = second_derivative(x, 1.0)
    assert np.isfinite(out).all()
    if frames >= 3:
        np.testing.assert_allclose(out, 2.0)


def test_stencil_is_fourth_order_on_a_sine():
    errors = []
    for rate in (30.0, 60.0):
        t = np.arange(int(rate)) / rate
        err = np.abs(second_derivative(np.sin(3 * t), rate) + 9 * np.sin(3 * t))
        errors.append(err[2:-2].max())
    assert errors[0] / errors[1] > 12  # halving h divides the error by ~16
