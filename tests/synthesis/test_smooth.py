"""The poses' filter (`synthesis.smooth`): a Gaussian that keeps what is already
smooth (a constant-velocity glide, a held pose, a quaternion written with either sign),
takes out frame-to-frame noise, and streams bit for bit as the batch filters."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.motion import quat
from graphsvc.synthesis.smooth import StreamingSmoother, gaussian_taps, half_width, smooth_poses


def _glide(T: int = 60, J: int = 3):
    """A body gliding at 1.2 m/s with a joint turning at a constant rate."""
    t = np.arange(T) / 30.0
    rot = np.tile([1.0, 0.0, 0.0, 0.0], (T, J, 1))
    rot[:, 1] = quat.about_y(0.8 * t)
    trans = np.zeros((T, J, 3))
    trans[:, 0, 0] = 1.2 * t
    trans[:, 0, 1] = 0.9
    trans[:, 1:, 1] = 0.3
    return rot, trans


def test_the_taps_are_a_normalised_gaussian_three_sigma_wide():
    w = gaussian_taps(1.0)
    assert w.size == 7 and half_width(1.0) == 3 and abs(w.sum() - 1.0) < 1e-15
    assert w[3] / w[4] == pytest.approx(np.exp(0.5))  # exp(−0²/2) / exp(−1²/2)
    assert gaussian_taps(0.0).tolist() == [1.0] and half_width(0.0) == 0
    assert half_width(1.2) == 4


def test_a_glide_and_a_steady_turn_are_kept_and_noise_is_not():
    rot, trans = _glide()
    r, t = smooth_poses(rot, trans, 1.0)
    h = half_width(1.0)
    inner = slice(h, -h)  # (the edges repeat the end frames: a glide slows there)
    np.testing.assert_allclose(t[inner], trans[inner], atol=1e-12)  # a symmetric filter keeps a line
    # The turn's quaternions are on one great circle, spaced evenly: the symmetric
    # weighted mean points at the centre frame's, so the turn is kept exactly.
    np.testing.assert_allclose(np.abs(np.sum(r[inner, 1] * rot[inner, 1], axis=-1)), 1.0, atol=1e-12)
    rng = np.random.default_rng(0)
    noisy = trans + rng.normal(0.0, 0.005, trans.shape)
    _, t = smooth_poses(rot, noisy, 1.0)
    third = [np.abs(np.diff(x[inner], n=3, axis=0)).mean() for x in (noisy, t)]
    assert third[1] < 0.15 * third[0]  # (white noise: 0.10 of its third difference is left at σ = 1 frame)
    assert np.abs(t - trans)[inner].mean() < 0.5 * np.abs(noisy - trans)[inner].mean()
    same_r, same_t = smooth_poses(rot, trans, 0.0)
    assert same_r is rot and same_t is trans


def test_a_quaternion_written_with_the_other_sign_changes_nothing():
    rot, trans = _glide()
    flipped = rot.copy()
    flipped[1::2] *= -1.0
    a, _ = smooth_poses(rot, trans, 1.5)
    b, _ = smooth_poses(flipped, trans, 1.5)
    np.testing.assert_allclose(np.abs(np.sum(a * b, axis=-1)), 1.0, atol=1e-12)


@pytest.mark.parametrize("chunks", [[1], [5, 2, 9], [60]])
def test_the_stream_gives_the_batch_bit_for_bit(chunks):
    rot, trans = _glide(50)
    rng = np.random.default_rng(1)
    trans = trans + rng.normal(0.0, 0.01, trans.shape)
    want_r, want_t = smooth_poses(rot, trans, 1.0)
    s = StreamingSmoother(1.0, rot.shape[1])
    got_r, got_t, t, k = [], [], 0, 0
    while t < len(rot):
        n = chunks[k % len(chunks)]
        first, r, tr = s.add(t, rot[t : t + n], trans[t : t + n])
        assert first == sum(len(x) for x in got_r)  # in order, each frame once
        assert first + len(r) <= max(0, t + n - s.h)  # a frame waits for the h after it
        got_r.append(r), got_t.append(tr)
        t, k = t + n, k + 1
    first, r, tr = s.finish()
    got_r.append(r), got_t.append(tr)
    assert np.array_equal(np.concatenate(got_r), want_r) and np.array_equal(np.concatenate(got_t), want_t)
    assert len(s.rot) <= 2 * s.h + max(chunks)  # (it keeps only what later frames reach)
    with pytest.raises(ValueError, match="in order"):
        s.add(3, rot[:1], trans[:1])
