import numpy as np

from graphsvc.motion import quat, signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from tests.conftest import still_motion


def test_heading_follows_root_rotation_and_ground_position(skeleton):
    m = still_motion(8)
    angles = np.linspace(-3.0, 3.0, 8)
    m.rotations[:, 0] = quat.about_y(angles)
    m.translations[:, 0] = np.stack([np.arange(8.0), np.full(8, 0.96), -np.arange(8.0)], -1)
    _, pos = motion_fk(m)
    table = joint_map(skeleton)
    np.testing.assert_allclose(signals.heading(pos, table), angles, atol=1e-12)
    np.testing.assert_allclose(
        signals.ground_position(pos, table["pelvis"]), np.stack([np.arange(8.0), -np.arange(8.0)], -1)
    )


def _feet(frames):
    """World positions where only ankles and toes matter: (F, J, 3) for the T-pose skeleton."""
    m = still_motion(frames)
    _, pos = motion_fk(m)
    return pos


def test_contact_follows_stance_and_swing(skeleton):
    rate = 30.0
    F = 90
    pos = _feet(F)
    table = joint_map(skeleton)
    # Left foot: planted for frames 0-29, swings (lifted 15 cm, moving 1.5 m/s) 30-59, planted again.
    swing = np.arange(30, 60)
    lift = 0.15 * np.sin(np.pi * (swing - 29) / 31)
    for j in ("l_ankle", "l_toe"):
        pos[swing, table[j], 1] += lift
        pos[swing, table[j], 2] += 1.5 * (swing - 29) / rate
        pos[60:, table[j], 2] += 1.5 * 31 / rate
    contacts = signals.foot_contacts(pos, table, rate)
    assert contacts[:, 1].all()  # right foot never moves
    assert contacts[:27, 0].all() and contacts[64:, 0].all()
    assert not contacts[33:57, 0].any()
    changes = np.nonzero(signals.contact_changes(contacts))[0]
    assert len(changes) == 2 and changes[0] < changes[1]


def test_hysteresis_keeps_flags_steady_between_thresholds(skeleton):
    table = joint_map(skeleton)
    t = np.arange(120) / 30.0
    # A slow waver (≤ 3 cm/s) between the on (5 cm) and off (8 cm) height thresholds.
    waver = 0.065 + 0.01 * np.sin(np.pi * t)

    def flags(lift):
        pos = _feet(120)
        for j in ("l_ankle", "l_toe"):
            pos[:, table[j], 1] += lift
        return signals.foot_contacts(pos, table, 30.0)[:, 0]

    assert not flags(waver).any()  # never came down below the on-threshold
    # Planted for the first second, then rising slowly into the band: stays planted.
    planted_first = np.where(t < 1.0, 0.0, np.minimum(waver, 0.065 * (t - 1.0)))
    assert flags(planted_first).all()


def test_speeds_span_two_frame_steps_at_the_ends_too():
    # x (m) at 30 Hz: central differences 0.012·15 = 0.18, 0, 0.018·15 = 0.27 m/s; the
    # first and last frames take their neighbours'.
    x = np.array([0.0, 0.012, 0.012, 0.012, 0.030])
    pos = np.stack([x, np.zeros(5), np.zeros(5)], axis=-1)
    np.testing.assert_allclose(signals.speeds(pos, 30.0), [0.18, 0.18, 0.0, 0.27, 0.27], atol=1e-12)
    np.testing.assert_allclose(signals.speeds(pos[:2], 30.0), [0.36, 0.36], atol=1e-12)  # (one step)
    assert signals.speeds(pos[:1], 30.0).tolist() == [0.0]


def test_a_foot_planted_from_frame_0_is_in_contact_at_frame_0(skeleton):
    # Both feet planted throughout; the whole body shifted 12 mm between frames 0 and 1
    # (a reconstruction's track pull): one step of 0.36 m/s, above the 0.35 m/s to
    # come into contact, but over two steps 0.18 m/s, as every later frame is measured.
    table = joint_map(skeleton)
    pos = _feet(30)
    pos[1:, :, 0] += 0.012
    contacts = signals.foot_contacts(pos, table, 30.0)
    assert contacts.all(), contacts[:3]
    # A foot that leaves the ground at frame 0 is not planted there.
    for j in ("l_ankle", "l_toe"):
        pos[:, table[j], 1] += 0.1 * np.arange(30) / 30.0
        pos[:, table[j], 2] += 1.0 * np.arange(30) / 30.0
    contacts = signals.foot_contacts(pos, table, 30.0)
    assert not contacts[:, 0].any() and contacts[:, 1].all()
