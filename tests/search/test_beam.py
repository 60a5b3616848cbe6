"""The beam search (ViterbiSearch's `beam`): with an infinite beam it is the exact search,
bit for bit; with a finite one it keeps exactly the paths its rule keeps, and never lets
every path run into a dead end while one can go on."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.batch import viterbi_search
from graphsvc.strategies.viterbi.beam import _immortal
from graphsvc.strategies.viterbi.costs import COST
from graphsvc.strategies.viterbi.search import ViterbiSearch
from graphsvc.strategies.viterbi.stream import FixedLagDecoder
from tests.search.problems import random_graph, tiny_graph

PLACED, UNPLACED = Weights(0.5, 1, 1), Weights(1, 0, 0)
# (BEAM_DENSE_SHARE, BEAM_SPARSE_SHARE) making every step sparse, every step the exact
# passes and a cut, or the class's own choice (sparse when few are live, timed between)
SPARSE, DENSE, OWN = (2.0, 2.0), (-1.0, -1.0), (ViterbiSearch.BEAM_DENSE_SHARE, ViterbiSearch.BEAM_SPARSE_SHARE)


def _steps(monkeypatch, shares):
    monkeypatch.setattr(ViterbiSearch, "BEAM_DENSE_SHARE", shares[0])
    monkeypatch.setattr(ViterbiSearch, "BEAM_SPARSE_SHARE", shares[1])


def _inputs(rng, g, T):
    """Readings near the graph's own (so costs spread as on real data), with gaps;
    a ground track and heading with gaps."""
    meas = g.edge_acc[rng.integers(0, g.num_edges, T)] + rng.normal(0, 3.0, (T, g.edge_acc.shape[1], 3))
    meas[rng.random((T, meas.shape[1])) < 0.1] = np.nan
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    position[rng.random(T) < 0.1] = np.nan
    heading[rng.random(T) < 0.1] = np.nan
    return meas, position, heading


def _run(search, meas, position, heading):
    search.start(position[0], heading[0])
    for t in range(1, len(meas)):
        search.step(meas[t], position[t], heading[t])
    best = search.best_node()
    nodes, edges = search.trace(best)
    return nodes, edges, search.cost[best]


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("threads", [True, False])
@pytest.mark.parametrize("steps", [SPARSE, DENSE], ids=["sparse", "dense"])
def test_an_infinite_beam_is_the_exact_search_bit_for_bit(seed, threads, steps, monkeypatch):
    _steps(monkeypatch, steps)
    rng = np.random.default_rng(seed)
    g = random_graph(rng, N=60, out=4)
    meas, position, heading = _inputs(rng, g, 90)
    allowed = rng.random(g.num_nodes) < 0.85
    for weights, pull_s in ((UNPLACED, None), (PLACED, None), (PLACED, 0.2)):
        searches = [
            ViterbiSearch(g, weights, 0, allowed, threads, ring=(16, 8), beam=beam, pull_s=pull_s)
            for beam in (None, np.inf)
        ]
        (exact_nodes, exact_edges, exact_cost), (nodes, edges, cost) = (
            _run(s, meas, position, heading) for s in searches
        )
        np.testing.assert_array_equal(nodes, exact_nodes)
        np.testing.assert_array_equal(edges, exact_edges)
        assert cost == exact_cost  # (bit for bit)
        assert searches[1].compression == searches[0].compression


def test_an_infinite_beam_streams_the_exact_decoders_frames():
    rng = np.random.default_rng(7)
    g = random_graph(rng, N=50, out=3)
    meas, position, heading = _inputs(rng, g, 80)
    decoders = [FixedLagDecoder(g, PLACED, lag=5, threads=False, beam=beam) for beam in (None, np.inf)]
    for t in range(len(meas)):
        out = [d.push(meas[t], position[t], heading[t]) for d in decoders]
        for a, b in zip(*out):
            np.testing.assert_array_equal(a, b)
    for a, b in zip(*(d.flush() for d in decoders)):
        np.testing.assert_array_equal(a, b)


def _graph_with_dead_ends(rng):
    """random_graph with a third of the nodes' outgoing edges removed: dead ends, and
    nodes whose every path runs into one."""
    g = random_graph(rng, N=45, out=3)
    cut = rng.random(g.num_nodes) < 0.3
    keep = ~cut[g.edge_src]
    return tiny_graph(
        g.edge_src[keep], g.edge_dst[keep], g.edge_acc[keep], offsets=g.edge_offset[keep], dheading=g.edge_heading[keep]
    )


@pytest.mark.parametrize("weights", [UNPLACED, PLACED])
@pytest.mark.parametrize("steps", [SPARSE, DENSE, OWN], ids=["sparse", "dense", "own"])
def test_a_step_keeps_exactly_the_paths_within_the_beam_of_the_best_that_can_go_on(weights, steps, monkeypatch):
    # Each step checked against the exact search's step from the same paths (a
    # constrained search's float64 passes, fed the beam search's states): the beam keeps
    # the nodes whose cost is within the beam of the cheapest immortal node's, whether
    # it steps sparsely or by the exact passes and a cut.
    _steps(monkeypatch, steps)
    rng = np.random.default_rng(3)
    g = _graph_with_dead_ends(rng)
    meas, position, heading = _inputs(rng, g, 60)
    immortal = _immortal(np.asarray(g.incoming, np.int32), np.asarray(g.edge_src, np.int32), np.ones(g.num_nodes, bool))
    assert 0 < immortal.sum() < g.num_nodes
    beam = 0.8
    search = ViterbiSearch(g, weights, beam=beam, placed=True)
    exact = ViterbiSearch(g, weights, gamma=1, placed=True)  # (a constraint always met: the float64 passes)
    free = np.zeros(1, np.int64)
    search.start(position[0], heading[0])
    exact.start(position[0], heading[0], free, free)
    narrowed = 0
    for t in range(1, len(meas)):
        exact.state[:], exact.det[:] = search.state, search.det
        exact.step(meas[t], position[t], heading[t], free, free)
        search.step(meas[t], position[t], heading[t])
        candidates = exact.cost
        limit = candidates[np.isfinite(candidates) & immortal].min() + beam
        kept = candidates <= limit
        np.testing.assert_array_equal(np.isfinite(search.cost), kept)
        np.testing.assert_array_equal(search.cost[kept], candidates[kept])
        narrowed += np.isfinite(candidates).sum() > kept.sum()
        assert immortal[kept].any()
    assert narrowed > 10  # the beam did cut


def test_the_beam_keeps_a_path_that_can_go_on_when_the_cheapest_runs_into_a_dead_end():
    # 0 → 1 → 2 is free but ends at 2; 0 → 3 ↺ 3 costs 1 a sample and goes on forever.
    # A beam of 0.01 around the cheapest path alone would drop 3 at the first sample
    # and have no path left at the third.
    src, dst = [0, 1, 0, 3], [1, 2, 3, 3]
    acc = np.zeros((4, 1, 3))
    acc[2:, 0, 0] = GRAVITY  # C_A 1 g² a sample against the zero measurements
    g = tiny_graph(src, dst, acc)
    meas = np.zeros((5, 1, 3))
    result = viterbi_search(g, meas, weights=UNPLACED, beam=0.01)
    exact = viterbi_search(g, meas, weights=UNPLACED)
    np.testing.assert_array_equal(result.node_path, exact.node_path)
    assert result.node_path[-1] == 3
    assert result.cost == exact.cost == 4.0


def test_beam_is_refused_unless_a_positive_cost_without_constraint_sets():
    g = random_graph(np.random.default_rng(0), N=10)
    meas = np.zeros((3, 2, 3))
    for beam in (0.0, -1.0, np.nan):
        with pytest.raises(InputError, match="beam"):
            viterbi_search(g, meas, beam=beam)
    sets = [[{"start_s": 0.0, "end_s": 0.05, "require": {"contact": "both"}}]]
    with pytest.raises(InputError, match="constraint sets"):
        viterbi_search(g, meas, constraint_sets=sets, beam=1.0)


@pytest.mark.parametrize("steps", [SPARSE, DENSE, OWN], ids=["sparse", "dense", "own"])
def test_a_beam_search_keeps_every_dead_node_at_cost_inf_and_without_arrival(steps, monkeypatch):
    # The dense invariants other parts read (flush, trace, best node): every node not
    # live has cost inf and arrival `none`, at every sample, in both state buffers'
    # turns; the live list is ascending.
    _steps(monkeypatch, steps)
    rng = np.random.default_rng(5)
    g = random_graph(rng, N=60, out=3)
    meas, position, heading = _inputs(rng, g, 50)
    search = ViterbiSearch(g, PLACED, beam=0.5, ring=(8, 4))
    search.start(position[0], heading[0])
    for t in range(1, len(meas)):
        search.step(meas[t], position[t], heading[t])
        live = search._live[: search._n_live]
        assert np.all(np.diff(live) > 0)
        np.testing.assert_array_equal(np.flatnonzero(np.isfinite(search.state[:, COST])), live)
        np.testing.assert_array_equal(
            np.flatnonzero(search.arrivals[(search.first + search.used - 1) % search.arrivals.shape[0]] != search.none),
            live,
        )
        assert len(live) < g.num_nodes


@pytest.mark.parametrize("weights", [UNPLACED, PLACED])
def test_sparse_and_dense_beam_steps_agree_and_may_alternate(weights, monkeypatch):
    # The same beam search stepped sparsely throughout, densely throughout, and switching
    # by the live share (with the unplaced float32 costs rebased at each switch): the same
    # live nodes and costs at every sample, the same path.
    rng = np.random.default_rng(11)
    g = random_graph(rng, N=80, out=3)
    meas, position, heading = _inputs(rng, g, 70)
    runs = []
    for steps in (SPARSE, DENSE, (0.1, 0.1)):
        _steps(monkeypatch, steps)
        search = ViterbiSearch(g, weights, beam=3.0, ring=(16, 8))
        search.start(position[0], heading[0])
        costs, shares = [], []
        for t in range(1, len(meas)):
            shares.append(search._n_live / g.num_nodes)
            search.step(meas[t], position[t], heading[t])
            costs.append(search.cost.copy())
        best = search.best_node()
        runs.append((np.array(costs), search.trace(best)[0], shares))
    (sparse, sparse_path, _), (dense, dense_path, _), (mixed, mixed_path, shares) = runs
    shares = np.array(shares)
    assert np.sum((shares[:-1] <= 0.1) & (shares[1:] > 0.1)) >= 2  # from sparse steps back to dense ones
    np.testing.assert_array_equal(dense, sparse)
    np.testing.assert_array_equal(mixed, sparse)
    np.testing.assert_array_equal(dense_path, sparse_path)
    np.testing.assert_array_equal(mixed_path, sparse_path)


def test_between_the_shares_a_beam_search_steps_the_way_its_past_steps_predict_is_faster():
    g = random_graph(np.random.default_rng(2), N=100)
    search = ViterbiSearch(g, UNPLACED, beam=1.0)
    N = g.num_nodes
    few, some, most = int(ViterbiSearch.BEAM_DENSE_SHARE * N), N // 4, int(ViterbiSearch.BEAM_SPARSE_SHARE * N) + 1
    search._step_seconds = (1e-3, 1e-6)  # sparse steps 1 ms a live node, dense 1 µs: dense looks faster
    search._n_live = few
    assert search.narrow  # few live: always sparse
    search._n_live = most
    assert not search.narrow  # most live: always dense
    search._n_live = some
    assert not search.narrow
    search._step_seconds = (1e-9, 1e-3)
    assert search.narrow
    search._step_seconds = (None, 1e-3)  # sparse not tried yet in this range
    assert search.narrow
    search._step_seconds = (1e-9, None)
    assert not search.narrow
    search._time_beam_step(True, 2e-3, 1000)  # running means: a quarter of the newest
    assert search._step_seconds[0] == pytest.approx(0.75e-9 + 0.25 * 2e-6)
    search._time_beam_step(False, 4e-3, 0)
    assert search._step_seconds[1] == pytest.approx(4e-3)
    assert not ViterbiSearch(g, UNPLACED).narrow  # the exact search


def test_narrow_steps_on_a_large_graph_reset_only_their_rows_survivors(monkeypatch):
    # Few live paths among many nodes: a sparse step lists the nodes it reaches by sorting
    # them (not a scan of every node's mark) and resets only the entries an earlier beam
    # step left in its lattice row. The same costs and path as the exact passes and a
    # cut, sample by sample, and every row reused from the ring holds exactly the live
    # nodes' arrivals.
    from graphsvc.strategies.viterbi.beam import MARKS_SCAN_SHARE

    rng = np.random.default_rng(21)
    g = random_graph(rng, N=6000, out=3)
    meas, position, heading = _inputs(rng, g, 60)
    runs = []
    for steps in (SPARSE, DENSE):
        _steps(monkeypatch, steps)
        search = ViterbiSearch(g, PLACED, beam=5.0, ring=(8, 4))
        search.max_live = 8
        search.start(position[0], heading[0])
        costs = []
        for t in range(1, len(meas)):
            search.step(meas[t], position[t], heading[t])
            live = search._live[: search._n_live]
            row = search.arrivals[(search.first + search.used - 1) % search.arrivals.shape[0]]
            np.testing.assert_array_equal(np.flatnonzero(row != search.none), live)
            assert 3 * len(live) * MARKS_SCAN_SHARE < g.num_nodes  # (the sort, not the scan)
            costs.append(search.cost.copy())
        runs.append((np.array(costs), search.trace(search.best_node())[0]))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
