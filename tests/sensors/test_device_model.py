"""The real-device sensor model: mounting rotations, soft tissue, foot-strike jolts and
the orientation output, each against an independent computation."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.motion import quat
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.motion.signals import foot_contacts
from graphsvc.sensors.accelerometer import G_UP, second_derivative, sensor_poses
from graphsvc.sensors.device_model import impacts, mounting, orientation_output, soft_tissue
from graphsvc.sensors.layout import PRESETS, anatomical_placement
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.simulate import simulate_recording


@pytest.fixture(scope="module")
def walk():
    return next(m for m in generate_knowledge_base(seed=4, minutes=0.5) if m.labels[0] in ("walk", "run"))


def test_mounting_is_drawn_from_the_seed_and_the_name_only():
    a = mounting(7, ("l_shin", "chest"), 30.0)
    b = mounting(7, ("chest", "x", "l_shin"), 30.0)
    np.testing.assert_array_equal(a[0], b[2])
    np.testing.assert_array_equal(a[1], b[0])
    assert not np.allclose(a[0], mounting(8, ("l_shin",), 30.0)[0])
    angles = 2 * np.degrees(np.arccos(np.clip(np.abs(mounting(1, [f"s{k}" for k in range(200)], 30.0)[:, 0]), 0, 1)))
    assert angles.max() <= 30.0 + 1e-9 and angles.min() >= 0 and 12 < angles.mean() < 18  # (uniform in [0, 30]°)
    np.testing.assert_array_equal(mounting(3, ("a",), 0.0), [[1.0, 0.0, 0.0, 0.0]])


def test_a_mounted_device_reads_in_its_rotated_frame_and_reports_it(walk):
    layout = PRESETS["kelly6"]
    ideal = simulate_recording(walk, layout, parse_noise("none"), seed=3)
    mounted = simulate_recording(walk, layout, parse_noise("none,mount=40,orientations=1"), seed=3)
    M = mounting(3, layout.sensor_names, 40.0)
    np.testing.assert_allclose(
        mounted.accelerations, quat.inv_rotate(M[None], ideal.accelerations.astype(float)), atol=2e-4
    )
    # The orientation output is the mounted frame's: with it, reading − gravity is the sensor point's p̈.
    world_rot, world_pos = motion_fk(walk)
    position, orientation = sensor_poses(
        world_rot, world_pos, anatomical_placement(layout, walk.skeleton, None, world_rot, world_pos)
    )
    np.testing.assert_allclose(mounted.orientations, quat.mul(orientation, M[None]), atol=1e-6)
    free = quat.rotate(mounted.orientations.astype(float), mounted.accelerations.astype(float)) - G_UP
    np.testing.assert_allclose(free, second_derivative(position, walk.rate_hz), atol=2e-3)


def test_soft_tissue_is_a_damped_spring():
    rate, hz, zeta = 1000.0, 5.0, 0.2
    step = np.zeros((3000, 1))
    step[100:] = 1.0
    out = soft_tissue(step, rate, hz, zeta)
    # The sensor's acceleration over the bone's is (2ζωs + ω²) / (s² + 2ζωs + ω²): its step
    # response, from scipy's continuous-time solution.
    from scipy.signal import lti

    w = 2 * np.pi * hz
    t, want = lti([2 * zeta * w, w * w], [1.0, 2 * zeta * w, w * w]).step(T=np.arange(2900) / rate)
    np.testing.assert_allclose(out[100:, 0], want, atol=0.01)
    assert out.max() - 1.0 > 0.5  # (a soft, lightly damped strap overshoots)
    assert out[-1, 0] == pytest.approx(1.0, abs=1e-3) and out[0, 0] == 0.0
    slow = np.sin(2 * np.pi * 0.2 * np.arange(2000) / 100.0)[:, None]
    settled = soft_tissue(slow, 100.0, 10.0, 0.3)[100:] - slow[100:]  # (after the start's transient)
    assert np.abs(settled).max() < 0.01  # (far below resonance: unchanged but for the hold's half sample)
    np.testing.assert_array_equal(soft_tissue(slow, 100.0, 0.0, 0.3), slow)  # (0 Hz: rigid)


def test_foot_strikes_jolt_the_legs_sensors(walk):
    table = joint_map(walk.skeleton)
    contacts = foot_contacts(motion_fk(walk)[1], table, walk.rate_hz)
    segments = ["l_knee", "r_knee", "l_elbow", "pelvis"]
    j = impacts(contacts, segments, walk.rate_hz, 20.0)
    strikes_l = np.flatnonzero(contacts[1:, 0] & ~contacts[:-1, 0]) + 1
    assert strikes_l.size and np.allclose(j[strikes_l, 0, 1], 20.0, atol=0.6)  # (the jolt's first sample, up)
    assert not j[:, 2].any() and not j[..., [0, 2]].any()  # (no arm jolt; vertical only)
    assert np.abs(j[:, 3, 1]).max() <= 0.25 * 0.5 * 20.0 * 2 + 1e-9  # (the trunk: a quarter, half a foot's)
    rec = simulate_recording(walk, PRESETS["kelly6"], parse_noise("none,impact=30"), seed=0)
    base = simulate_recording(walk, PRESETS["kelly6"], parse_noise("none"), seed=0)
    arms = [k for k, n in enumerate(rec.sensor_names) if "forearm" in n]
    np.testing.assert_array_equal(rec.accelerations[:, arms], base.accelerations[:, arms])


def test_orientation_output_noise_and_drift():
    rng = np.random.default_rng(0)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (3000, 50, 1))
    drift = orientation_output(q, 30.0, 0.0, 1.0, rng)
    yaw = np.degrees(quat.heading_angle(drift))
    # A random walk of 1°/√s: after 100 s its spread is about 10°; nothing but yaw.
    assert np.std(yaw[-1]) == pytest.approx(10.0, rel=0.3) and np.abs(yaw[0]).max() < 1e-9
    np.testing.assert_allclose(drift[..., [1, 3]], 0.0, atol=1e-12)
    noisy = orientation_output(q, 30.0, 2.0, 0.0, np.random.default_rng(1))
    angle = np.degrees(2 * np.arccos(np.clip(np.abs(noisy[..., 0]), 0, 1)))
    assert np.sqrt(np.mean(angle**2)) == pytest.approx(2.0, rel=0.05)


def test_a_common_heading_drift_turns_every_device_alike():
    from graphsvc.sensors.orientation import relative_orientations

    rng = np.random.default_rng(2)
    q = quat.normalize(rng.normal(size=(3000, 6, 4)))
    plain = orientation_output(q, 30.0, 1.0, 0.5, np.random.default_rng(3))
    common = orientation_output(q, 30.0, 1.0, 0.5, np.random.default_rng(3), heading_drift_deg=1.0)
    turn = quat.mul(common, quat.conjugate(plain))  # what the common drift added, device by device
    yaw = np.degrees(quat.heading_angle(turn))
    np.testing.assert_allclose(yaw, np.broadcast_to(yaw[:, :1], yaw.shape), atol=1e-6)  # the same turn for all ...
    np.testing.assert_allclose(turn[..., [1, 3]], 0.0, atol=1e-9)  # ... about the vertical
    assert np.abs(yaw[:, 0]).max() > 5.0  # (a random walk of 1°/√s over 100 s)
    # what the strategies read of orientations relative to a root sensor does not see it
    np.testing.assert_allclose(relative_orientations(common, 0), relative_orientations(plain, 0), atol=1e-9)


def test_the_real_preset_and_bad_keys(walk):
    real = parse_noise("real")
    assert real.orientations == 1.0 and real.tissue > 0 and real.impact > 0 and real.mount == 0
    assert real.heading_drift > 0
    rec = simulate_recording(walk, PRESETS["wrists-ankles"], real, seed=2)
    assert rec.orientations is not None and rec.orientations.shape == (walk.num_frames, 4, 4)
    np.testing.assert_allclose(np.linalg.norm(rec.orientations, axis=-1), 1.0, atol=1e-5)
    again = simulate_recording(walk, PRESETS["wrists-ankles"], real, seed=2)
    np.testing.assert_array_equal(rec.orientations, again.orientations)  # (same seed, same bytes)
    no_orient = simulate_recording(walk, PRESETS["wrists-ankles"], parse_noise("real,orientations=0"), seed=2)
    np.testing.assert_array_equal(no_orient.accelerations, rec.accelerations)  # (its own stream)
    for bad in ("default,orientations=2", "default,mount=200", "default,tissue=-1"):
        with pytest.raises(InputError):
            parse_noise(bad)
