"""Hand-checked cases for the §9 metrics."""

import json

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.evaluate.metrics import (
    bone_scaled_positions,
    canonical_parents,
    evaluate_frames,
    heading_err_deg,
    joint_err_cm,
    joint_err_scaled_cm,
    label_acc,
    root_err_cm,
    summarize,
)
from graphsvc.motion import quat, signals
from graphsvc.motion.joints import CANONICAL, canonical_indices, joint_map
from graphsvc.motion.kinematics import motion_fk
from tests.conftest import still_motion


def _walk(frames, headings, ground, skeleton):
    """Canonical joint positions (T, 19, 3) m of the T-pose with root heading and ground
    position per frame, plus its (T, 2) ground position and (T,) heading from signals."""
    m = still_motion(frames)
    m.rotations[:, 0] = quat.about_y(headings)
    m.translations[:, 0] = np.stack([ground[:, 0], np.full(frames, 0.96), ground[:, 1]], -1)
    _, pos = motion_fk(m)
    table = joint_map(skeleton)
    return (
        pos[:, canonical_indices(skeleton)],
        signals.ground_position(pos, table["pelvis"]),
        signals.heading(pos, table),
    )


def test_identical_inputs_give_zero(skeleton):
    pos, g, h = _walk(4, np.linspace(-1, 2, 4), np.array([[0, 0], [0.1, 0], [0.2, 0.1], [0.3, 0.3]]), skeleton)
    r = evaluate_frames(pos, pos, g, h, g, h, ["walk"] * 4, "walk")
    assert r["joint_err_cm"] == pytest.approx(0, abs=1e-9)
    assert r["root_err_cm"] == 0 and r["heading_err_deg"] == 0 and r["label_acc"] == 1.0
    assert r["frames"] == 4 and r["frames_dropped"] == 0
    np.testing.assert_allclose(r["per_frame"]["joint_err_cm"], 0, atol=1e-9)


def test_rigid_ground_shift_costs_no_joint_error(skeleton):
    T = 3
    h_true = np.array([0.0, 0.5, -2.0])
    g_true = np.array([[0.0, 0.0], [1.0, 2.0], [-1.0, 0.5]])
    shift = np.array([0.3, -0.4])  # 50 cm
    pred, pg, ph = _walk(T, h_true + np.radians(30), g_true + shift, skeleton)
    true, tg, th = _walk(T, h_true, g_true, skeleton)
    np.testing.assert_allclose(ph - th, np.radians(30), atol=1e-12)
    per, _ = joint_err_cm(pred, true, pg, ph, tg, th)
    np.testing.assert_allclose(per, 0, atol=1e-9)
    np.testing.assert_allclose(root_err_cm(pg, tg)[0], 50.0)
    assert heading_err_deg(ph, th)[1] == pytest.approx(30.0)
    # without the alignment the prediction would be far off
    assert np.linalg.norm(pred - true, axis=-1).mean() > 0.4


def test_alignment_uses_heading_convention():
    # one joint 1 m in front (+Z) of a root heading 0; the truth faces +X (heading +90°):
    # aligned, the joint must sit 1 m along +X of the true root at (5, 5).
    pred = np.array([[[0.0, 1.0, 1.0]]])
    true = np.array([[[6.0, 1.0, 5.0]]])
    per, _ = joint_err_cm(pred, true, [[0.0, 0.0]], [0.0], [[5.0, 5.0]], [np.pi / 2])
    assert per[0] == pytest.approx(0, abs=1e-9)


def test_single_joint_offset(skeleton):
    pos, g, h = _walk(2, np.array([0.3, 0.3]), np.zeros((2, 2)), skeleton)
    P = pos.shape[1]
    pred = pos.copy()
    pred[1, 7, 1] += 0.03  # 3 cm up: heights are not aligned away
    per, mean = joint_err_cm(pred, pos, g, h, g, h)
    np.testing.assert_allclose(per, [0.0, 3.0 / P], atol=1e-9)
    assert mean == pytest.approx(3.0 / (2 * P))  # 19 joints: 0.0789 cm


def test_heading_wraps_across_pi():
    per, mean = heading_err_deg(np.radians([179.0, 10.0]), np.radians([-179.0, 350.0]))
    np.testing.assert_allclose(per, [2.0, 20.0], atol=1e-9)  # 10° vs 350° is 20° apart
    assert mean == pytest.approx(11.0)


def test_label_accuracy():
    per, acc = label_acc(["walk", "run", "walk", None], "walk")
    np.testing.assert_array_equal(per, [1, 0, 1, 0])
    assert acc == 0.5
    assert label_acc(np.array([3, 3, 1]), "3")[1] == pytest.approx(2 / 3)


def test_lengths_truncate_to_shorter(skeleton):
    pos, g, h = _walk(5, np.zeros(5), np.zeros((5, 2)), skeleton)
    r = evaluate_frames(pos, pos[:3], g, h, g[:3], h[:3])
    assert r["frames"] == 3 and r["frames_dropped"] == 2 and r["label_acc"] is None
    assert r["per_frame"]["root_err_cm"].shape == (3,)


def test_bad_inputs_raise(skeleton):
    pos, g, h = _walk(2, np.zeros(2), np.zeros((2, 2)), skeleton)
    with pytest.raises(InputError):
        evaluate_frames(pos, pos[:, :5], g, h, g, h)  # joint counts
    with pytest.raises(InputError):
        evaluate_frames(pos[:0], pos[:0], g[:0], h[:0], g[:0], h[:0])  # empty
    with pytest.raises(InputError):
        evaluate_frames(pos, pos, g[:1], h, g, h)  # predicted side disagrees with itself
    bad = pos.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError):
        evaluate_frames(bad, pos, g, h, g, h)
    with pytest.raises(InputError):
        heading_err_deg([], [])


def test_summarize_weights_by_frames():
    a = {
        "name": "a",
        "frames": 10,
        "frames_dropped": 0,
        "joint_err_cm": 2.0,
        "root_err_cm": 10.0,
        "heading_err_deg": 0.0,
        "label_acc": 1.0,
        "per_frame": {"joint_err_cm": np.zeros(10)},
    }
    b = {
        "name": "b",
        "frames": 30,
        "frames_dropped": 1,
        "joint_err_cm": 6.0,
        "root_err_cm": 20.0,
        "heading_err_deg": 4.0,
        "label_acc": 0.5,
        "per_frame": {},
    }
    c = {
        "name": "c",
        "frames": 60,
        "frames_dropped": 0,
        "joint_err_cm": 1.0,
        "root_err_cm": 0.0,
        "heading_err_deg": 1.0,
        "label_acc": None,
        "per_frame": {},
    }
    s = summarize([a, b, c])
    assert [r["name"] for r in s["clips"]] == ["a", "b", "c"]
    assert all("per_frame" not in r for r in s["clips"])
    m = s["mean"]
    assert m["clips"] == 3 and m["frames"] == 100
    assert m["joint_err_cm"] == pytest.approx((10 * 2 + 30 * 6 + 60 * 1) / 100)  # 2.6
    assert m["root_err_cm"] == pytest.approx((100 + 600) / 100)  # 7.0
    assert m["heading_err_deg"] == pytest.approx((120 + 60) / 100)  # 1.8
    assert m["label_acc"] == pytest.approx((10 * 1.0 + 30 * 0.5) / 40)  # c has no label: 0.625
    json.dumps(s)  # JSON-ready
    assert summarize([])["mean"]["joint_err_cm"] is None


def test_summarize_of_evaluated_clips_is_json(skeleton):
    pos, g, h = _walk(3, np.zeros(3), np.zeros((3, 2)), skeleton)
    s = summarize([evaluate_frames(pos, pos, g, h, g + 0.01, h, [1, 1, 2], 1, name="x")])
    out = json.loads(json.dumps(s))
    assert set(out) == {"clips", "mean"}
    assert out["mean"]["root_err_cm"] == pytest.approx(np.sqrt(2))
    assert out["clips"][0]["label_acc"] == pytest.approx(2 / 3)


# ---------------------------------------------------------------- on the truth's bone lengths


def _chain(points):
    """(1, 3, 3) a two-bone chain root → 1 → 2 in one frame."""
    return np.array([points], dtype=np.float64)


CHAIN_PARENTS = np.array([-1, 0, 1])


def test_bone_scaled_positions_of_a_two_bone_chain():
    # out along +X by 0.5, then down by 0.5; the truth's bones 1.0 and 2.0 long
    pred = _chain([(0.0, 1.0, 0.0), (0.5, 1.0, 0.0), (0.5, 0.5, 0.0)])
    got = bone_scaled_positions(pred, [0.0, 1.0, 2.0], CHAIN_PARENTS)
    np.testing.assert_allclose(got, _chain([(0.0, 1.0, 0.0), (1.0, 1.0, 0.0), (1.0, -1.0, 0.0)]), atol=1e-15)
    # per-frame lengths and a diagonal bone: (0.3, 0.4) scaled to 10 → (6, 8)
    pred = _chain([(1.0, 0.0, 0.0), (1.3, 0.4, 0.0), (1.3, 0.4, 0.0)])
    got = bone_scaled_positions(pred, [[0.0, 10.0, 3.0]], CHAIN_PARENTS)
    # the second bone has zero length in the prediction: no direction, it stays zero
    np.testing.assert_allclose(got, _chain([(1.0, 0.0, 0.0), (7.0, 8.0, 0.0), (7.0, 8.0, 0.0)]), atol=1e-12)


def test_joint_err_scaled_scores_the_pose_not_the_proportions():
    truth = _chain([(0.0, 1.0, 0.0), (1.0, 1.0, 0.0), (1.0, -1.0, 0.0)])
    same_pose = _chain([(0.0, 1.0, 0.0), (0.5, 1.0, 0.0), (0.5, 0.5, 0.0)])  # bones half as long, and a quarter
    ground, heading = np.array([[0.0, 0.0]]), np.zeros(1)
    args = (ground, heading, ground, heading)
    # unscaled: joints 0, 0.5 and √(0.5² + 1.5²) m apart
    _, plain = joint_err_cm(same_pose, truth, *args)
    assert plain == pytest.approx(100.0 * (0.0 + 0.5 + np.sqrt(2.5)) / 3.0, abs=1e-9)
    _, scaled = joint_err_scaled_cm(same_pose, truth, CHAIN_PARENTS, *args)
    assert scaled == pytest.approx(0.0, abs=1e-12)
    # a bent elbow: the second bone along +X instead of down; on the truth's lengths the
    # hand lands at (3, 1, 0), √(2² + 2²) from the truth's (1, −1, 0)
    bent = _chain([(0.0, 1.0, 0.0), (0.5, 1.0, 0.0), (0.75, 1.0, 0.0)])
    per_frame, scaled = joint_err_scaled_cm(bent, truth, CHAIN_PARENTS, *args)
    assert scaled == pytest.approx(100.0 * np.sqrt(8.0) / 3.0, abs=1e-9)
    assert per_frame.shape == (1,)


def test_joint_err_scaled_lifts_the_root_with_the_truth_s_legs():
    # a leg standing straight: root → knee → ankle, the prediction's bones 0.5 m, the
    # truth's 0.6 m (its root 1.2 m up)
    pred = _chain([(0.0, 1.0, 0.0), (0.0, 0.5, 0.0), (0.0, 0.0, 0.0)])
    truth = _chain([(0.0, 1.2, 0.0), (0.0, 0.6, 0.0), (0.0, 0.0, 0.0)])
    ground, heading = np.array([[0.0, 0.0]]), np.zeros(1)
    args = (ground, heading, ground, heading)
    # the root kept where it is: every joint 0.2 m low
    _, kept = joint_err_scaled_cm(pred, truth, CHAIN_PARENTS, *args)
    assert kept == pytest.approx(20.0, abs=1e-9)
    # the root lifted by the legs' ratio 1.2 / 1.0: on the truth
    _, lifted = joint_err_scaled_cm(pred, truth, CHAIN_PARENTS, *args, legs=[1, 2])
    assert lifted == pytest.approx(0.0, abs=1e-9)


def test_canonical_parents_skip_a_missing_joint():
    assert list(canonical_parents(["pelvis", "spine", "chest", "l_shoulder", "l_elbow"])) == [-1, 0, 1, 2, 3]
    # no spine: the chest hangs from the pelvis; no chest either: the shoulder does too
    assert list(canonical_parents(["pelvis", "chest", "neck"])) == [-1, 0, 1]
    assert list(canonical_parents(["pelvis", "l_shoulder", "l_hip"])) == [-1, 0, 0]


def test_evaluate_frames_adds_the_scaled_error_with_joint_names(skeleton):
    frames = 4
    ground = np.zeros((frames, 2))
    pos, g, h = _walk(frames, np.zeros(frames), ground, skeleton)
    names = list(CANONICAL)
    # the same pose with every bone 1.2 × as long, standing on the floor below the pelvis
    # (its pelvis 1.2 × as high): proportions only
    floor = pos[:, :1] * np.array([1.0, 0.0, 1.0])
    bigger = floor + 1.2 * (pos - floor)
    row = evaluate_frames(bigger, pos, g, h, g, h, joints=names)
    assert row["joint_err_cm"] > 1.0
    assert row["joint_err_scaled_cm"] == pytest.approx(0.0, abs=1e-9)
    assert "joint_err_scaled_cm" not in evaluate_frames(bigger, pos, g, h, g, h)
    mean = summarize([row, {**row, "frames": 4, "joint_err_scaled_cm": 3.0}])["mean"]
    assert mean["joint_err_scaled_cm"] == pytest.approx(1.5)


def test_bone_scaled_inputs_are_checked():
    pred = _chain([(0.0, 1.0, 0.0), (0.5, 1.0, 0.0), (0.5, 0.5, 0.0)])
    with pytest.raises(InputError, match="parents"):
        bone_scaled_positions(pred, [0.0, 1.0, 1.0], [-1, 2, 1])
    with pytest.raises(InputError, match="negative"):
        bone_scaled_positions(pred, [0.0, -1.0, 1.0], CHAIN_PARENTS)
    with pytest.raises(InputError, match="NaN"):
        bone_scaled_positions(pred, [0.0, np.nan, 1.0], CHAIN_PARENTS)
    with pytest.raises(InputError, match="frame counts"):
        bone_scaled_positions(pred, np.ones((2, 3)), CHAIN_PARENTS)
