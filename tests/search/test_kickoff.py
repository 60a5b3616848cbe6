"""A bounded live search (FixedLagDecoder's `max_live`: the kick-off of many live streams
at once): the bound keeps exactly the cheapest paths, ties to the lower node and always
one that can go on; the seed where it starts is the sources of the edges whose readings
fit the sample best; a bounded decoder never holds more paths than its bound, keeps the
search's invariants, and with a bound holding every node gives the unbounded decoder's
frames bit for bit."""

import numpy as np
import pytest

from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.beam import _bound_live
from graphsvc.strategies.viterbi.costs import COST, DEAD32
from graphsvc.strategies.viterbi.search import ViterbiSearch
from graphsvc.strategies.viterbi.stream import FixedLagDecoder
from tests.search.problems import random_graph

PLACED, UNPLACED = Weights(0.5, 1, 1), Weights(1, 0, 0)


def _inputs(rng, g, T):
    meas = g.edge_acc[rng.integers(0, g.num_edges, T)] + rng.normal(0, 3.0, (T, g.edge_acc.shape[1], 3))
    meas[rng.random((T, meas.shape[1])) < 0.1] = np.nan
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    return meas, position, heading


@pytest.mark.parametrize("seed", range(4))
def test_the_bound_keeps_the_cheapest_paths_ties_to_the_lower_node_and_one_that_can_go_on(seed):
    rng = np.random.default_rng(seed)
    N, most = 200, 25
    state = np.zeros((N, 6))
    state[:, COST] = np.inf
    live = np.sort(rng.choice(N, 120, replace=False)).astype(np.int32)
    state[live, COST] = rng.integers(0, 30, live.size).astype(float)  # (many ties)
    immortal = np.zeros(N, dtype=bool)
    if seed % 2:  # only expensive nodes can go on: the cheapest of them is kept too
        immortal[live[state[live, COST] > 20]] = True
    else:
        immortal[live] = rng.random(live.size) < 0.5
    arrivals = np.zeros(N, dtype=np.uint8)
    c32 = np.zeros(N, dtype=np.float32)
    # reference: by (cost, node), the first `most`; the cheapest immortal (lowest node) if none of them is
    order = sorted(live.tolist(), key=lambda n: (state[n, COST], n))
    want = set(order[:most])
    if not immortal[list(want)].any() and immortal[live].any():
        want.add(min((n for n in live if immortal[n]), key=lambda n: (state[n, COST], n)))
    before = state[:, COST].copy()
    kept = _bound_live(state, live, live.size, most, immortal, arrivals, np.uint8(255), c32)
    assert kept == len(want)
    np.testing.assert_array_equal(live[:kept], sorted(want))
    dropped = np.setdiff1d(np.flatnonzero(np.isfinite(before)), sorted(want))
    assert np.isinf(state[dropped, COST]).all() and (arrivals[dropped] == 255).all() and (c32[dropped] == DEAD32).all()
    np.testing.assert_array_equal(state[sorted(want), COST], before[sorted(want)])
    assert (arrivals[sorted(want)] == 0).all()


def test_the_seed_is_the_sources_of_the_edges_whose_readings_fit_best():
    rng = np.random.default_rng(3)
    g = random_graph(rng, N=80, out=3)
    allowed = rng.random(g.num_nodes) < 0.9
    search = ViterbiSearch(g, PLACED, allowed=allowed, beam=5.0)
    acc = g.edge_acc[7] + rng.normal(0, 1.0, g.edge_acc.shape[1:])
    acc[0] = np.nan  # (a sensor missing: the mean over those present, eq. 4)
    # C_A in float64 (Kelly et al. 2013, eq. 4): mean over present sensors of |r − m|² in g
    d = (g.edge_acc[:, 1:] - acc[None, 1:]) / GRAVITY
    cost = (d * d).sum(axis=(1, 2)) / (acc.shape[0] - 1)
    usable = allowed[g.edge_src] & allowed[g.edge_dst]
    cost[~usable] = np.inf
    ranked = np.argsort(cost, kind="stable")
    for most in (1, 10, 40):
        assert cost[ranked[most]] - cost[ranked[most - 1]] > 1e-4  # (no near-tie at the cut: float32 agrees)
        want = np.zeros(g.num_nodes, dtype=bool)
        want[g.edge_src[ranked[:most]]] = True
        np.testing.assert_array_equal(search.seed(acc, most), want)
    everything = np.zeros(g.num_nodes, dtype=bool)
    everything[g.edge_src[usable]] = True
    np.testing.assert_array_equal(search.seed(acc, 10**6), everything)


@pytest.mark.parametrize("weights", [PLACED, UNPLACED])
def test_a_bounded_search_holds_at_most_its_bound_and_keeps_the_searchs_invariants(weights):
    rng = np.random.default_rng(11)
    g = random_graph(rng, N=300, out=3)
    meas, position, heading = _inputs(rng, g, 60)
    unbounded = FixedLagDecoder(g, weights, lag=5, threads=False, beam=20.0, start_samples=10)
    decoder = FixedLagDecoder(g, weights, lag=5, threads=False, beam=20.0, start_samples=10, max_live=12)
    search = decoder.search
    lives, out = [], []
    step = search.step

    def counted(*args, **kwargs):
        step(*args, **kwargs)
        live = search._live[: search._n_live]
        lives.append(len(live))
        np.testing.assert_array_equal(np.flatnonzero(np.isfinite(search.state[:, COST])), live)
        row = search.arrivals[(search.first + search.used - 1) % search.arrivals.shape[0]]
        np.testing.assert_array_equal(np.flatnonzero(row != search.none), live)

    search.step = counted
    most = 0
    for t in range(len(meas)):
        out.append(decoder.push(meas[t], position[t], heading[t])[0])
        unbounded.push(meas[t], position[t], heading[t])
        most = max(most, unbounded.search._n_live)
    out.append(decoder.flush()[0])
    nodes = np.concatenate(out)
    assert len(nodes) == len(meas)
    assert max(lives) <= 12 < most  # (the beam alone keeps more)
    assert np.isfinite(search.cost[nodes[-1]])


def test_a_bound_holding_every_node_gives_the_unbounded_decoders_frames():
    rng = np.random.default_rng(2)
    g = random_graph(rng, N=70, out=3)
    meas, position, heading = _inputs(rng, g, 70)
    decoders = [
        FixedLagDecoder(g, PLACED, lag=6, threads=False, beam=8.0, start_samples=12, max_live=k)
        for k in (0, g.num_nodes)
    ]
    for t in range(len(meas)):
        a, b = (d.push(meas[t], position[t], heading[t]) for d in decoders)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
    for x, y in zip(*(d.flush() for d in decoders)):
        np.testing.assert_array_equal(x, y)
    assert decoders[1].search.max_live == g.num_nodes and decoders[0].search.max_live is None


@pytest.mark.parametrize("catch_up,lag,T", [(1, 6, 70), (3, 6, 70), (4, 0, 70), (2, 6, 14), (3, 2, 8)])
def test_a_start_caught_up_over_several_pushes_gives_the_same_frames_a_few_steps_a_push(catch_up, lag, T):
    rng = np.random.default_rng(5)
    g = random_graph(rng, N=90, out=3)
    meas, position, heading = _inputs(rng, g, T)
    start = 12
    whole = FixedLagDecoder(g, PLACED, lag=lag, threads=False, beam=8.0, start_samples=start, max_live=20)
    spread = FixedLagDecoder(
        g, PLACED, lag=lag, threads=False, beam=8.0, start_samples=start, max_live=20, catch_up=catch_up
    )
    steps = [0]
    step = spread.search.step

    def counted(*args, **kwargs):
        steps[0] += 1
        step(*args, **kwargs)

    spread.search.step = counted
    want, got, per_push = [], [], []
    for t in range(T):
        want.append(whole.push(meas[t], position[t], heading[t]))
        before = steps[0]
        got.append(spread.push(meas[t], position[t], heading[t]))
        per_push.append(steps[0] - before)
    want.append(whole.flush())
    got.append(spread.flush())
    for k in (0, 1):
        np.testing.assert_array_equal(np.concatenate([w[k] for w in want]), np.concatenate([o[k] for o in got]))
    assert sum(len(o[0]) for o in got) == T
    # before the start nothing, then at most catch_up samples a push (the start's own
    # sample 0 is no step), until the search has caught up: one a push
    assert per_push[: start - 1] == [0] * min(T, start - 1)
    assert max(per_push) <= catch_up
    if T >= start + (start - 1) // max(1, catch_up - 1) + 1:
        assert spread.search.t == T - 1 and not spread._pending
        assert per_push[-1] == 1
    # a frame is released no earlier than by the whole start's push
    released = np.cumsum([len(o[0]) for o in got[:T]])
    assert (released <= np.cumsum([len(w[0]) for w in want[:T]])).all()
