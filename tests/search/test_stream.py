"""Streaming decoders: fixed-lag output against independent prefix searches, the
converged-prefix commit, streaming = batch once flushed, sliding windows."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.batch import viterbi_search
from graphsvc.strategies.viterbi.search import ViterbiSearch
from graphsvc.strategies.viterbi.stream import FixedLagDecoder, SlidingWindowDecoder, decode_stream
from tests.search.problems import random_walk_problem


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("unmeasured", [0, 4])
def test_flushed_stream_equals_batch_search(seed, unmeasured, ring):
    g, meas, position, heading = random_walk_problem(seed)
    position[:unmeasured] = np.nan  # paths start at the first measured position and heading
    heading[: unmeasured // 2] = np.nan
    w = Weights(0.5, 1, 1)
    batch = viterbi_search(g, meas, position, heading, w)
    # A lag longer than the input emits everything at flush: the batch path exactly.
    nodes, edges = decode_stream(FixedLagDecoder(g, w, lag=len(meas)), meas, position, heading)
    np.testing.assert_array_equal(nodes, batch.node_path)
    np.testing.assert_array_equal(edges[1:], batch.edge_path)
    assert edges[0] == -1


@pytest.mark.parametrize("lag", [0, 3, 40])
def test_fixed_lag_emits_frame_t_minus_lag_of_the_best_prefix_path(lag, ring):
    g, meas, position, heading = random_walk_problem(7)
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
    np.testing.assert_array_equal(
        emitted[T - lag :], viterbi_search(g, meas, position, heading, w).node_path[T - lag :]
    )


def test_converged_prefix_is_emitted_before_its_lag(ring):
    # Paths through a random graph merge: once all survivors share a prefix it is
    # final and comes out long before the (huge) lag. (Agreement is looked for whenever
    # the oldest dense rows move to the store: with the default ring, from sample 257.)
    g, meas, position, heading = random_walk_problem(5, T=300)
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
    g, meas, position, heading = random_walk_problem(3, T=30)
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


def test_trace_walks_the_dense_rows_and_the_store_alike(ring):
    g, meas, position, heading = random_walk_problem(11, T=150)  # several flushes with the small rings
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


def test_fixed_lag_decoder_forgets_emitted_survivors(ring):
    # After emitting frames the decoder lets the search drop their survivors: the store
    # then holds nothing older than the next frame to emit, tracing before it is refused,
    # and the output is that of a decoder which keeps everything.
    g, meas, position, heading = random_walk_problem(4, T=200)
    w = Weights(0.5, 1, 1)
    forgetful = FixedLagDecoder(g, w, lag=5, store=True)
    keeper = FixedLagDecoder(g, w, lag=5, store=True)
    keeper.search.forget_before = lambda t: None  # keeps every survivor
    out_f, out_k = [], []
    for t in range(len(meas)):
        out_f.append(forgetful.push(meas[t], position[t], heading[t])[0])
        out_k.append(keeper.push(meas[t], position[t], heading[t])[0])
    out_f.append(forgetful.flush()[0])
    out_k.append(keeper.flush()[0])
    np.testing.assert_array_equal(np.concatenate(out_f), np.concatenate(out_k))
    s, k = forgetful.search, keeper.search
    assert s.keep_from == len(meas) - 1  # everything emitted
    s._collect()  # a sweep now keeps no survivor older than the cutoff
    k._collect()
    assert s.size == 0 or s.store[: s.size, 3].min() >= s.keep_from  # (the newest samples sit in the dense rows)
    assert k.store[: k.size, 3].min() == 0 and k.size > s.size
    nodes, _ = s.trace_arrivals(s.best_node(), since=s.keep_from)
    np.testing.assert_array_equal(nodes, k.trace_arrivals(k.best_node(), since=s.keep_from)[0])
    with pytest.raises(InputError, match="forgotten"):
        s.trace_arrivals(s.best_node(), since=0)


@pytest.mark.parametrize("lag", [0, 3, 30, 64, 200])
def test_dense_window_decoder_equals_the_survivor_store_decoder(lag, ring):
    # Short lags keep only the last lag + 1 samples' back-pointers (no survivor store):
    # the frames must be those of the store-backed decoder, each out by its lag. (Frames
    # that all survivors agree on may come out earlier in either, at other moments: the
    # two look for agreement at different times.)
    g, meas, position, heading = random_walk_problem(12, T=260)  # the window slides several times
    w = Weights(0.5, 1, 1)
    dense = FixedLagDecoder(g, w, lag=lag)
    stored = FixedLagDecoder(g, w, lag=lag, store=True)
    assert dense.search.window == lag + 1 and stored.search.window is None
    out = {"dense": [], "stored": []}
    for t in range(len(meas)):
        for name, decoder in (("dense", dense), ("stored", stored)):
            out[name].extend(decoder.push(meas[t], position[t], heading[t])[0].tolist())
            assert len(out[name]) >= t + 1 - lag
    out["dense"].extend(dense.flush()[0].tolist())
    out["stored"].extend(stored.flush()[0].tolist())
    assert out["dense"] == out["stored"] and len(out["dense"]) == len(meas)
    if lag >= 30 and len(meas) > dense.search.arrivals.shape[0]:  # (looked for when the ring is full)
        assert dense.converged_frames > 0  # agreement is still found and committed early
    s = dense.search
    assert s.size == g.num_nodes  # only sample 0's rows: the store is never appended to
    with pytest.raises(InputError, match="forgotten"):
        s.trace_arrivals(s.best_node(), since=s.t - s.used)
