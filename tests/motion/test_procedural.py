"""Procedural knowledge base: determinism, labels, and physical plausibility checked
independently of the generator (contacts are re-derived here from joint heights and
speeds, never read from the generator's plan)."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.motion import quat, signals
from graphsvc.motion.joints import CANONICAL, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import (
    CONTENT_LABELS,
    generate_knowledge_base,
    generate_performance,
    standard_skeleton,
)

G = 9.81
SWINGS = ("forehand", "backhand", "overhead", "punch")


@pytest.fixture(scope="module")
def kb():
    clips = generate_knowledge_base(seed=0, minutes=2.0)
    return [(c, motion_fk(c)[1]) for c in clips]


def _by_label(kb, label):
    return [(c, p) for c, p in kb if c.labels[0] == label]


def _runs(mask: np.ndarray) -> list[np.ndarray]:
    idx = np.flatnonzero(mask)
    return [] if idx.size == 0 else np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)


def _ground_speed(x: np.ndarray, rate: float) -> np.ndarray:
    return np.linalg.norm(np.gradient(x[:, [0, 2]], 1.0 / rate, axis=0), axis=-1)


def _contact(pos, sk, side, rate, height=0.05, speed=0.2):
    """(F,) bool: the foot's toe or ankle is within `height` of its lowest point in
    the clip and moving slower than `speed` over the ground."""
    out = np.zeros(pos.shape[0], dtype=bool)
    for j in ("ankle", "toe"):
        x = pos[:, sk.index(f"{side}_{j}")]
        out |= (x[:, 1] < x[:, 1].min() + height) & (_ground_speed(x, rate) < speed)
    return out


def test_skeleton_is_canonical_tpose_of_adult_height():
    sk = standard_skeleton()
    table = joint_map(sk)  # the procedural map: canonical names used verbatim
    assert set(CANONICAL) <= set(sk.names)
    assert all(sk.names[table[c]] == c for c in CANONICAL)
    assert {"head_End", "l_wrist_End", "r_wrist_End", "l_toe_End", "r_toe_End"} <= set(sk.names)
    assert all(len(ch) == 0 for ch, e in zip(sk.channels, sk.end_site) if e)
    assert len(sk.channels[0]) == 6 and all(len(ch) == 3 for ch, e in zip(sk.channels[1:], sk.end_site[1:]) if not e)
    F = 1
    _, pos = motion_fk_rest(sk, F)
    p = {n: pos[0, i] for i, n in enumerate(sk.names)}
    assert 1.65 < p["head_End"][1] < 1.85
    assert p["l_wrist"][0] > 0.6 and p["r_wrist"][0] < -0.6  # arms along ±X, left to +X
    assert abs(p["l_wrist"][1] - p["l_shoulder"][1]) < 1e-9
    assert p["l_toe"][2] > p["l_ankle"][2] and p["l_knee"][1] > p["l_ankle"][1]  # feet point +Z, legs down
    assert abs(p["l_ankle"][1] - 0.08) < 0.01 and 0.0 <= p["l_toe"][1] <= 0.03


def motion_fk_rest(sk, frames):
    from graphsvc.motion.kinematics import forward_kinematics

    rot = quat.identity((frames, sk.num_joints))
    trans = np.broadcast_to(sk.offsets, (frames, sk.num_joints, 3)).copy()
    return forward_kinematics(rot, trans, sk.parents)


def test_deterministic_by_seed():
    a = generate_knowledge_base(seed=3, minutes=0.4)
    b = generate_knowledge_base(seed=3, minutes=0.4)
    c = generate_knowledge_base(seed=4, minutes=0.4)
    assert [m.name for m in a] == [m.name for m in b]
    for x, y in zip(a, b):
        assert x.labels == y.labels and x.rate_hz == y.rate_hz
        np.testing.assert_array_equal(x.rotations, y.rotations)
        np.testing.assert_array_equal(x.translations, y.translations)
    assert any(x.num_frames != y.num_frames or not np.array_equal(x.rotations, y.rotations) for x, y in zip(a, c)) or [
        m.name for m in a
    ] != [m.name for m in c]
    p1, l1 = generate_performance(seed=1, seconds=8.0)
    p2, l2 = generate_performance(seed=1, seconds=8.0)
    np.testing.assert_array_equal(p1.rotations, p2.rotations)
    np.testing.assert_array_equal(l1, l2)


def test_all_labels_present_names_and_durations(kb):
    labels = {c.labels[0] for c, _ in kb}
    assert labels == set(CONTENT_LABELS)
    total = sum(c.duration_s for c, _ in kb)
    assert 110.0 < total < 150.0
    for c, _ in kb:
        assert c.name.startswith(c.labels[0] + "_") and c.name[-2:].isdigit()
        assert 4.0 < c.duration_s < 20.0 and c.rate_hz == 30.0
        assert np.all(np.isfinite(c.rotations)) and np.allclose(np.linalg.norm(c.rotations, axis=-1), 1.0)
    assert len({c.name for c, _ in kb}) == len(kb)


def test_bone_lengths_preserved_and_body_above_ground(kb):
    for c, pos in kb:
        sk = c.skeleton
        bones = np.linalg.norm(pos[:, 1:] - pos[:, sk.parents[1:]], axis=-1)
        np.testing.assert_allclose(bones, np.broadcast_to(sk.bone_lengths()[1:], bones.shape), atol=1e-9)
        assert pos[..., 1].min() > -0.005, c.name
        assert pos[:, sk.index("head_End"), 1].min() > 1.45, c.name  # no collapsing


def test_feet_planted_without_skate(kb):
    """Ankle or toe within 2 cm of the clip's lowest and slower than 0.2 m/s: that
    joint must stay put (< 1 cm over the whole contact) at ground level."""
    for c, pos in kb:
        sk = c.skeleton
        for side in "lr":
            for j, ground in (("ankle", 0.08), ("toe", 0.02)):
                x = pos[:, sk.index(f"{side}_{j}")]
                assert abs(x[:, 1].min() - ground) < 0.01, (c.name, side, j)
                low = (x[:, 1] < x[:, 1].min() + 0.02) & (_ground_speed(x, c.rate_hz) < 0.2)
                for r in _runs(low):
                    slide = np.linalg.norm(x[r][:, [0, 2]] - x[r[0], [0, 2]], axis=-1).max()
                    assert slide < 0.01, (c.name, side, j, slide)


def test_feet_lift_and_gait_phases(kb):
    """Walking: both feet down at once (double support) in every stride; running:
    both feet off the ground (flight). Swing feet clear the ground."""
    for label in ("walk", "run"):
        for c, pos in _by_label(kb, label):
            sk = c.skeleton
            left = _contact(pos, sk, "l", c.rate_hz)
            right = _contact(pos, sk, "r", c.rate_hz)
            strides = c.duration_s * (0.8 if label == "walk" else 1.3)  # at least this many
            if label == "walk":
                assert len(_runs(left & right)) >= 0.8 * strides, c.name
                assert not np.any(~left & ~right), c.name  # never airborne
            else:
                assert len(_runs(~left & ~right)) >= 0.8 * strides, c.name
                assert not np.any(left & right), c.name
            for side in "lr":
                toe = pos[:, sk.index(f"{side}_toe"), 1]
                assert toe.max() - toe.min() > (0.05 if label == "walk" else 0.15), c.name


def test_wrist_accelerations_plausible(kb):
    """Second differences of wrist positions (what a wrist accelerometer sees,
    minus gravity): no spikes."""
    limits = {"walk": 3.0, "idle": 1.0, "stop": 5.0, "run": 8.0} | {k: 15.0 for k in SWINGS}
    peak = {}
    for c, pos in kb:
        w = pos[:, [c.skeleton.index("l_wrist"), c.skeleton.index("r_wrist")]]
        acc = np.linalg.norm(np.diff(w, 2, axis=0), axis=-1).max() * c.rate_hz**2 / G
        assert acc < limits[c.labels[0]], (c.name, acc)
        peak[c.labels[0]] = max(peak.get(c.labels[0], 0.0), acc)
    assert all(peak[k] > 2.0 for k in SWINGS)  # strokes and punches are actually fast


def test_joint_trajectories_smooth(kb):
    """No joint jumps: world speeds bounded and local rotations change by < 0.5 rad
    per frame at 30 Hz (15 rad/s; running knees and strokes up to 24–30 rad/s)."""
    for c, pos in kb:
        speed = np.linalg.norm(np.diff(pos, axis=0), axis=-1).max() * c.rate_hz
        assert speed < 20.0, (c.name, speed)
        dot = np.abs(np.sum(c.rotations[1:] * c.rotations[:-1], axis=-1)).clip(0, 1)
        assert (2 * np.arccos(dot)).max() < {"run": 0.8, "stop": 0.8}.get(
            c.labels[0], 1.0 if c.labels[0] in SWINGS else 0.5
        ), c.name


def test_locomotion_speed_ranges_and_turns(kb):
    turned = []
    for label, lo, hi in (("walk", 0.7, 1.9), ("run", 2.3, 4.7)):
        clips = _by_label(kb, label)
        assert clips
        for c, pos in clips:
            table = joint_map(c.skeleton)
            ground = signals.ground_position(pos, table["pelvis"])
            speed = np.linalg.norm(np.diff(ground, axis=0), axis=-1).sum() / c.duration_s
            assert lo < speed < hi, (c.name, speed)
            heading = np.unwrap(signals.heading(pos, table))
            turned.append(np.ptp(heading))
            # heading follows the path direction (smoothed over a stride)
            k = int(c.rate_hz)
            path = np.arctan2(*(ground[k:] - ground[:-k]).T)
            mid = np.unwrap(heading[k // 2 : k // 2 + path.size])
            err = np.abs(quat.wrap_angle(mid - path))
            assert np.median(err) < 0.2, c.name
    assert max(turned) > 0.5  # some clips follow curved paths


def test_stops_come_to_rest(kb):
    for c, pos in _by_label(kb, "stop"):
        v = _ground_speed(pos[:, 0], c.rate_hz)
        assert v.max() > 0.8 and np.mean(v < 0.05) > 0.1, c.name
        both = _contact(pos, c.skeleton, "l", c.rate_hz) & _contact(pos, c.skeleton, "r", c.rate_hz)
        assert np.any([len(r) > c.rate_hz for r in _runs(both)]), c.name  # stands a second


def test_performance_is_held_out_and_labelled_per_frame():
    perf, labels = generate_performance(seed=1, seconds=20.0)
    assert labels.shape == (perf.num_frames,) and perf.num_frames >= 20 * 30
    assert {"walk", "run", "punch"} <= set(labels) and set(labels) <= set(CONTENT_LABELS)
    assert {"forehand", "backhand", "overhead"} & set(labels)
    changes = np.count_nonzero(labels[1:] != labels[:-1])
    assert changes >= 5
    _, pos = motion_fk(perf)
    assert np.linalg.norm(np.diff(pos, axis=0), axis=-1).max() * perf.rate_hz < 20.0  # continuous
    kb = generate_knowledge_base(seed=0, minutes=0.5)
    assert all(
        c.num_frames < perf.num_frames or not np.allclose(c.rotations, perf.rotations[: c.num_frames]) for c in kb
    )
