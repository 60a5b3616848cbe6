import numpy as np
from scipy.optimize import minimize_scalar

from graphsvc.graph.distance import (
    alignment,
    distance_block,
    distance_pairs,
    pose_features,
    window_frames,
    window_weights,
)


def rot_y(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def brute_force(cloud_a, cloud_b, w):
    """Weighted RMS after the best Y rotation (1-D search) and optimal XZ translation."""

    def cost(theta):
        rb = cloud_b @ rot_y(theta).T
        t = np.sum(w[:, None] * (cloud_a - rb), axis=0)
        t[1] = 0.0
        return np.sum(w * np.sum((cloud_a - rb - t) ** 2, axis=-1))

    grid = np.linspace(-np.pi, np.pi, 721)
    start = grid[np.argmin([cost(g) for g in grid])]
    res = minimize_scalar(cost, bounds=(start - 0.01, start + 0.01), method="bounded", options={"xatol": 1e-12})
    return np.sqrt(res.fun)


def test_window_weights():
    assert window_frames(30.0) == 7 and window_frames(60.0) == 15 and window_frames(4.0) == 3
    w = window_weights(7)
    assert abs(w.sum() - 1) < 1e-12 and np.argmax(w) == 3 and np.allclose(w, w[::-1])


def test_closed_form_matches_brute_force_search():
    rng = np.random.default_rng(0)
    P, F, W = 5, 12, 5
    a = rng.standard_normal((F, P, 3))
    b = rng.standard_normal((F, P, 3))
    fa, fb = pose_features(a, W), pose_features(b, W)
    d = distance_block(fa, fb)
    tw = window_weights(W)
    w = np.repeat(tw / P, P)
    for i, j in [(0, 0), (5, 7), (11, 3), (6, 6)]:
        ia = np.clip(np.arange(i - 2, i + 3), 0, F - 1)
        ib = np.clip(np.arange(j - 2, j + 3), 0, F - 1)
        expected = brute_force(a[ia].reshape(-1, 3), b[ib].reshape(-1, 3), w)
        assert abs(d[i, j] - expected) < 1e-5
        assert abs(distance_pairs(fa, np.array([i]), fb, np.array([j]))[0] - d[i, j]) < 1e-9


def test_rigidly_moved_copy_has_zero_distance_and_alignment_recovers_the_motion():
    rng = np.random.default_rng(1)
    a = rng.standard_normal((20, 6, 3))
    theta, shift = 0.7, np.array([1.5, 0.0, -2.0])
    b = (a - shift) @ rot_y(-theta).T  # so that a = R(θ)·b + shift
    fa, fb = pose_features(a, 7), pose_features(b, 7)
    d = distance_block(fa, fb)
    assert np.all(np.diag(d) < 2e-3)  # float32 features
    th, t = alignment(fa, np.arange(20), fb, np.arange(20))
    np.testing.assert_allclose(th, theta, atol=1e-5)
    np.testing.assert_allclose(t, np.broadcast_to(shift[[0, 2]], (20, 2)), atol=1e-4)
    # Height differences are not aligned away.
    lifted = b + np.array([0.0, 0.3, 0.0])
    assert np.allclose(distance_block(fa, pose_features(lifted, 7)).diagonal(), 0.3, atol=1e-3)
