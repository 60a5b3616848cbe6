import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.motion import quat
from graphsvc.motion.resample import resample, sample_times
from tests.conftest import still_motion


def turning_motion(frames, rate):
    m = still_motion(frames, rate)
    t = np.arange(frames) / rate
    m.rotations[:, 0] = quat.about_y(0.5 * t)  # 0.5 rad/s, well inside slerp's exact regime
    m.translations[:, 0, 0] = 2.0 * t  # 2 m/s along X
    return m


def test_frame_count_covers_same_span():
    assert len(sample_times(121, 120.0, 30.0)) == 31
    assert len(sample_times(10, 30.0, 60.0)) == 19


def test_downsample_120_to_30_keeps_every_fourth_frame():
    m = turning_motion(121, 120.0)
    r = resample(m, 30.0)
    assert r.rate_hz == 30.0 and r.num_frames == 31
    np.testing.assert_allclose(r.rotations, m.rotations[::4], atol=1e-12)
    np.testing.assert_allclose(r.translations, m.translations[::4], atol=1e-12)


def test_upsample_interpolates_constant_velocity_exactly():
    m = turning_motion(31, 30.0)
    r = resample(m, 120.0)
    t = np.arange(r.num_frames) / 120.0
    np.testing.assert_allclose(r.translations[:, 0, 0], 2.0 * t, atol=1e-12)
    # Slerp between poses on one axis reproduces constant angular velocity.
    np.testing.assert_allclose(quat.heading_angle(r.rotations[:, 0]), 0.5 * t, atol=1e-9)


def test_same_rate_is_identity_and_bad_rate_refused():
    m = turning_motion(5, 30.0)
    assert resample(m, 30.0) is m
    with pytest.raises(InputError):
        resample(m, 0.0)
