"""Streaming decoders: fixed-lag output against independent prefix searches, the
converged-prefix commit, streaming = batch once flushed, sliding windows."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.search.stream import FixedLagDecoder, SlidingWindowDecoder, decode_stream
from graphsvc.search.viterbi import ViterbiSearch, Weights, viterbi_search
from tests.search.test_viterbi import random_graph


def _problem(seed, T=70):
    rng = np.random.default_rng(seed)
    g = random_graph(rng)
    meas = rng.normal(0, 9.81, (T, 2, 3))
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    return g, meas, position, heading


@pytest.mark.parametrize("seed", range(3))
def test_flushed_stream_equals_batch_search(seed):
    g, meas, position, heading = _problem(seed)
    w = Weights(0.5, 1, 1)
    batch = viterbi_search(g, meas, position, heading, w)
    # A lag longer than the input emits everything at flush: the batch path exactly.
    nodes, edges = decode_stream(FixedLagDecoder(g, w, lag=len(meas)), meas, position, heading)
    np.testing.assert_array_equal(nodes, batch.node_path)
    np.testing.assert_array_equal(edges[1:], batch.edge_path)
    assert edges[0] == -1


@pytest.mark.parametrize("lag", [0, 3, 40])
def test_fixed_lag_emits_frame_t_minus_lag_of_the_best_prefix_path(lag):
    g, meas, position, heading = _problem(7)
    w = Weights(0.5, 1, 1)
    T = len(meas)
    decoder = FixedLagDecoder(g, w, lag=lag)
    emitted = []
    for t in range(T):
        nodes, _ = decoder.push(meas[t], position[t], heading[t])
        emitted.extend(nodes.tolist())
        # Independently: the best path over samples 0..t from a fresh batch search.
        assert len(emitted) >= t + 1 - lag
        if t >= lag:
            # Frame t−lag is the best prefix path's — whether the lag ran out now or all
            # survivors agreed on it earlier (then every later path passes through it).
            prefix = viterbi_search(g, meas[: t + 1], position[: t + 1], heading[: t + 1], w).node_path
            assert emitted[t - lag] == prefix[t - lag]
    nodes, _ = decoder.flush()
    emitted.extend(nodes.tolist())
    assert len(emitted) == T
    # The frames decided at flush are the full search's.
    np.testing.assert_array_equal(emitted[T - lag :], viterbi_search(g, meas, position, heading, w).node_path[T - lag :])


def test_converged_prefix_is_emitted_before_its_lag():
    # Paths through a random graph merge: once all survivors share a prefix it is
    # final and comes out long before the (huge) lag.
    g, meas, position, heading = _problem(5, T=200)
    w = Weights(1, 0, 0)
    decoder = FixedLagDecoder(g, w, lag=10_000)
    out = []
    for t in range(len(meas)):
        out.extend(decoder.push(meas[t])[0].tolist())
    assert decoder.converged_frames == len(out) > 0
    out.extend(decoder.flush()[0].tolist())
    assert decoder.revisions == 0  # an agreed prefix is never revised
    np.testing.assert_array_equal(out, viterbi_search(g, meas, weights=w).node_path)


def test_sliding_window_matches_a_fresh_search_over_each_window():
    g, meas, position, heading = _problem(3, T=30)
    w = Weights(0.5, 1, 1)
    window, lag = 8, 2
    decoder = SlidingWindowDecoder(g, w, window=window, lag=lag)
    emitted = []
    for t in range(len(meas)):
        nodes, _ = decoder.push(meas[t], position[t], heading[t])
        emitted.extend(nodes.tolist())
        if t >= lag:
            lo = max(0, t - window + 1)
            fresh = viterbi_search(g, meas[lo : t + 1], position[lo : t + 1], heading[lo : t + 1], w).node_path
            assert emitted[t - lag] == fresh[t - lag - lo]
    emitted.extend(decoder.flush()[0].tolist())
    assert len(emitted) == len(meas)
    with pytest.raises(InputError, match="window"):
        SlidingWindowDecoder(g, w, window=3, lag=2)


def test_trace_walks_the_block_and_the_store_alike():
    g, meas, position, heading = _problem(11, T=150)  # several compactions
    s = ViterbiSearch(g, Weights(0.5, 1, 1))
    s.start(position[0], heading[0])
    for t in range(1, len(meas)):
        s.step(meas[t], position[t], heading[t])
    best = s.best_node()
    nodes, edges = s.trace_arrivals(best)
    tail, tail_edges = s.trace_arrivals(best, since=100)
    np.testing.assert_array_equal(tail, nodes[100:])
    np.testing.assert_array_equal(tail_edges, edges[100:])
    np.testing.assert_array_equal(g.edge_dst[edges[1:]], nodes[1:])
    np.testing.assert_array_equal(g.edge_src[edges[1:]], nodes[:-1])
    with pytest.raises(InputError):
        s.trace_arrivals(best, since=len(meas))
