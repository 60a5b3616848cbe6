"""Transition search on procedural walking-like clips whose contacts we control."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from graphsvc.graph.distance import concat_features, distance_block, pose_features
from graphsvc.graph.transitions import (
    best_per_source,
    find_transitions,
    find_transitions_bruteforce,
    indexed_pairs,
    kb_frames,
    local_minima,
)
from graphsvc.motion.signals import contact_changes

PERIOD = 30  # frames per gait cycle
WINDOW = 5
SPEED = 0.04  # m per frame of forward progress


def rot_y(theta):
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def gait_contacts(t):
    """(F, 2) contacts from the phase of frame numbers t: left down on [0, 0.6),
    right on [0.5, 1.1) of each cycle, so double support at [0, 0.1) and [0.5, 0.6);
    every change falls on a whole frame (phases × 30)."""
    ph = (t % PERIOD) / PERIOD
    return np.stack([ph < 0.6, (ph >= 0.5) | (ph < 0.1)], axis=1)


def walker(t, arm=0.25, lift=0.12, raise_hands=0.0):
    """(F, 6, 3) pelvis, head, hands, feet of a walker heading +Z at frame numbers t
    (floats allowed): a periodic pose on top of steady forward progress."""
    ph = 2 * np.pi * (t % PERIOD) / PERIOD
    contacts = gait_contacts(np.floor(t).astype(int))
    z0 = SPEED * t
    pts = np.zeros((t.shape[0], 6, 3))
    pts[:, 0] = np.stack([0.02 * np.sin(ph), 1.0 + 0.02 * np.cos(2 * ph), z0], axis=1)
    pts[:, 1] = pts[:, 0] + [0, 0.6, 0]
    for k, side in ((2, 1.0), (3, -1.0)):  # hands swing opposite to the feet
        pts[:, k] = pts[:, 0] + np.stack(
            [np.full_like(ph, 0.25 * side), -0.1 + raise_hands + 0 * ph, side * arm * np.sin(ph)], axis=1
        )
    for k, foot, side in ((4, 0, 1.0), (5, 1, -1.0)):
        swing = ~contacts[:, foot]
        pts[:, k] = pts[:, 0] + np.stack(
            [np.full_like(ph, 0.1 * side), -1.0 + swing * lift * np.abs(np.sin(ph)), -side * 0.3 * np.sin(ph)], axis=1
        )
    return pts, contacts


def build_kb(clips):
    """clips: list of (positions (F, P, 3), contacts (F, 2)) → kwargs of find_transitions
    plus the raw positions for checks."""
    feats = concat_features([pose_features(p, WINDOW) for p, _ in clips])
    lengths = np.array([p.shape[0] for p, _ in clips])
    return {
        "features": feats,
        "contacts": np.concatenate([c for _, c in clips]),
        "changes": np.concatenate([contact_changes(c) for _, c in clips]),
        "clip_of_frame": np.repeat(np.arange(len(clips)), lengths),
        "frame_in_clip": np.concatenate([np.arange(n) for n in lengths]),
        "clip_lengths": lengths,
    }, np.concatenate([p for p, _ in clips])


THETA, SHIFT, OFFSET = 0.9, np.array([2.0, -1.0]), 9  # clip 1 = clip 0 rotated, moved, 9 frames later


@pytest.fixture(scope="module")
def kb():
    t0 = np.arange(100.0)
    p0, c0 = walker(t0)
    p1, c1 = walker(t0[:80] + OFFSET)
    p1 = p1 @ rot_y(THETA).T + [SHIFT[0], 0.0, SHIFT[1]]
    p2, c2 = walker(np.arange(90.0) + 4, arm=0.32, lift=0.16)  # a slightly different walker
    c2[26:29] = [[True, False], [True, True], [True, False]]  # flickering flags at a heel strike
    p3, c3 = walker(np.arange(70.0), raise_hands=0.9)  # hands up: far from the rest
    return build_kb([(p0, c0), (p1, c1), (p2, c2), (p3, c3)])


def as_set(tr):
    return set(zip(tr.src.tolist(), tr.dst.tolist()))


def test_rules_hold(kb):
    args, _ = kb
    tr = find_transitions(**args, threshold_m=0.05)
    assert len(tr) > 0
    contacts, clip, fic = args["contacts"], args["clip_of_frame"], args["frame_in_clip"]
    assert np.all(contacts[tr.src] == contacts[tr.dst])
    assert np.all(args["changes"][tr.src] & args["changes"][tr.dst])
    assert np.all((fic[tr.src] > 0) & (fic[tr.dst] > 0))
    assert np.all(fic[tr.dst] + 1 < args["clip_lengths"][clip[tr.dst]])  # the edge's target dst+1 exists
    assert np.all(tr.distance <= 0.05)
    assert np.all(tr.src != tr.dst)
    same = clip[tr.src] == clip[tr.dst]
    assert np.all(np.abs(tr.src - tr.dst)[same] >= 10)
    d = distance_block(args["features"], args["features"])[tr.src, tr.dst]
    np.testing.assert_allclose(tr.distance, d, atol=1e-6)
    order = np.lexsort((tr.dst, tr.src))
    assert np.array_equal(order, np.arange(len(tr)))
    assert not np.any((clip[tr.src] == 3) != (clip[tr.dst] == 3))  # hands-up clip: only loops onto itself
    assert np.any(clip[tr.src] == 3)


def test_rigid_copy_gives_zero_distance_transitions_with_its_motion(kb):
    args, pos = kb
    tr = find_transitions(**args, threshold_m=0.05)
    clip, fic = args["clip_of_frame"], args["frame_in_clip"]
    # Clip 1 frame k is clip 0 frame k + 9 moved by (θ, shift): both directions at
    # every contact change away from the clip ends (where windows are clamped).
    starts = np.concatenate([[0], np.cumsum(args["clip_lengths"])])
    k = np.flatnonzero(args["changes"][starts[1] : starts[2]])
    k = k[(k >= 3) & (k + OFFSET < 97) & (k < 77)]
    assert k.size >= 8
    found = as_set(tr)
    for kk in k:
        src, dst = starts[1] + kk, kk + OFFSET
        assert (src, dst) in found and (dst, src) in found
        row = np.flatnonzero((tr.src == src) & (tr.dst == dst))[0]
        assert tr.distance[row] < 2e-3
        assert abs(tr.theta[row] - THETA) < 1e-4
        np.testing.assert_allclose(tr.translation[row], SHIFT, atol=1e-3)
    # Every transition's (θ, t) maps the raw dst frame onto the src frame's pose.
    for s, d, th, t, dist in zip(tr.src, tr.dst, tr.theta, tr.translation, tr.distance):
        moved = pos[d] @ rot_y(th).T + [t[0], 0.0, t[1]]
        if dist < 2e-3 and 3 <= fic[s] and 3 <= fic[d]:
            np.testing.assert_allclose(moved, pos[s], atol=0.02)
    # The periodic clip loops onto itself a cycle later.
    assert (starts[0] + 15, starts[0] + 45) in found and (starts[0] + 45, starts[0] + 15) in found
    # The other walker joins in, at a non-zero distance.
    assert np.any((clip[tr.src] == 2) & (clip[tr.dst] == 0) & (tr.distance > 2e-3))


@pytest.mark.parametrize("threshold", [0.01, 0.05, 0.3])
@pytest.mark.parametrize("radius", [0, 3, 8])
def test_indexed_equals_bruteforce(kb, threshold, radius):
    args, _ = kb
    rules = {"threshold_m": threshold, "local_min_radius": radius, "exclude_same_clip_within": 10}
    a = find_transitions(**args, **rules)
    b = find_transitions_bruteforce(**args, **rules)
    assert as_set(a) == as_set(b)
    np.testing.assert_array_equal(a.src, b.src)
    np.testing.assert_array_equal(a.dst, b.dst)
    np.testing.assert_allclose(a.distance, b.distance)
    c = find_transitions(**args, **rules, k=10_000, pca_dims=4)  # k path, other tree dimension
    assert as_set(c) == as_set(a)


def test_local_minimum_and_determinism(kb):
    args, _ = kb
    r = 3
    tr = find_transitions(**args, threshold_m=0.3, local_min_radius=r)
    again = find_transitions(**args, threshold_m=0.3, local_min_radius=r)
    for f in ("src", "dst", "distance", "theta", "translation"):
        np.testing.assert_array_equal(getattr(tr, f), getattr(again, f))
    # Recheck against the full matrix: no candidate cell of the same clips and state
    # within ±r is strictly closer.
    d = distance_block(args["features"], args["features"])
    contacts, clip, changes = args["contacts"], args["clip_of_frame"], args["changes"]
    cand = changes & (args["frame_in_clip"] > 0)
    for s, t, dist in zip(tr.src, tr.dst, tr.distance):
        for ds in range(-r, r + 1):
            for dt in range(-r, r + 1):
                s2, t2 = s + ds, t + dt
                if (ds, dt) == (0, 0) or not (0 <= s2 < len(clip) and 0 <= t2 < len(clip)):
                    continue
                if clip[s2] != clip[s] or clip[t2] != clip[t] or not (cand[s2] and cand[t2]):
                    continue
                if np.any(contacts[s2] != contacts[s]) or np.any(contacts[t2] != contacts[s]):
                    continue
                if (
                    clip[s2] == clip[t2]
                    and abs(s2 - t2) < 10
                    or args["frame_in_clip"][t2] + 1 >= args["clip_lengths"][clip[t2]]
                ):
                    continue
                assert d[s2, t2] >= dist - 1e-6
    more = find_transitions(**args, threshold_m=0.3, local_min_radius=0)
    assert as_set(tr) <= as_set(more) and len(more) > len(tr)


def test_local_minima_ties_and_groups():
    src = np.array([10, 11, 10, 30])
    dst = np.array([50, 51, 50, 70])
    dist = np.array([0.0, 0.0, 0.0, 0.0])
    group = np.array([0, 0, 1, 0])
    keep = local_minima(src, dst, dist, group, radius=2)
    # Equal distances: the smaller (src, dst) wins; other groups and far cells stand.
    assert keep.tolist() == [True, False, True, True]


def test_max_per_source_keeps_the_closest():
    src = np.array([5, 5, 5, 7, 7])
    dist = np.array([0.3, 0.1, 0.2, 0.5, 0.4])
    assert best_per_source(src, dist, 2).tolist() == [False, True, True, True, True]
    assert best_per_source(src, dist, 1).tolist() == [False, True, False, False, True]


def test_no_changes_no_transitions():
    pts = np.tile(np.random.default_rng(0).standard_normal((1, 4, 3)), (40, 1, 1))
    contacts = np.ones((40, 2), dtype=bool)
    args, _ = build_kb([(pts, contacts), (pts + 1.0, contacts)])
    tr = find_transitions(**args)
    assert len(tr) == 0 and tr.translation.shape == (0, 2)
    assert len(find_transitions_bruteforce(**args)) == 0


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    threshold=st.floats(0.02, 0.4),
    radius=st.integers(0, 6),
    exclude=st.integers(1, 20),
)
def test_indexed_equals_bruteforce_on_random_kbs(seed, threshold, radius, exclude):
    rng = np.random.default_rng(seed)
    clips = []
    for _ in range(rng.integers(2, 6)):
        F = int(rng.integers(20, 80))
        t = rng.uniform(0, PERIOD) + np.arange(F) * rng.uniform(0.7, 1.3)
        pts, _ = walker(t, arm=rng.uniform(0.1, 0.4), lift=rng.uniform(0.05, 0.2))
        pts = pts + rng.normal(0, 0.01, pts.shape)
        contacts = rng.random((F, 2)) < 0.7  # flickery flags: many changes, all states
        pts = pts @ rot_y(rng.uniform(-np.pi, np.pi)).T
        clips.append((pts, contacts))
    args, _ = build_kb(clips)
    rules = {"threshold_m": threshold, "local_min_radius": radius, "exclude_same_clip_within": exclude}
    a = find_transitions(**args, **rules)
    b = find_transitions_bruteforce(**args, **rules)
    assert as_set(a) == as_set(b)
    assert np.all(args["contacts"][a.src] == args["contacts"][a.dst]) and np.all(a.distance <= threshold)


def test_bounded_candidates_on_near_identical_clips():
    """Twenty near-copies of one walk: every heel strike is within the threshold of
    about a hundred others. k nearest candidates a frame bound the pairs, keep every
    transition valid, and find nearly all of the exact search's (8 a source)."""
    rng = np.random.default_rng(4)
    clips = []
    for _ in range(20):
        pts, contacts = walker(np.arange(90.0) + rng.uniform(-0.2, 0.2), arm=rng.uniform(0.24, 0.26))
        clips.append((pts + rng.normal(0, 0.002, pts.shape), contacts))
    args, _ = build_kb(clips)
    rules = {"threshold_m": 0.05, "local_min_radius": 5, "exclude_same_clip_within": 10, "max_per_source": 8}
    exact = find_transitions(**args, **rules)
    candidates = int(np.sum(args["changes"] & (args["frame_in_clip"] > 0)))
    fr = kb_frames(
        args["features"],
        args["contacts"],
        args["changes"],
        args["clip_of_frame"],
        args["frame_in_clip"],
        args["clip_lengths"],
    )
    assert len(indexed_pairs(args["features"], fr, 0.05)) > 40 * candidates  # the square the bound is for
    assert len(indexed_pairs(args["features"], fr, 0.05, k=16)) <= 16 * candidates
    bounded = find_transitions(**args, **rules, k=16)
    assert np.all(bounded.distance <= 0.05)
    assert np.all(args["contacts"][bounded.src] == args["contacts"][bounded.dst])
    assert np.all(np.bincount(bounded.src) <= 8)
    found = len(as_set(bounded) & as_set(exact)) / len(as_set(exact))
    assert found > 0.9, found
    assert as_set(find_transitions(**args, **rules, k=candidates)) == as_set(exact)
