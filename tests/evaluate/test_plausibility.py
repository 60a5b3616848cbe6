"""What a viewer sees, measured (`evaluate.metrics`): jitter, foot skate and ground
penetration on hand-made motions with hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.evaluate.metrics import jitter_km_s3, penetration_cm, plausibility, skate_cm_s

RATE = 30.0


def _frames(T: int, P: int = 2) -> np.ndarray:
    return np.zeros((T, P, 3))


def test_a_constant_velocity_glide_has_no_jitter():
    pos = _frames(40)
    t = np.arange(40) / RATE
    pos[:, :, 0] = 1.5 * t[:, None] + np.array([0.0, 0.3])
    pos[:, :, 1] = 0.9
    per_frame, mean = jitter_km_s3(pos, RATE)
    assert per_frame.shape == (37,) and mean == pytest.approx(0.0, abs=1e-9)


def test_jitter_of_a_cubic_is_its_third_derivative():
    # x = a t³: the third difference is 6 a dt³ exactly, so the jerk is 6 a m/s³
    a = 2.0
    t = np.arange(30) / RATE
    pos = _frames(30, 1)
    pos[:, 0, 0] = a * t**3
    per_frame, mean = jitter_km_s3(pos, RATE)
    np.testing.assert_allclose(per_frame, 6 * a / 1000.0, rtol=1e-6)
    assert mean == pytest.approx(0.012, rel=1e-6)
    assert jitter_km_s3(pos[:3], RATE) == (pytest.approx(np.zeros(0)), None)


def test_a_planted_foot_does_not_skate_and_one_sliding_on_the_floor_at_1_m_s_skates_100_cm_s():
    T = 30
    planted = _frames(T)
    planted[:, 0] = (0.1, 0.08, 0.0)
    planted[:, 1] = (-0.1, 0.08, 0.3)
    _, mean = skate_cm_s(planted, RATE, (0, 1))
    assert mean == 0.0
    sliding = planted.copy()
    sliding[:, :, 2] += np.arange(T)[:, None] / RATE  # both feet on their floor, +Z at 1 m/s
    per_frame, mean = skate_cm_s(sliding, RATE, (0, 1))
    np.testing.assert_allclose(per_frame, 100.0)
    assert mean == pytest.approx(100.0)
    # a foot 2.5 cm or more above its lowest height weighs nothing; 1 cm up, 2 − 2^0.4
    lifted = sliding.copy()
    lifted[:, 1, 1] += np.where(np.arange(T) < 15, 0.0, 0.01)
    lifted[:, 0, 1] += np.where(np.arange(T) < 15, 0.0, 0.03)
    per_frame, _ = skate_cm_s(lifted, RATE, (0, 1))
    assert per_frame[0] == pytest.approx(100.0)
    assert per_frame[-1] == pytest.approx(0.5 * (0.0 + 100.0 * (2.0 - 2.0**0.4)))


def test_penetration_is_the_depth_of_the_lowest_joint_below_the_floor():
    pos = _frames(3)
    pos[:, 0, 1] = (0.05, -0.02, -0.001)
    pos[:, 1, 1] = (0.9, 0.9, -0.005)
    per_frame, mean = penetration_cm(pos)
    np.testing.assert_allclose(per_frame, (0.0, 2.0, 0.5))
    assert mean == pytest.approx(2.5 / 3)


def test_plausibility_gathers_the_three_and_refuses_bad_input():
    pos = _frames(10)
    values, per_frame = plausibility(pos, RATE, (0, 1))
    assert values == {"jitter_km_s3": 0.0, "skate_cm_s": 0.0, "penetration_cm": 0.0}
    assert [len(per_frame[k]) for k in values] == [7, 9, 10]
    pos[2, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        plausibility(pos, RATE, (0, 1))
