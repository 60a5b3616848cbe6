"""Hand-checked cases for the §9 metrics."""

import json

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.evaluate.metrics import (
    evaluate_frames,
    heading_err_deg,
    joint_err_cm,
    label_acc,
    root_err_cm,
    summarize,
)
from graphsvc.motion import quat, signals
from graphsvc.motion.joints import canonical_indices, joint_map
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
    return pos[:, canonical_indices(skeleton)], signals.ground_position(pos, table["pelvis"]), signals.heading(pos, table)


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
    a = {"name": "a", "frames": 10, "frames_dropped": 0, "joint_err_cm": 2.0, "root_err_cm": 10.0,
         "heading_err_deg": 0.0, "label_acc": 1.0, "per_frame": {"joint_err_cm": np.zeros(10)}}  # fmt: skip
    b = {"name": "b", "frames": 30, "frames_dropped": 1, "joint_err_cm": 6.0, "root_err_cm": 20.0,
         "heading_err_deg": 4.0, "label_acc": 0.5, "per_frame": {}}  # fmt: skip
    c = {"name": "c", "frames": 60, "frames_dropped": 0, "joint_err_cm": 1.0, "root_err_cm": 0.0,
         "heading_err_deg": 1.0, "label_acc": None, "per_frame": {}}  # fmt: skip
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
