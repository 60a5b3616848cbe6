"""The float32 first pass of the Viterbi search against the float64 search, bit for
bit: ties, near-ties, placements, masks, gaps, orientations, the eight-wide candidate
loops and the batch search's short inputs."""

import numba
import numpy as np
import pytest

from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.search import ViterbiSearch
from tests.search.problems import random_graph, random_up, shared_reading_graph, tiny_graph


def _lockstep(g, meas, position, heading, weights, allowed=None, pull_s=None, up=None):
    """Run the float32-pass search (no constraint sets) and the float64 one (one
    constraint set that requires nothing, so ranks never differ) side by side; every
    sample's costs, detours, placements and lattice rows must be identical, bit for bit.
    up: (T, S, 3) measured sensor "up" vectors (an oriented search). Returns the
    float32-pass search."""
    from graphsvc.strategies.viterbi.dense import _best_node as every_node

    oriented = up is not None
    fast = ViterbiSearch(g, weights, 0, allowed, pull_s=pull_s, oriented=oriented)
    exact = ViterbiSearch(g, weights, 1, allowed, pull_s=pull_s, oriented=oriented)
    assert fast.float32_pass and not exact.float32_pass
    free = np.zeros(1, np.int64)
    fast.start(position[0], heading[0])
    exact.start(position[0], heading[0], free, free)
    for t in range(1, len(meas)):
        fast.step(meas[t], position[t], heading[t], up=None if up is None else up[t])
        exact.step(meas[t], position[t], heading[t], free, free, up=None if up is None else up[t])
        row = (fast.first + fast.used - 1) % fast.arrivals.shape[0]
        np.testing.assert_array_equal(fast.arrivals[row], exact.arrivals[row], err_msg=f"sample {t}")
        np.testing.assert_array_equal(fast.cost, exact.cost, err_msg=f"sample {t}")
        np.testing.assert_array_equal(fast.det, exact.det, err_msg=f"sample {t}")
        np.testing.assert_array_equal(fast.place, exact.place, err_msg=f"sample {t}")
        # the best node from the chunks' lowest and highest costs, as from every node's
        assert fast.best_node() == exact.best_node() == every_node(fast.state, fast.rank, fast.det), f"sample {t}"
    np.testing.assert_array_equal(fast.trace(fast.best_node())[0], exact.trace(exact.best_node())[0])
    return fast


@pytest.mark.parametrize("seed", range(3))
def test_float32_pass_equals_float64_search_with_exact_ties(seed):
    # Readings from three levels, measurements on the same grid: many paths cost exactly
    # the same, and the choice falls to detours and edge kind (the float64 rule).
    rng = np.random.default_rng(seed)
    N, out = 50, 4
    src = np.repeat(np.arange(N), out)
    dst = rng.integers(0, N, len(src))
    pairs = np.unique(np.stack([src, dst], 1), axis=0)
    E = len(pairs)
    acc = rng.integers(-1, 2, (E, 2, 3)) * 9.81
    g = tiny_graph(pairs[:, 0], pairs[:, 1], acc, kinds=rng.integers(0, 4, E))
    T = 80
    meas = rng.integers(-1, 2, (T, 2, 3)) * 9.81
    none = [None] * T
    fast = _lockstep(g, meas, none, none, Weights(1, 0, 0))
    assert fast.near_ties > 0  # exact ties go to the float64 rule


@pytest.mark.parametrize("seed", range(3))
def test_float32_pass_equals_float64_search_placed_with_masks_and_gaps(seed):
    rng = np.random.default_rng(10 + seed)
    g = random_graph(rng, N=60, out=4)
    T = 90
    meas = rng.normal(0, 9.81, (T, 2, 3))
    meas[rng.random((T, 2)) < 0.1] = np.nan
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    position[rng.random(T) < 0.15] = np.nan  # some samples without a position, some without a heading
    heading[rng.random(T) < 0.15] = np.nan
    allowed = rng.random(g.num_nodes) < 0.8
    for weights in (Weights(0.5, 1, 1), Weights(1, 2, 0), Weights(0, 0, 1)):
        _lockstep(g, meas, position, heading, weights, allowed)
        _lockstep(g, meas, position, heading, weights, allowed, pull_s=0.2)
    # with the orientation term riding in the C_A kernels (some sensors' orientations
    # missing, and at W_A = 0 the term alone)
    g.edge_up = random_up(rng, g.edge_acc.shape)
    up = random_up(rng, meas.shape)
    up[rng.random((T, 2)) < 0.1] = np.nan
    for weights in (Weights(0.5, 1, 1, 2.0), Weights(0, 1, 0, 1.5)):
        _lockstep(g, meas, position, heading, weights, allowed, up=up)


def test_float32_pass_resolves_differences_below_float32_resolution_in_float64():
    # Readings come in pairs a hair apart (1e-6 g: costs differ by ~1e-6 g², far above
    # TIE but below float32's resolution once costs reach tens): the float32 pass cannot
    # tell such candidates apart, so the float64 rule must decide — the same way the
    # float64 search does.
    rng = np.random.default_rng(5)
    N, out = 60, 4
    src = np.repeat(np.arange(N), out)
    dst = rng.integers(0, N, len(src))
    pairs = np.unique(np.stack([src, dst], 1), axis=0)
    E = len(pairs)
    pool = rng.normal(0, 1, (6, 1, 3)).astype(np.float32)
    twins = pool.copy()
    twins[:, 0, 0] = np.nextafter(np.nextafter(pool[:, 0, 0], np.float32(9)), np.float32(9))  # 2 ulps up
    readings = np.concatenate([pool, twins])
    acc = readings[rng.integers(0, len(readings), E)].astype(np.float64) * 9.81
    g = tiny_graph(pairs[:, 0], pairs[:, 1], acc)
    T = 150
    meas = readings[rng.integers(0, len(readings), T)].astype(np.float64) * 9.81 + rng.normal(0, 0.3, (T, 1, 3))
    none = [None] * T
    fast = _lockstep(g, meas, none, none, Weights(1, 0, 0))
    assert fast.near_ties > 0


def test_near_ties_are_marked_only_where_float32_cannot_decide():
    # Node 4's incoming edges (arrivals 0–3, from nodes 0–3) read 1, 2, 3 and 0 g on one
    # axis, measured 0 g: arrival 3 wins by 1 g², far beyond float32 rounding, so the
    # float32 choice stands — its label must not be the all-ones mark (which it would
    # be with one label bit too few). Node 5's two edges read the same: an exact tie,
    # the one near-tie, which the float64 rule decides (fewer detours: the plain edge).
    readings = np.array([1.0, 2.0, 3.0, 0.0, 0.5, 0.5])
    acc = np.zeros((6, 1, 3))
    acc[:, 0, 0] = readings * 9.81
    g = tiny_graph([0, 1, 2, 3, 0, 1], [4, 4, 4, 4, 5, 5], acc, kinds=[0, 0, 0, 0, 1, 0])
    search = ViterbiSearch(g, Weights(1, 0, 0))
    assert search.float32_pass
    search.start()
    search.step(np.zeros((1, 3)))
    assert search.near_ties == 1
    np.testing.assert_array_equal(search.arrivals[0, 4:], [3, 1])
    assert search.cost[4] == 0.0 and search.cost[5] == 0.25


def test_tagged_minimum_keeps_the_lowest_value_and_its_label():
    import numba

    from graphsvc.strategies.viterbi.intrinsics import fmin, tag

    @numba.njit
    def tagged_min(values, keep):
        best = np.float32(1e38)
        for j in range(values.shape[0]):
            best = fmin(tag(values[j], keep, np.uint32(j)), best)
        return best

    rng = np.random.default_rng(2)
    for bits in (0, 2, 4, 9):
        keep = np.uint32(0xFFFFFFFF ^ ((1 << bits) - 1))
        for _ in range(200):
            k = int(rng.integers(1, 1 << bits)) if bits else 1
            values = (rng.random(k) * 10.0 ** rng.integers(-3, 4)).astype(np.float32)
            values[rng.random(k) < 0.3] = values[0]  # exact ties
            got = tagged_min(values, keep)
            label = int(np.float32(got).view(np.uint32)) & ((1 << bits) - 1)
            lowest = values.min()
            # Within 2^bits ulps of the true minimum, labelled by a candidate holding it
            # (the lowest-numbered one, unless tagging reordered values closer than that).
            assert abs(float(got) - float(lowest)) <= 2.0 ** (bits - 23) * float(lowest)
            assert abs(float(values[label]) - float(lowest)) <= 2.0 ** (bits - 22) * float(lowest)
            if np.all((values == lowest) | (values > lowest * (1 + 2.0 ** (bits - 21)))):
                assert label == int(np.argmax(values == lowest))


def test_search_tables_give_every_edge_its_own_reading_and_pass_1_every_edge_once():
    from graphsvc.sensors.accelerometer import GRAVITY
    from graphsvc.strategies.viterbi.tables import float32_tables, search_tables

    g = shared_reading_graph(np.random.default_rng(3))
    tables, pass1 = search_tables(g), float32_tables(g)
    N, E = g.num_nodes, g.num_edges
    readings = tables["readings_t"].T[tables["edge_reading"]]  # each edge's column
    expected = (g.edge_acc.reshape(E, -1).astype(np.float64) / GRAVITY).astype(np.float32)
    np.testing.assert_array_equal(readings, expected)
    dst = np.repeat(np.arange(N), np.diff(g.incoming))
    shared = tables["edge_shared"]
    assert 0.7 < shared.mean() < 0.95  # most edges share their node's reading, not all
    # a shared edge's column is its destination's layout position
    np.testing.assert_array_equal(tables["edge_reading"][shared], tables["node_pos"][dst[shared]])
    # pass 1 sees each edge once, at its destination's position, labelled with its arrival
    seen = []
    chunk_nodes, slots = pass1["chunk_nodes"].astype(np.int64), pass1["shared_slots"].astype(np.int64)
    for c in range(len(chunk_nodes) - 1):
        for j in range(slots.shape[1] - 1):
            for i in range(slots[c, j], slots[c, j + 1]):
                seen.append((chunk_nodes[c] + i - slots[c, j], pass1["shared_src"][i], pass1["shared_arrival"][i]))
    seen += zip(pass1["own_pos"], pass1["own_src"], pass1["own_arrival"])
    position = tables["node_pos"][dst]
    arrival = np.arange(E) - g.incoming[dst]
    assert sorted((int(p), int(m), int(a)) for p, m, a in seen) == sorted(
        zip(position.tolist(), g.edge_src.tolist(), arrival.tolist())
    )
    assert pass1["own_bounds"][-1] == len(pass1["own_src"]) == E - shared.sum()


@pytest.mark.parametrize("seed", range(2))
def test_float32_pass_eight_wide_equals_float64_search_on_a_built_like_graph(seed):
    rng = np.random.default_rng(20 + seed)
    g = shared_reading_graph(rng)
    T = 40
    meas = g.edge_acc[rng.integers(0, g.num_edges, T)] + rng.normal(0, 2.0, (T, 2, 3))
    meas[rng.random((T, 2)) < 0.05] = np.nan
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    allowed = rng.random(g.num_nodes) < 0.9
    none = [None] * T
    _lockstep(g, meas, none, none, Weights(1, 0, 0), allowed)
    _lockstep(g, meas, position, heading, Weights(0.5, 1, 1), allowed)


def _keep_two_scalar_and_eight_wide(placed):
    """Two kernels over one run of slot entries: `_keep_two` one entry at a time with
    pass 1's float32 arithmetic, and the eight-wide intrinsic."""
    from graphsvc.strategies.viterbi.costs import RC32, _place_terms
    from graphsvc.strategies.viterbi.dense import _keep_two
    from graphsvc.strategies.viterbi.intrinsics import keep_two_gathered8, keep_two_placed8
    from graphsvc.strategies.viterbi.intrinsics import tag as _tag

    @numba.njit
    def scalar(best, second, rel, c32, src, labels, offset, turn, extra, w, keep):
        for i in range(src.shape[0]):
            m = src[i]
            if placed:
                pos, head = _place_terms(rel[m, 0], rel[m, 1], rel[m, 2], offset[i, 0], offset[i, 1], turn[i])
                t = rel[m, RC32] + w[0] * extra[i] + w[1] * pos + w[2] * head
            else:
                t = c32[m] + w[0] * extra[i]
            _keep_two(best, second, i, _tag(t, keep, labels[i]))

    @numba.njit
    def wide(best, second, rel, c32, src, labels, offset, turn, extra, w, keep):
        for i in range(0, src.shape[0], 8):
            u = np.uint64(i)
            if placed:
                keep_two_placed8(best, second, u, rel, src, u, offset, turn, extra, w[0], w[1], w[2], keep, labels)
            else:
                keep_two_gathered8(best, second, u, c32, src, u, extra, w[0], keep, labels)

    return scalar, wide


@pytest.mark.parametrize("placed", [False, True])
def test_eight_wide_candidates_equal_the_scalar_loop_bit_for_bit(placed):
    scalar, wide = _keep_two_scalar_and_eight_wide(placed)
    rng = np.random.default_rng(4)
    R, n = 500, 64
    rel = np.empty((R, 4), np.float32)
    rel[:, :2] = rng.normal(0, 3, (R, 2))
    rel[:, 2] = rng.uniform(-3.2, 3.2, R)  # wrapped heading differences, a few past ±π after a turn
    rel[:, 3] = rng.random(R) * 50
    c32 = (rng.random(R) * 50).astype(np.float32)
    w = np.array([0.5, 1.0, 2.0], np.float32)
    keep = np.uint32(0xFFFFFFF0)
    for labels_dtype in (np.uint8, np.uint16):
        for _ in range(20):
            src = rng.integers(0, R, n).astype(np.uint32)
            labels = rng.integers(0, 15, n).astype(labels_dtype)
            offset = rng.normal(0, 0.1, (n, 2)).astype(np.float32)
            turn = rng.normal(0, 0.5, n).astype(np.float32)
            extra = (rng.random(n) * 5).astype(np.float32)
            start = (rng.random(n) * 60).astype(np.float32)
            start[rng.random(n) < 0.3] = np.float32(1e38)  # no candidate yet
            out = []
            for kernel in (scalar, wide):
                best, second = start.copy(), np.full(n, np.float32(1e38))
                second[::3] = start[::3] + np.float32(1.0)
                kernel(best, second, rel, c32, src, labels, offset, turn, extra, w, keep)
                out.append((best.view(np.uint32), second.view(np.uint32)))
            np.testing.assert_array_equal(out[0][0], out[1][0])
            np.testing.assert_array_equal(out[0][1], out[1][1])
    from numba.core.registry import cpu_target

    if not placed and "+avx2" in cpu_target.target_context.codegen()._tm_features.split(","):
        assert "vgatherdps" in "".join(wide.inspect_asm().values())  # the gather path is the one run here


def test_eight_wide_candidates_without_avx2_load_one_by_one_and_agree(tmp_path):
    # A target without AVX2 (NUMBA_CPU_FEATURES) gets eight loads instead of vgatherdps,
    # with the same values.
    import subprocess
    import sys

    from numba.core.registry import cpu_target

    features = cpu_target.target_context.codegen()._tm_features
    if "+avx2" not in features.split(","):
        pytest.skip("this machine has no AVX2: the gather path is the one not tested")
    code = (
        "import numpy as np, sys\n"
        "sys.path.insert(0, '.')\n"
        "from tests.search.test_float32_pass import test_eight_wide_candidates_equal_the_scalar_loop_bit_for_bit as t\n"
        "from tests.search.test_float32_pass import _keep_two_scalar_and_eight_wide as k\n"
        "t(False)\n"
        "scalar, wide = k(False)\n"
        "asm = ''.join(wide.inspect_asm().values())\n"
        "print('vgatherdps' in asm, 'vpgatherdd' in asm)\n"
    )
    env = {
        "NUMBA_CPU_FEATURES": features.replace("+avx2", "-avx2"),
        "NUMBA_CACHE_DIR": str(tmp_path),
        "PATH": "/usr/bin:/bin",
    }
    root = str(__import__("pathlib").Path(__file__).resolve().parents[2])
    done = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["False", "False"]


def test_a_short_batch_search_makes_only_the_rows_it_fills_and_finds_the_same_path(monkeypatch):
    # An input too short to fill a block of the batch ring never flushes it: one row a
    # sample is enough, and the search must be the one the full ring gives.
    from graphsvc.strategies.viterbi import batch as V

    rng = np.random.default_rng(7)
    g = random_graph(rng, N=60, out=4)
    T = 40
    acc = rng.normal(0, 9.81, (T, 2, 3))
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    made = []
    original = V.ViterbiSearch.__init__

    def recording(self, *args, **kwargs):
        original(self, *args, **kwargs)
        made.append(self)

    monkeypatch.setattr(V.ViterbiSearch, "__init__", recording)
    short = V.viterbi_search(g, acc, position, heading, Weights(0.5, 1, 1))
    assert made[-1].arrivals.shape[0] == T
    scale = V.ViterbiSearch.BATCH_RING_SCALE
    full_ring = (scale * V.ViterbiSearch.BLOCK, scale * V.ViterbiSearch.STORE_WINDOW)
    assert V.batch_ring(full_ring[0]) == (full_ring[0], 0) and V.batch_ring(full_ring[0] + 1) == full_ring
    monkeypatch.setattr(V, "batch_ring", lambda samples: full_ring)
    full = V.viterbi_search(g, acc, position, heading, Weights(0.5, 1, 1))
    assert made[-1].arrivals.shape[0] == sum(full_ring)
    np.testing.assert_array_equal(short.node_path, full.node_path)
    np.testing.assert_array_equal(short.edge_path, full.edge_path)
    assert (short.cost, short.compression, short.peak_entries) == (full.cost, full.compression, full.peak_entries)
    np.testing.assert_array_equal(short.terms, full.terms)
