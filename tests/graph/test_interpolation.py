import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from graphsvc.graph.distance import distance_block, pose_features
from graphsvc.graph.interpolation import (
    align_ground,
    align_root_rotation,
    aligned_segments,
    blend_along_path,
    blend_arrays_along_path,
    blend_ground,
    blend_timeline,
    bounded_dtw,
    path_score,
    same_contact_matrix,
    similar_regions,
    slope_ok,
)
from graphsvc.motion import quat

STEPS = [(1, 1), (1, 2), (2, 1)]


# ----------------------------------------------------------------------------- regions


def region_cells(r):
    return {(r.a0 + i, r.b0 + j) for i, j in zip(*np.nonzero(r.mask))}


def test_regions_join_diagonal_neighbours():
    keep = np.array(
        [
            [1, 0, 0, 0, 0, 1],
            [0, 1, 0, 0, 0, 1],
            [0, 0, 1, 0, 0, 0],
            [0, 1, 0, 0, 0, 0],
            [0, 0, 0, 0, 1, 1],
        ],
        dtype=bool,
    )
    dist = np.where(keep, 0.1, 1.0)
    regions = similar_regions(dist, np.ones_like(keep), 0.5)
    groups = sorted(map(sorted, map(region_cells, regions)))
    # The diagonal chain and its anti-diagonal branch touch only at corners (4-disconnected).
    assert groups == [
        [(0, 0), (1, 1), (2, 2), (3, 1)],
        [(0, 5), (1, 5)],
        [(4, 4), (4, 5)],
    ]
    chain = next(r for r in regions if (0, 0) in region_cells(r))
    assert (chain.a0, chain.b0, chain.shape) == (0, 0, (4, 3))


def test_regions_respect_contacts_and_threshold_and_bbox_masks():
    dist = np.full((5, 5), 0.2)
    dist[2, :] = 0.5  # not strictly below the threshold: splits the matrix
    same = np.ones((5, 5), dtype=bool)
    same[:, 4] = False
    regions = similar_regions(dist, same, 0.5)
    assert len(regions) == 2
    assert sorted(map(sorted, map(region_cells, regions))) == [
        sorted((i, j) for i in (0, 1) for j in range(4)),
        sorted((i, j) for i in (3, 4) for j in range(4)),
    ]
    # An L-shaped component's box includes cells of another component that the mask excludes.
    keep = np.array([[1, 0, 1], [1, 0, 0], [1, 1, 0]], dtype=bool)
    regions = similar_regions(np.where(keep, 0.0, 1.0), np.ones_like(keep), 0.5)
    big = max(regions, key=lambda r: r.mask.sum())
    assert big.shape == (3, 2) and big.mask.sum() == 4 and len(regions) == 2


def test_same_contact_matrix():
    a = np.array([[1, 0], [1, 1], [0, 0]], dtype=bool)
    b = np.array([[1, 1], [1, 0]], dtype=bool)
    assert same_contact_matrix(a, b).tolist() == [[False, True], [True, False], [False, False]]


# ----------------------------------------------------------------------------- DTW


def brute_force_best(cost, allowed, reward):
    """Minimum objective over every path (any allowed start, steps of STEPS through
    allowed cells, stop anywhere), by exhaustive enumeration."""
    h, w = cost.shape
    best = np.inf

    def walk(i, j, score):
        nonlocal best
        best = min(best, score)
        for di, dj in STEPS:
            ni, nj = i + di, j + dj
            if ni < h and nj < w and allowed[ni, nj]:
                walk(ni, nj, score + 0.5 * (di + dj) * (cost[ni, nj] - reward))

    for i, j in itertools.product(range(h), range(w)):
        if allowed[i, j]:
            walk(i, j, cost[i, j] - reward)
    return best


small = st.integers(1, 7).flatmap(
    lambda h: st.integers(1, 7).flatmap(
        lambda w: st.tuples(
            arrays(np.float64, (h, w), elements=st.floats(0.0, 1.0)),
            arrays(np.bool_, (h, w)),
            st.sampled_from([None, 0.5, 1.5]),
        )
    )
)


@settings(max_examples=150, deadline=None)
@given(small)
def test_dtw_matches_brute_force_and_keeps_slope(case):
    cost, allowed, reward = case
    path = bounded_dtw(cost, allowed, reward)
    if not allowed.any():
        assert path is None
        return
    assert path.ndim == 2 and path.shape[1] == 2
    assert slope_ok(path)
    assert allowed[path[:, 0], path[:, 1]].all()
    r = reward if reward is not None else cost[allowed].max() + 1e-6 * max(1.0, cost[allowed].max())
    assert path_score(cost, path, r) == pytest.approx(brute_force_best(cost, allowed, r), abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 25), st.integers(2, 25), st.integers(0, 2**31 - 1))
def test_dtw_slope_bounded_on_random_costs(h, w, seed):
    rng = np.random.default_rng(seed)
    cost = rng.random((h, w))
    allowed = rng.random((h, w)) < 0.8
    path = bounded_dtw(cost, allowed)
    if not allowed.any():  # (small grids can draw no allowed cell)
        assert path is None
        return
    assert path is not None and slope_ok(path)
    assert allowed[path[:, 0], path[:, 1]].all()
    if len(path) > 1:
        span = path[-1] - path[0]
        assert 0.5 <= span[1] / span[0] <= 2.0


def test_dtw_finds_zero_cost_diagonal():
    rng = np.random.default_rng(3)
    cost = rng.uniform(0.2, 1.0, (20, 20))
    np.fill_diagonal(cost, 0.0)
    path = bounded_dtw(cost, np.ones_like(cost, dtype=bool))
    assert np.array_equal(path, np.stack([np.arange(20)] * 2, axis=1))


def test_dtw_no_allowed_cell():
    assert bounded_dtw(np.zeros((3, 4)), np.zeros((3, 4), dtype=bool)) is None


def test_slope_ok():
    assert slope_ok(np.array([[0, 0], [1, 2], [3, 3], [4, 4]]))
    assert not slope_ok(np.array([[0, 0], [1, 3]]))
    assert not slope_ok(np.array([[0, 0], [0, 1]]))
    assert slope_ok(np.array([[5, 7]]))


# ----------------------------------------------------------------------------- segments


def test_segment_duration_filter():
    rate = 20.0  # 0.5 s = 10 frames of elapsed time
    dist = np.ones((40, 40))
    same = np.ones_like(dist, dtype=bool)
    idx = np.arange(11)
    dist[idx, idx] = 0.1  # 11 cells: 10 frames elapsed, kept
    dist[20 + idx[:10], 25 + idx[:10]] = 0.1  # 10 cells: 9 frames elapsed, dropped
    segments = aligned_segments(dist, same, 0.5, rate)
    assert len(segments) == 1
    assert np.array_equal(segments[0], np.stack([idx, idx], axis=1))
    assert aligned_segments(dist, same, 0.5, rate, min_seconds=0.4)[1][0].tolist() == [20, 25]


def smooth_cloud(times, seed=0, points=6):
    """(F, P, 3) smooth non-periodic point motion at the given times (seconds)."""
    rng = np.random.default_rng(seed)
    freq = rng.uniform(0.2, 1.2, (3, points, 3))
    phase = rng.uniform(0, 2 * np.pi, (3, points, 3))
    amp = rng.uniform(0.05, 0.25, (3, points, 3))
    base = rng.normal(0, 0.4, (points, 3)) + np.array([0.0, 1.0, 0.0])
    wave = np.sum(amp * np.sin(2 * np.pi * freq * times[:, None, None, None] + phase), axis=1)
    return base + wave


def test_time_stretched_copy_aligns_with_slope_one_and_a_half():
    rate = 30.0
    fa = np.arange(120) / rate
    fb = np.arange(178) / (1.5 * rate)  # the same motion played 1.5× slower
    a, b = smooth_cloud(fa), smooth_cloud(fb)
    feats_a, feats_b = pose_features(a, 7), pose_features(b, 7)
    dist = distance_block(feats_a, feats_b)
    segments = aligned_segments(dist, np.ones_like(dist, dtype=bool), 0.15, rate)
    longest = max(segments, key=len)
    assert slope_ok(longest)
    span = longest[-1] - longest[0]
    assert span[0] > 90
    assert span[1] / span[0] == pytest.approx(1.5, abs=0.05)
    assert np.max(np.abs(longest[:, 1] - 1.5 * longest[:, 0])) <= 2.0


# ----------------------------------------------------------------------------- blending


def random_rotations(rng, shape):
    return quat.normalize(rng.standard_normal(tuple(shape) + (4,)))


def test_blend_of_identical_inputs_is_the_input():
    rng = np.random.default_rng(1)
    rot = random_rotations(rng, (30, 5))
    path = np.stack([np.arange(4, 24), np.arange(4, 24)], axis=1)
    out = blend_along_path(rot, rot, path)
    assert out.shape == (20, 5, 4)
    assert np.allclose(np.abs(np.sum(out * rot[4:24], axis=-1)), 1.0, atol=1e-12)
    heights = rng.random(30)
    assert np.allclose(blend_arrays_along_path(heights, heights, path), heights[4:24])


def test_weight_zero_reproduces_a_on_a_warped_path():
    rng = np.random.default_rng(2)
    rot_a, rot_b = random_rotations(rng, (20, 3)), random_rotations(rng, (30, 3))
    path = np.array([[2, 0], [3, 2], [4, 3], [6, 4], [7, 6]])
    out = blend_along_path(rot_a, rot_b, path, weight=0.0)
    assert np.allclose(np.abs(np.sum(out * rot_a[2:8], axis=-1)), 1.0, atol=1e-12)


def test_blend_about_one_axis_halves_the_angles():
    rng = np.random.default_rng(4)
    axis = quat.normalize(np.array([0.3, -1.0, 0.5, 0.0]))[:3]
    alpha = rng.uniform(-1.5, 1.5, (12, 2))
    beta = rng.uniform(-1.5, 1.5, (12, 2))
    ra, rb = quat.from_axis_angle(axis, alpha), quat.from_axis_angle(axis, beta)
    out = blend_along_path(ra, rb, np.stack([np.arange(12)] * 2, axis=1))
    want = quat.from_axis_angle(axis, 0.5 * (alpha + beta))
    assert np.allclose(np.abs(np.sum(out * want, axis=-1)), 1.0, atol=1e-12)


def test_timeline_is_uniform_mean_of_both_sides():
    path = np.array([[0, 0], [1, 2], [2, 3], [4, 4], [5, 6]])
    ca, cb = blend_timeline(path)
    # Clock: 0, 1.5, 2.5, 4, 5.5 → frames 0..5.
    assert len(ca) == 6
    assert np.allclose(0.5 * (ca - ca[0]) + 0.5 * (cb - cb[0]), np.arange(6))
    assert np.all(np.diff(ca) > 0) and np.all(np.diff(cb) > 0)
    assert ca[0] == 0 and cb[0] == 0 and ca[-1] <= 5 and cb[-1] <= 6


def test_blend_ground_undoes_rigid_motion():
    rng = np.random.default_rng(5)
    F = 40
    ground_a = np.cumsum(rng.normal(0.0, 0.05, (F, 2)), axis=0)
    heading_a = np.cumsum(rng.normal(0.0, 0.1, F)) + 3.0  # crosses +π
    theta, shift = 0.9, np.array([2.0, -1.0])
    # b is a moved rigidly away: b = R(−θ)(a − t), so aligning b by (θ, t) recovers a.
    c, s = np.cos(-theta), np.sin(-theta)
    d = ground_a - shift
    ground_b = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=-1)
    heading_b = quat.wrap_angle(heading_a - theta)
    moved, moved_heading = align_ground(ground_b, heading_b, theta, shift)
    assert np.allclose(moved, ground_a)
    assert np.allclose(quat.wrap_angle(moved_heading - heading_a), 0.0)
    path = np.stack([np.arange(F)] * 2, axis=1)
    pos, head = blend_ground(ground_a, quat.wrap_angle(heading_a), ground_b, heading_b, path, theta, shift)
    assert np.allclose(pos, ground_a)
    assert np.allclose(quat.wrap_angle(head - heading_a), 0.0, atol=1e-12)
    # Root rotation alignment agrees with the heading convention.
    root_b = quat.about_y(heading_b)[:, None, :]
    aligned = align_root_rotation(root_b, theta)
    assert np.allclose(quat.wrap_angle(quat.heading_angle(aligned[:, 0]) - heading_a), 0.0, atol=1e-9)


def test_blend_ground_headings_take_short_arc():
    ground = np.zeros((3, 2))
    _, head = blend_ground(
        ground, np.full(3, 3.0), ground, np.full(3, -3.0), np.stack([np.arange(3)] * 2, 1), 0.0, np.zeros(2)
    )
    assert np.allclose(np.abs(head), np.pi)
