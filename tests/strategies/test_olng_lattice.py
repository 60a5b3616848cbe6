"""The online lazy neighbourhood graph's path costs (graphsvc/strategies/olng/lattice.py)."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.strategies.olng.lattice import (
    BASIC_STEPS,
    NEW_PATH,
    STEPS,
    Lattice,
    LatticeOptions,
    path_weights,
)


def _brute_force(columns, clip_of, steps):
    """Every path's window cost when the window holds every column (M ≥ T): a path
    from column s to t pays 2 × the K-th distance of each column before s, its nodes'
    costs, and once more the node a column-skipping step enters. The cheapest into
    each node of the last column."""
    T = len(columns)
    penalty = [2.0 * max(d) for _, d in columns]
    best = {}  # (column, frame) → cheapest path cost ending there
    for t, (frames, dist) in enumerate(columns):
        for f, d in zip(frames, dist):
            options = [sum(penalty[:t]) + d]
            for back, skip in steps:
                g = f - skip
                if t - back < 0 or g < 0 or clip_of[g] != clip_of[f] or (t - back, g) not in best:
                    continue
                options.append(best[(t - back, g)] + d * (2.0 if back == 2 else 1.0))
            best[(t, f)] = min(options)
    frames, _ = columns[-1]
    return np.array([best[(T - 1, f)] for f in frames])


@pytest.mark.parametrize("extended", [True, False])
@pytest.mark.parametrize("seed", range(4))
def test_costs_equal_every_paths_minimum_while_the_window_holds_every_column(seed, extended):
    rng = np.random.default_rng(seed)
    F = 40
    clip_of = np.repeat(np.arange(4), 10)  # four clips of ten frames
    T, K = 9, 8
    columns = []
    for _ in range(T):
        frames = rng.choice(F, K, replace=False)
        columns.append((frames, rng.random(K)))
    steps = STEPS if extended else BASIC_STEPS
    lattice = Lattice(clip_of, LatticeOptions(k=K, m=T + 2, i=3, extended=extended))
    for t, (frames, dist) in enumerate(columns):
        lattice.push(frames, dist)
        np.testing.assert_allclose(lattice.column()["cost"], _brute_force(columns[: t + 1], clip_of, steps), rtol=1e-12)


def test_a_hand_made_window_slides_and_skips():
    # One clip of frames 0..9. Two neighbours a column; M = 3.
    #   column 0: frame 2 (0.1), frame 7 (0.5)       K-th distance 0.5 → penalty 1.0
    #   column 1: frame 3 (0.2), frame 9 (0.4)       penalty 0.8
    #   column 2: frame 5 (0.3), frame 0 (0.6)       penalty 1.2
    #   column 3: frame 6 (0.1), frame 8 (0.2)       penalty 0.4
    clip_of = np.zeros(10, np.int64)
    lattice = Lattice(clip_of, LatticeOptions(k=2, m=3, i=2))
    lattice.push([2, 7], [0.1, 0.5])
    np.testing.assert_allclose(lattice.column()["cost"], [0.1, 0.5])  # new paths, nothing before
    lattice.push([3, 9], [0.2, 0.4])
    col = lattice.column()
    # frame 3 continues frame 2 (0.1 + 0.2); frame 9 continues frame 7 by two frames (0.5 + 0.4)
    np.testing.assert_allclose(col["cost"], [0.3, 0.9])
    assert col["step"].tolist() == [0, 1] and col["length"].tolist() == [2, 2]
    lattice.push([5, 0], [0.3, 0.6])
    col = lattice.column()
    # frame 5: from 3 by two frames (0.3 + 0.3), or from column 0's frame 2 skipping a
    # column by three frames (0.1 + 2 × 0.3 = 0.7): 0.6. Frame 0: nothing before it, a
    # new path: the two earlier columns' penalties 1.0 + 0.8, plus 0.6.
    np.testing.assert_allclose(col["cost"], [0.6, 2.4])
    assert col["step"].tolist() == [1, NEW_PATH]
    lattice.push([6, 8], [0.1, 0.2])
    col = lattice.column()
    # The window is columns 1–3 now, so column 0's contributions drop out. Frame 6:
    # continuing 2 → 3 → 5 → 6 costs 0.2 + 0.3 + 0.1 = 0.6; from column 1's frame 3 by
    # three frames, skipping column 2 (an extended step), 2 → 3 → 6 costs 0.2 + 0.1 (the
    # skip: the node entered) + 0.1 = 0.4, the cheaper. Frame 8: from column 2's frame 5
    # is three frames (no basic step), from column 1's frame 3 five: a new path, the
    # penalties of columns 1 and 2 (0.8 + 1.2) + 0.2 = 2.2.
    np.testing.assert_allclose(col["cost"], [0.4, 2.2])
    assert [STEPS[s] for s in col["step"][:1]] == [(2, 3)] and col["step"][1] == NEW_PATH
    assert col["length"].tolist() == [3, 1]
    _, frames, cost, weights = lattice.best()
    assert frames.tolist() == [6, 8] and cost.tolist() == pytest.approx([0.4, 2.2])
    np.testing.assert_allclose(weights, [1.0, 0.0])


def test_clip_boundaries_break_paths():
    clip_of = np.array([0, 0, 0, 1, 1, 1])
    lattice = Lattice(clip_of, LatticeOptions(k=1, m=4, i=1))
    lattice.push([2], [0.1])
    lattice.push([3], [0.1])  # frame 3 is the next clip's first frame, not frame 2's next
    col = lattice.column()
    assert col["step"].tolist() == [NEW_PATH] and col["cost"] == pytest.approx([0.2 + 0.1])


def test_path_weights():
    np.testing.assert_allclose(path_weights([1.0, 2.0, 4.0]), [3 / 5, 2 / 5, 0.0])
    np.testing.assert_allclose(path_weights([2.0, 2.0]), [0.5, 0.5])


def test_bad_options_and_columns_are_refused():
    for options, match in (
        (LatticeOptions(k=0), "K"),
        (LatticeOptions(m=1), "M"),
        (LatticeOptions(k=4, i=5), "I"),
        (LatticeOptions(k=2.5), "whole"),
    ):
        with pytest.raises(InputError, match=match):
            Lattice(np.zeros(10, np.int64), options)
    with pytest.raises(InputError, match="exceeds"):
        LatticeOptions(k=20, i=5).check(frames=10)
    lattice = Lattice(np.zeros(10, np.int64), LatticeOptions(k=2, m=3, i=1))
    with pytest.raises(InputError, match="finite"):
        lattice.push([1, 2], [0.1, np.nan])
    with pytest.raises(InputError, match="1 to 2 frames"):
        lattice.push([1, 2, 3], [0.1, 0.2, 0.3])
