"""The root's track fused with the tracker (`synthesis.track`): the smoother is the
linear-Gaussian model's maximum-likelihood answer (checked against scipy's least
squares on the same equations), it removes the tracker's noise, it holds the offset
while both feet are planted (a stance's answer is the measurements' precision-weighted
mean, computed by hand), and live (fixed lag) equals the batch smoother over the same
frames bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import lstsq

from graphsvc.synthesis.track import (
    PRIOR_OFFSET_M,
    PRIOR_RATE_M_S,
    FixedLagSmoother,
    TrackModel,
    free_steps,
    smooth_offsets,
)


def _least_squares(z: np.ndarray, model: TrackModel) -> np.ndarray:
    """min over x_t = (d_t, ḋ_t) of |prior|² + Σ |Q^-½ (x_{t+1} − F x_t)|² + Σ ((z_t − d_t) / σ)²,
    one axis at a time: the offsets d (T, 2)."""
    dt, s, _ = model.noise()
    q11, q12, q22 = s * dt**3 / 3.0, s * dt**2 / 2.0, s * dt  # (van Loan's white-acceleration model)
    L = np.linalg.cholesky(np.array([[q11, q12], [q12, q22]]))
    W = np.linalg.inv(L)  # whitens a step's process noise
    F = np.array([[1.0, dt], [0.0, 1.0]])
    T = z.shape[0]
    out = np.zeros((T, 2))
    for axis in range(2):
        rows, rhs = [], []
        e = np.zeros(2 * T)
        e[0] = 1.0 / PRIOR_OFFSET_M
        rows.append(e), rhs.append(0.0)
        e = np.zeros(2 * T)
        e[1] = 1.0 / PRIOR_RATE_M_S
        rows.append(e), rhs.append(0.0)
        for t in range(T - 1):
            block = np.zeros((2, 2 * T))
            block[:, 2 * t + 2 : 2 * t + 4] = W
            block[:, 2 * t : 2 * t + 2] = -W @ F
            rows += list(block)
            rhs += [0.0, 0.0]
        for t in range(T):
            if np.isfinite(z[t]).all():
                e = np.zeros(2 * T)
                e[2 * t] = 1.0 / model.sigma_m
                rows.append(e), rhs.append(z[t, axis] / model.sigma_m)
        x = lstsq(np.array(rows), np.array(rhs))[0]
        out[:, axis] = x[0::2]
    return out


def _noisy(T: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 30.0
    truth = np.stack([0.4 * np.sin(0.5 * t), 0.2 * t], axis=1)
    return truth, truth + rng.normal(0.0, 0.1, (T, 2))


def test_the_smoother_is_the_models_least_squares_answer():
    model = TrackModel(0.1, 0.5, 30.0)
    _, z = _noisy(60)
    z[10:14] = np.nan  # a gap in the tracker
    np.testing.assert_allclose(smooth_offsets(z, model), _least_squares(z, model), atol=1e-8)


def test_a_constant_offset_comes_back_and_the_noise_does_not():
    model = TrackModel(0.1, 0.2, 30.0)
    z = np.full((90, 2), (0.3, -1.2))
    np.testing.assert_allclose(smooth_offsets(z, model), z, atol=1e-4)  # (the 10 m prior: a shrink of 1e-5)
    truth, noisy = _noisy(600, seed=3)
    err = smooth_offsets(noisy, model) - truth
    assert np.sqrt(np.mean(err**2)) < 0.03  # from σ 10 cm
    jitter = np.abs(np.diff(smooth_offsets(noisy, model), n=3, axis=0)).max() * 30.0**3
    assert jitter < 5.0  # m/s³ (the raw measurements: about 12,000; a walking body: about 100)
    assert smooth_offsets(np.full((5, 2), np.nan), model).tolist() == [[0.0, 0.0]] * 5


def test_both_feet_planted_hold_the_offset_at_the_measurements_weighted_mean():
    model = TrackModel(0.1, 0.5, 30.0)
    _, z = _noisy(40, seed=4)
    z[5] = np.nan
    contacts = np.ones((40, 2), bool)  # standing: no step moves the offset
    out = smooth_offsets(z, model, free_steps(contacts))
    seen = z[np.isfinite(z).all(axis=1)]
    # One unknown seen n times with variance σ², from a prior N(0, PRIOR_OFFSET_M²).
    want = seen.sum(axis=0) / model.sigma_m**2 / (1.0 / PRIOR_OFFSET_M**2 + len(seen) / model.sigma_m**2)
    np.testing.assert_allclose(out, np.broadcast_to(want, out.shape), atol=1e-9)
    # A stance inside a walk: the offset moves only into the frames with a foot free.
    contacts = np.zeros((40, 2), bool)
    contacts[10:25] = True
    g = free_steps(contacts)
    assert g.tolist() == [1.0] * 10 + [0.0] * 15 + [1.0] * 15
    out = smooth_offsets(z, model, g)
    moved = np.abs(np.diff(out, axis=0)).max(axis=1) > 1e-12  # step t → t + 1
    assert not moved[10:24].any() and moved[:9].all() and moved[25:].all()


@pytest.mark.parametrize("lag", [0, 1, 12])
def test_live_with_a_lag_equals_the_batch_smoother_over_the_same_frames(lag):
    model = TrackModel(0.1, 0.5, 30.0)
    _, z = _noisy(80, seed=1)
    z[30:33] = np.nan
    contacts = np.zeros((80, 2), bool)
    contacts[40:55] = True
    g = free_steps(contacts)
    live = FixedLagSmoother(model, lag)
    got = {}
    for t in range(len(z)):
        live.push(z[t], g[t])
        if t - lag >= 0:
            got[t - lag] = live.take(t - lag)
            want = smooth_offsets(z[: t + 1], model, g[: t + 1])[t - lag]
            assert np.array_equal(got[t - lag], want), (t, lag)
    live.flush()
    for t in range(len(z) - lag, len(z)):
        assert np.array_equal(live.take(t), smooth_offsets(z, model, g)[t])
    assert live.finals == {}
