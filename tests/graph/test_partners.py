"""Interpolation partners: the clip-level index against the all-pairs ranking."""

import numpy as np

from graphsvc.graph.distance import pose_features
from graphsvc.graph.partners import choose_partners, exact_scores, indexed_scores
from tests.graph.test_transitions import WINDOW, rot_y, walker

THRESHOLD = 0.08


def sampled_clips(count: int, seed: int = 3):
    """Walkers of varied arm swing, foot lift and hand height, each turned and shifted
    on the ground and started at its own phase: (features, contacts) a clip."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        t = np.arange(rng.integers(40, 70)) + rng.integers(0, 30)
        pts, contacts = walker(
            t.astype(float), arm=rng.uniform(0.1, 0.4), lift=rng.uniform(0.05, 0.2), raise_hands=rng.uniform(0, 0.3)
        )
        pts = pts @ rot_y(rng.uniform(-np.pi, np.pi)).T + [rng.uniform(-3, 3), 0, rng.uniform(-3, 3)]
        out.append((pose_features(pts, WINDOW), contacts))
    return out


def test_index_with_room_for_every_neighbour_scores_as_all_pairs():
    clips = sampled_clips(12)
    members = list(range(12))
    performance = [c // 2 if c < 4 else c for c in members]  # clips 0/1 and 2/3: one performance each
    exact = exact_scores(clips, members, performance, THRESHOLD)
    indexed = indexed_scores(clips, members, performance, THRESHOLD, neighbours=10_000)
    positive = {k: v for k, v in exact.items() if v > 0}
    assert positive and len(positive) < len(exact)  # some pairs match, some do not
    assert indexed.keys() == positive.keys()
    for k, v in positive.items():
        assert indexed[k] == v  # both count whole frames over the same frame total
    assert exact[0, 1] == exact[2, 3] == 0.0 and (0, 1) not in indexed


def test_few_neighbours_still_find_each_clips_close_partners():
    clips = sampled_clips(30, seed=5)
    members = list(range(30))
    performance = members
    exact = exact_scores(clips, members, performance, THRESHOLD)
    indexed = indexed_scores(clips, members, performance, THRESHOLD, neighbours=8)
    assert indexed and all(0 < v <= exact[k] for k, v in indexed.items())  # never credits what is not close
    by_label = [members]
    full = choose_partners(clips, by_label, performance, THRESHOLD, 2)
    bounded = choose_partners(clips, by_label, performance, THRESHOLD, 2, exact_max_clips=10)
    assert full == choose_partners(clips, by_label, performance, THRESHOLD, 2, exact_max_clips=30)
    # Every clip with a partner in the full ranking gets one through the index, each
    # pair it picks does share close frames, and no clip gets more than its two plus
    # those that picked it.
    has = lambda pairs: {c for p in pairs for c in p}  # noqa: E731
    assert has(full) == has(bounded) == set(members)
    assert all(exact[a, b] > 0 and exact[b, a] > 0 for a, b in bounded)
    assert len(bounded) <= 2 * len(members)
