"""The Viterbi search against brute force, the full-lattice reference and crafted graphs."""

import itertools

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from graphsvc.errors import InputError
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.batch import viterbi_search
from graphsvc.strategies.viterbi.reference import reference_viterbi
from graphsvc.strategies.viterbi.search import ViterbiSearch
from tests.search.problems import path_cost, random_graph, random_up, random_walk_problem, tiny_graph


@st.composite
def random_problem(draw):
    N = draw(st.integers(2, 5))
    pairs = draw(
        st.lists(st.tuples(st.integers(0, N - 1), st.integers(0, N - 1)), min_size=N, max_size=12, unique=True)
    )
    src, dst = zip(*pairs)
    if len(set(dst)) < 1:
        src, dst = src + (0,), dst + (0,)
    S = draw(st.integers(1, 2))
    T = draw(st.integers(2, 5))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    acc = rng.normal(0, 9.81, (len(src), S, 3))
    meas = rng.normal(0, 9.81, (T, S, 3))
    return src, dst, acc, meas


@settings(max_examples=80, deadline=None)
@given(random_problem())
def test_accelerometer_only_equals_brute_force(problem):
    src, dst, acc, meas = problem
    g = tiny_graph(src, dst, acc)
    T, N = meas.shape[0], g.num_nodes
    best = None
    for nodes in itertools.product(range(N), repeat=T):
        c = path_cost(g, nodes, meas)
        if c is not None and (best is None or c < best):
            best = c
    if best is None:
        with pytest.raises(InputError, match="dead end"):
            viterbi_search(g, meas, weights=Weights(1, 0, 0))
        return
    r = viterbi_search(g, meas, weights=Weights(1, 0, 0))
    # The search sums float32 per-step costs (readings kept as float32 in g): equal to
    # the float64 brute force to float32 precision. Rounding a reading of size M (in g)
    # moves it by up to eps·M and a squared difference d² by about 2·|d|·eps·M, so the
    # path's cost by at most 2·eps·M·√(cost·3·S·T) (Cauchy–Schwarz over its components);
    # a near match (small cost) of large readings is where a fixed relative bound fails.
    eps = float(np.finfo(np.float32).eps)
    big = max(np.abs(meas).max(), np.abs(acc).max()) / 9.81
    tol = 4.0 * eps * big * np.sqrt(best * 3 * meas.shape[1] * T) + 1e-6 * best + 1e-9
    assert r.cost == pytest.approx(best, rel=0.0, abs=tol)
    assert path_cost(g, r.node_path, meas) == pytest.approx(r.cost, rel=0.0, abs=tol)
    assert len(r.node_path) == T and len(r.edge_path) == T - 1
    np.testing.assert_array_equal(g.edge_src[r.edge_path], r.node_path[:-1])
    np.testing.assert_array_equal(g.edge_dst[r.edge_path], r.node_path[1:])


@pytest.mark.parametrize("seed", range(6))
def test_pruned_survivor_tree_equals_full_lattice(seed, ring):
    rng = np.random.default_rng(seed)
    g = random_graph(rng)
    T = 120
    meas = rng.normal(0, 9.81, (T, 2, 3))
    meas[rng.random((T, 2)) < 0.1] = np.nan  # missing sensors contribute nothing
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    position[rng.random(T) < 0.1] = np.nan
    constraints = [
        [{"start_s": 0.5, "end_s": 1.5, "require": {"contact": "both"}}],
        [{"start_s": 1.0, "end_s": 3.0, "require": {"label": "b"}}],
    ]
    for weights, sets in ((Weights(1, 0, 0), []), (Weights(0.5, 1, 1), []), (Weights(0.5, 1, 1), constraints)):
        fast = viterbi_search(g, meas, position, heading, weights, sets)
        ref_path, ref_cost = reference_viterbi(g, meas, position, heading, weights, sets)
        np.testing.assert_array_equal(fast.node_path, ref_path)
        assert fast.cost == pytest.approx(ref_cost, rel=1e-6)  # float32 per-step C_A sums
        assert fast.compression > 1.0 and fast.peak_entries < g.num_nodes * T
        if ring is not None:  # lattice points did go through the store
            assert fast.peak_entries > g.num_nodes


def test_constraints_beat_sensor_cost_lexicographically():
    # Two parallel chains 0→1→2 (contact: left) and 3→4→5 (both feet); start nodes 0 and 3.
    # The sensors fit the second chain perfectly, but the first set demands left contact.
    S = 1
    acc_fit = np.zeros((1, 3))
    acc_off = np.full((1, 3), 9.81)
    src = [0, 1, 3, 4]
    dst = [1, 2, 4, 5]
    acc = np.stack([acc_off, acc_off, acc_fit, acc_fit])
    contacts = np.array([[1, 0], [1, 0], [1, 0], [1, 1], [1, 1], [1, 1]], bool)
    g = tiny_graph(src, dst, acc, contacts=contacts)
    meas = np.zeros((3, S, 3))
    free = viterbi_search(g, meas, weights=Weights(1, 0, 0))
    assert list(free.node_path) == [3, 4, 5]
    sets = [[{"start_s": 0.0, "end_s": 1.0, "require": {"contact": "left"}}]]
    bound = viterbi_search(g, meas, weights=Weights(1, 0, 0), constraint_sets=sets)
    assert list(bound.node_path) == [0, 1, 2] and bound.broken == [0]
    assert bound.cost > free.cost
    # A second, less important set cannot override the first.
    sets2 = sets + [[{"start_s": 0.0, "end_s": 1.0, "require": {"contact": "both"}}]]
    both = viterbi_search(g, meas, weights=Weights(1, 0, 0), constraint_sets=sets2)
    assert list(both.node_path) == [0, 1, 2] and both.broken == [0, 3]


def test_bad_inputs():
    g = tiny_graph([0, 1], [1, 0], np.zeros((2, 1, 3)))
    with pytest.raises(InputError, match="no samples"):
        viterbi_search(g, np.zeros((0, 1, 3)))
    with pytest.raises(InputError, match="layout"):
        viterbi_search(g, np.zeros((3, 2, 3)))
    with pytest.raises(InputError, match="unknown label"):
        viterbi_search(
            g, np.zeros((3, 1, 3)), constraint_sets=[[{"start_s": 0, "end_s": 1, "require": {"label": "zzz"}}]]
        )


def test_noise_free_input_decodes_to_its_own_clip():
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.graph.model import READING_DTYPE
    from graphsvc.motion.procedural import generate_knowledge_base
    from graphsvc.sensors.layout import PRESETS
    from graphsvc.sensors.noise import PRESETS as NOISE
    from graphsvc.sensors.simulate import simulate_recording

    kb = generate_knowledge_base(seed=3, minutes=0.8)
    g, _ = build_graph(kb, BuildOptions(progress=False))
    for c in range(len(kb)):
        rec = simulate_recording(kb[c], PRESETS["wrists-ankles"], NOISE["none"])
        first = g.clips[c]["first_node"]
        acc = rec.accelerations.astype(READING_DTYPE)  # (the graph's readings are the clip's, to their bits)
        for w in (Weights(1, 0, 0), Weights(0.5, 1, 1)):
            r = viterbi_search(g, acc, rec.ground_position, rec.heading, weights=w)
            np.testing.assert_array_equal(r.node_path, first + np.arange(rec.num_samples), err_msg=kb[c].name)
            assert r.terms["acc_g2"] < 1e-9


def test_batch_reading_costs_equal_the_per_sample_kernel():
    # The batch search computes C_A for 16 samples per pass over the readings table,
    # a live search one sample at a time: the values must be identical, bit for bit,
    # missing sensors included (else a stream and a batch run could pick different paths).
    # 21 samples (no multiple of the SIMD width), missing sensors in some, none in others;
    # the readings' count is no multiple of 8 either.
    rng = np.random.default_rng(5)
    g = random_graph(rng, N=300, out=4, S=3)
    acc = rng.normal(0, 9.81, (21, 3, 3))
    acc[:8][rng.random((8, 3)) < 0.3] = np.nan
    acc[4] = np.nan  # no sensor at all: C_A is 0
    acc[18, 1, 2] = np.nan
    for threads in (True, False):
        s = ViterbiSearch(g, Weights(1, 0, 0), threads=threads)
        assert s.readings_t.shape[1] % 8 != 0
        batch = s.reading_costs(acc)
        assert batch.shape == (21, s.readings_t.shape[1])
        for t in range(21):
            s._set_measurement(acc[t])
            present = s._mask.sum() / 3.0
            expected = np.zeros_like(s.reading_cost)
            if present:
                s._kernels[0](s.readings_t, s._meas, s._mask, np.float32(1.0 / present), expected)
            np.testing.assert_array_equal(batch[t], expected)
    # …and against a direct float64 computation, to float32 precision.
    r_g = s.readings_t.T.astype(np.float64)
    for t in (0, 10, 18, 20):
        m = (acc[t].astype(np.float32).astype(np.float64) / 9.81).astype(np.float32).reshape(-1)
        valid = np.repeat(np.isfinite(acc[t]).all(axis=1), 3)
        direct = np.sum((r_g[:, valid] - m[valid]) ** 2, axis=1) / (valid.sum() / 3)
        np.testing.assert_allclose(batch[t], direct, rtol=1e-5)


def test_reported_accelerometer_term_is_the_search_cost_exactly():
    # The report integrates C_A along the path with the search's own arithmetic (one
    # fused multiply-add an axis), so at weights (1, 0, 0) it is the search's cost to
    # the last bit, missing sensors included.
    rng = np.random.default_rng(11)
    g = random_graph(rng, N=200, out=4, S=3)
    acc = rng.normal(0, 9.81, (40, 3, 3))
    acc[rng.random((40, 3)) < 0.2] = np.nan
    r = viterbi_search(g, acc, weights=Weights(1, 0, 0))
    assert r.cost > 0
    assert r.terms["acc_g2"] == r.cost


def test_search_without_placement_ignores_position_like_zero_weights():
    # At W_P = W_O = 0 the placement is not carried; the path and cost equal those of a
    # search that carries it (placed=True) and multiplies it by zero.
    T = 60
    g, meas, position, heading = random_walk_problem(8, T)
    runs = []
    for placed in (False, True):
        s = ViterbiSearch(g, Weights(1, 0, 0), placed=placed)
        assert (s.place is not None) == placed
        s.start(position[0], heading[0])
        for t in range(1, T):
            s.step(meas[t], position[t], heading[t])
        runs.append((s.trace(s.best_node())[0], s.cost.copy()))
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])


def test_distinct_rows_groups_bit_identical_rows_in_order_of_first_use():
    from graphsvc.strategies.viterbi.tables import distinct_rows

    rng = np.random.default_rng(3)
    pool = rng.normal(0, 1, (7, 4)).astype(np.float32)
    pool[5] = pool[4]
    pool[5, 0] = -0.0 if pool[4, 0] == 0.0 else pool[4, 0]
    pool[6] = 0.0
    rows = pool[rng.integers(0, 7, 300)]
    rows[::7, 1] = -0.0  # -0.0 and 0.0 differ bit for bit, so they are different readings
    rows[::11, 1] = 0.0
    # Independent grouping: a dictionary of byte strings, numbered as first seen.
    seen: dict[bytes, int] = {}
    expected_label = np.array([seen.setdefault(r.tobytes(), len(seen)) for r in rows])
    expected_first = np.array([int(np.nonzero(expected_label == k)[0][0]) for k in range(len(seen))])
    for hashes in (None, np.zeros(len(rows), np.uint64)):  # the real hash, then every row colliding
        first, label = distinct_rows(rows, hashes)
        np.testing.assert_array_equal(label, expected_label)
        np.testing.assert_array_equal(first, expected_first)


@pytest.mark.parametrize("ring", [(8, 5)], indirect=True)
def test_a_node_with_300_incoming_edges_keeps_every_arrival(ring):
    # Dense lattice rows hold which incoming edge each node arrived by, one byte a node
    # while in-degrees stay below 255; a hub with 300 incoming edges needs two bytes, and
    # the path through it — arriving by its 300th edge among others — must survive the
    # ring and the survivor store intact (the reference keeps the full lattice).
    rng = np.random.default_rng(21)
    hub, spokes = 0, np.arange(1, 301)
    src = np.concatenate([spokes, np.full(300, hub), [hub]])
    dst = np.concatenate([np.full(300, hub), spokes, [hub]])  # hub ← every spoke ← hub, hub ↻
    acc = rng.normal(0, 9.81, (len(src), 1, 3))
    g = tiny_graph(src, dst, acc)
    assert np.diff(g.incoming).max() == 301
    # Noise-free input along hub → spoke 300 → hub → spoke 7 → hub …
    walk = [0, 300, 0, 7, 0, 300, 0, 299] * 6
    edges = [int(np.nonzero((g.edge_src == a) & (g.edge_dst == b))[0][0]) for a, b in zip(walk[:-1], walk[1:])]
    meas = np.concatenate([acc[:1], g.edge_acc[edges].astype(np.float64)])
    s = ViterbiSearch(g, Weights(1, 0, 0))
    assert s.arrivals.dtype == np.uint16
    fast = viterbi_search(g, meas, weights=Weights(1, 0, 0))
    np.testing.assert_array_equal(fast.node_path[1:], walk[1:])
    np.testing.assert_array_equal(fast.edge_path, edges)
    ref_path, _ = reference_viterbi(g, meas, weights=Weights(1, 0, 0))
    np.testing.assert_array_equal(fast.node_path, ref_path)


@pytest.mark.parametrize("share", [-1.0, 2.0], ids=["carried", "not-carried"])
def test_flush_from_the_ancestors_lists_the_survivors_of_a_walk_from_the_newest_row(ring, share, monkeypatch):
    # A flush starts its walk back at the sample where it last took every live path's
    # node (its ancestor), not at the newest row, when ancestors are carried (share −1:
    # from the second flush on; 2: never): the survivors it lists must be those of the
    # walk through every row, for rings whose blocks are longer, equal to or shorter
    # than the rows kept beyond them, placed or not, in the float32 pass and in the
    # float64 passes.
    from graphsvc.strategies.viterbi import store as V

    monkeypatch.setattr(ViterbiSearch, "ANCESTOR_SHARE", share)
    flushes = []  # whether each walked from the ancestors

    class Checked(ViterbiSearch):
        def _flush(self):
            level_nodes = np.zeros(self.N * self.used + 16, np.int32)
            level_start = np.zeros(self.BLOCK + 1, np.int64)
            whole = np.arange(self.N, dtype=np.int32)  # every live node is its own ancestor at the newest row
            total, _ = V._block_levels(
                self.arrivals,
                self.first,
                self.used,
                self.BLOCK,
                self.incoming,
                self.edge_src,
                self.alive_map,
                level_nodes,
                level_start,
                whole,
                self.state,
            )
            flushes.append(self.ancestor_t >= 0)
            super()._flush()
            np.testing.assert_array_equal(self.level_start, level_start)
            np.testing.assert_array_equal(self.level_nodes[:total], level_nodes[:total])

    rng = np.random.default_rng(7)
    g = random_graph(rng, N=40, out=2)
    T = 400  # the default ring flushes at samples 256 and 384
    meas = rng.normal(0, 9.81, (T, 2, 3))
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    free = np.zeros(1, np.int64)  # one constraint set that requires nothing: the float64 passes
    for weights, gamma in ((Weights(1, 0, 0), 0), (Weights(0.5, 1, 0), 0), (Weights(0.5, 1, 0), 1)):
        search = Checked(g, weights, gamma)
        search.start(position[0], None, free[:gamma], free[:gamma])
        for t in range(1, T):
            search.step(meas[t], position[t], None, free[:gamma], free[:gamma])
        assert len(search.trace(search.best_node())[0]) == T
    assert len(flushes) >= 3
    assert any(flushes) == (share < 0) and not flushes[0]


def _levels_by_sets(arrivals, first, used, flush, incoming, edge_src, ancestor, cost, lowest=0):
    """`_block_levels` written plainly with Python sets: each row's distinct nodes, and
    the highest row from `lowest` on holding one."""
    R = arrivals.shape[0]
    alive = {int(ancestor[n]) for n in np.nonzero(np.isfinite(cost))[0]}
    levels = [None] * used
    for k in range(used - 1, -1, -1):
        row = (first + k) % R
        levels[k] = sorted(alive)
        alive = {int(edge_src[incoming[n] + arrivals[row, n]]) for n in alive}
    counts = [len(level) for level in levels]
    converged = max([k for k in range(lowest, used) if counts[k] == 1], default=-1)
    return [n for level in levels[:flush] for n in level], np.cumsum([0] + counts[:flush]), converged


def test_walk_back_lists_the_rows_nodes_as_plain_sets_do():
    # The walks back scan byte maps while rows hold many nodes and switch to lists once
    # they hold few (≤ 16 here): every row's nodes, the converged row (both walks), and a
    # level list too short (in either phase) reported without leaving a mark behind.
    from graphsvc.strategies.viterbi import store as V

    counts = []  # every row's

    class Checked(ViterbiSearch):
        def _flush(self):
            ancestor = np.arange(self.N, dtype=np.int32)
            args = (self.arrivals, self.first, self.used)
            scratch = (self.incoming, self.edge_src, self.alive_map)
            for listed in (self.BLOCK, self.used):  # the flush's rows, and every row walked
                want_nodes, want_start, want_converged = _levels_by_sets(
                    *args, listed, self.incoming, self.edge_src, ancestor, self.cost
                )
                for short in (len(want_nodes) - 1, len(want_nodes) // 2, 0):  # runs out: -1, nothing left marked
                    total, _ = V._block_levels(
                        *args,
                        listed,
                        *scratch,
                        np.zeros(short, np.int32),
                        np.zeros(listed + 1, np.int64),
                        ancestor,
                        self.state,
                    )
                    assert total == -1 and not self.alive_map.any()
                level_nodes, level_start = np.zeros(len(want_nodes), np.int32), np.zeros(listed + 1, np.int64)
                total, converged = V._block_levels(
                    *args, listed, *scratch, level_nodes, level_start, ancestor, self.state
                )
                assert not self.alive_map.any()
                assert total == len(want_nodes)
                np.testing.assert_array_equal(level_nodes, want_nodes)
                np.testing.assert_array_equal(level_start, want_start)
                assert converged == want_converged
            counts.extend(np.diff(want_start))
            # …and the dense-window mode's walk, from the nodes alive at the newest row
            newest = self.arrivals[(self.first + self.used - 1) % self.arrivals.shape[0]]
            cost = np.where(newest != self.none, 0.0, np.inf)
            for lowest in (0, self.used // 2, self.used - 1):
                want = _levels_by_sets(*args, 0, self.incoming, self.edge_src, ancestor, cost, lowest)[2]
                for live in (np.zeros(0, np.int32), np.flatnonzero(newest != self.none).astype(np.int32)):
                    # (the row scanned for its alive nodes, or given them, as a beam search does)
                    assert V._converged_row(*args, lowest, *scratch[:2], self.none, self.alive_map, live) == want
                    assert not self.alive_map.any()
            super()._flush()

    rng = np.random.default_rng(9)
    g = random_graph(rng, N=1500, out=3)
    T = 300
    edges, node = [], 0  # readings along a random walk, for paths to merge into
    for _ in range(T):
        edges.append(rng.choice(np.nonzero(g.edge_src == node)[0]))
        node = g.edge_dst[edges[-1]]
    meas = g.edge_acc[edges].astype(np.float64) + rng.normal(0, 0.5, (T, 2, 3))
    search = Checked(g, Weights(1, 0, 0), ring=(40, 24))  # flushes every 40 samples, walking 64 rows
    search.start()
    for t in range(1, T):
        search.step(meas[t])
    assert len(counts) >= 5 * 64
    assert max(counts) > 16 and min(counts) == 1  # both ways of listing, and converged rows


def test_serial_kernels_never_load_the_threaded_ones_from_the_cache(tmp_path):
    # numba's disk cache tells a function's entries apart by signature, bytecode and
    # closure, not by compile flags: a later process must not be served a kernel
    # compiled threaded when it asks for the serial one (a server's streams would run
    # threaded kernels side by side).
    import os
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from graphsvc.strategies.viterbi import costs as V\n"
        "k = V.{name}\n"
        "k(np.zeros((4, 8)), np.zeros(2), 0.0, 0.0, np.zeros((4, 4), np.float32))\n"
        "print(sum(k.stats.cache_hits.values()))\n"
    )
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}

    def cache_hits(name):
        done = subprocess.run(
            [sys.executable, "-c", code.format(name=name)], env=env, capture_output=True, text=True, timeout=600
        )
        assert done.returncode == 0, done.stderr[-2000:]
        return int(done.stdout.split()[-1])

    assert cache_hits("_relative") == 0  # compiled and cached threaded
    assert cache_hits("_relative_serial") == 0  # compiled afresh, not the threaded code
    assert cache_hits("_relative_serial") == 1  # and cached in its own right
    assert cache_hits("_relative") == 1


def test_every_kernel_is_compiled_once_per_cache_entry():
    # The same check for every kernel: no two dispatchers with different compile flags
    # share a function name and line (which is what numba files cache entries under).
    from graphsvc.strategies.viterbi import batch, beam, costs, dense, search, store, tables

    modules = (batch, beam, costs, dense, search, store, tables)
    dispatchers = [d for m in modules for d in vars(m).values() if isinstance(d, numba.core.registry.CPUDispatcher)]
    dispatchers += [d for k in (dense._finish, dense._finish_serial) for d in k.values()]
    seen = {}
    for d in dispatchers:
        key = (d.py_func.__qualname__, d.py_func.__code__.co_firstlineno)
        flags = tuple(sorted((k, str(v)) for k, v in d.targetoptions.items()))
        assert seen.setdefault(key, flags) == flags, key
    assert ("_relative_py_serial", costs._relative_py.__code__.co_firstlineno) in seen


def test_warm_up_search_runs_the_walk_back_kernels():
    # A server warms up at load; the kernels that walk back through the dense rows run
    # only every BLOCK samples, the float64 passes only for constrained searches, the
    # beam step only for beam searches, and the float32 pass's second half is compiled
    # apart for placed and unplaced ones, so the warm-up must reach them all itself. A
    # fresh process: here other tests have already compiled them.
    import subprocess
    import sys

    code = (
        "import numpy as np\n"
        "from graphsvc.strategies.viterbi import batch, beam, dense, store\n"
        "from tests.search.problems import random_graph\n"
        "kernels = (store._block_levels, store._append_block, store._converged_row, store._trace, dense._approx_select,\n"
        "           *dense._finish.values(), dense._edge_totals, dense._select, dense._advance, beam._beam_step,\n"
        "           beam._immortal, beam._best_in_list, beam._reset_costs, beam._beam_prune)\n"
        "assert not any(k.signatures for k in kernels)\n"
        "batch.warm_up_search(random_graph(np.random.default_rng(0)))\n"
        "assert all(k.signatures for k in kernels), [k.__name__ for k in kernels if not k.signatures]\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]


def test_best_node_ranks_constraints_then_cost_within_tie_then_detours_then_id():
    from graphsvc.strategies.viterbi.costs import TIE
    from graphsvc.strategies.viterbi.dense import _best_node as best_of_state

    def _best_node(cost, rank, det):  # the kernel reads the costs from state rows
        return best_of_state(cost[:, None].copy(), rank, det)

    def narrowed(cost, rank, det):  # the definition, by numpy narrowing key by key
        candidates = np.nonzero(np.isfinite(cost))[0]
        for k in range(rank.shape[1]):
            candidates = candidates[rank[candidates, k] == rank[candidates, k].min()]
        c = cost[candidates]
        key = np.round(c / TIE) if np.all(np.abs(c) < 1e6) else c
        candidates = candidates[key == key.min()]
        return int(candidates[det[candidates] == det[candidates].min()][0])

    rng = np.random.default_rng(5)
    for trial in range(300):
        N, gamma = int(rng.integers(1, 60)), int(rng.integers(0, 3))
        cost = rng.choice([0.0, 1.0, 1.0 + 0.3 * TIE, 1.0 + 3 * TIE, 2.0, np.inf], N)
        if trial % 7 == 0:
            cost[rng.integers(0, N)] = 3e6  # no rounding once a candidate is this large
        if not np.isfinite(cost).any():
            cost[0] = 1.0
        rank = rng.integers(0, 2, (N, gamma)).astype(np.int32)
        det = rng.integers(0, 3, N).astype(np.int32)
        assert _best_node(cost, rank, det) == narrowed(cost, rank, det)
    # A hand-checked case: node 2 breaks fewer constraints despite its cost; of nodes 3
    # and 4, equal within TIE, 4 has fewer detours.
    cost = np.array([0.0, np.inf, 5.0, 6.0, 6.0 + 0.4 * TIE])
    rank = np.array([[1], [0], [0], [0], [0]], np.int32)
    assert _best_node(cost, rank, np.array([0, 0, 0, 2, 1], np.int32)) == 2
    rank[2] = 1
    assert _best_node(cost, rank, np.array([0, 0, 0, 2, 1], np.int32)) == 4


def test_best_node_from_the_chunks_lowest_and_highest_costs_equals_reading_every_node():
    # Costs on a grid finer and coarser than TIE, ties across chunk boundaries, chunks
    # with no live node, a cost ≥ 1e6 now and then (no rounding then), detours.
    from graphsvc.strategies.viterbi.costs import COST, TIE
    from graphsvc.strategies.viterbi.dense import _best_in_chunks, _best_node

    rng = np.random.default_rng(11)
    for trial in range(300):
        N = int(rng.integers(1, 80))
        chunk_nodes = np.unique(np.r_[0, rng.integers(0, N + 1, int(rng.integers(0, 6))), N]).astype(np.uint64)
        cost = rng.choice([0.0, 1.0, 1.0 + 0.3 * TIE, 1.0 + 1.5 * TIE, 1.0 + 3 * TIE, 2.0, np.inf], N)
        if trial % 5 == 0:
            cost[rng.integers(0, N)] = 3e6
        state = np.zeros((N, 6))
        state[:, COST] = cost
        det = rng.integers(0, 3, N).astype(np.int32)
        live = np.where(np.isfinite(cost), cost, np.nan)
        bounds = list(zip(chunk_nodes[:-1].astype(int), chunk_nodes[1:].astype(int)))
        lowest = np.array([np.nanmin(live[a:b], initial=np.inf) for a, b in bounds])
        highest = np.array([np.nanmax(live[a:b], initial=-np.inf) for a, b in bounds])
        expect = _best_node(state, np.zeros((N, 0), np.int32), det)
        assert _best_in_chunks(state, det, chunk_nodes, lowest, highest) == expect, trial
    # by hand: node 3 (chunk 1) is within TIE of node 1 (chunk 0) and has fewer detours
    state = np.zeros((5, 6))
    state[:, COST] = [5.0, 2.0, np.inf, 2.0 + 0.4 * TIE, 3.0]
    chunks = np.array([0, 2, 5], np.uint64)
    det = np.array([0, 2, 0, 1, 0], np.int32)
    assert _best_in_chunks(state, det, chunks, np.array([2.0, 2.0 + 0.4 * TIE]), np.array([5.0, 3.0])) == 3
    state[4, COST] = 2e6  # a cost ≥ 1e6: compared as they are, so node 1's lower cost wins
    assert _best_in_chunks(state, det, chunks, np.array([2.0, 2.0 + 0.4 * TIE]), np.array([5.0, 2e6])) == 1


def test_negative_or_infinite_weights_are_refused():
    g = random_graph(np.random.default_rng(0))
    for w in (Weights(-1, 0, 0), Weights(1, np.inf, 0), Weights(1, 0, np.nan)):
        with pytest.raises(InputError, match="weights"):
            ViterbiSearch(g, w)


def test_paths_start_at_the_first_measured_position_and_heading():
    # The track's first samples are missing: every path must start where the track
    # does (its first measured position and heading), not at the origin — so moving
    # the whole track moves nothing but the placements, and the reference (which
    # starts there at sample 0) finds the same path.
    rng = np.random.default_rng(4)
    g = random_graph(rng, N=50, out=4)
    T = 70
    meas = rng.normal(0, 9.81, (T, 2, 3))
    position = np.array([40.0, -25.0]) + np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = 1.0 + np.cumsum(rng.normal(0, 0.05, T))
    position[:4] = np.nan
    heading[:2] = np.nan
    w = Weights(0.5, 1, 1)
    fast = viterbi_search(g, meas, position, heading, w)
    ref_path, ref_cost = reference_viterbi(g, meas, position, heading, w)
    np.testing.assert_array_equal(fast.node_path, ref_path)
    assert fast.cost == pytest.approx(ref_cost, rel=1e-6)
    moved = viterbi_search(g, meas, position + np.array([100.0, -50.0]), heading, w)
    np.testing.assert_array_equal(moved.node_path, fast.node_path)
    assert moved.cost == pytest.approx(fast.cost, rel=1e-9)
    # The search's own record of the start, and the per-term costs integrated from it.
    s = ViterbiSearch(g, w)
    s.start(position[0], heading[0])
    for t in range(1, 6):
        s.step(meas[t], position[t], heading[t])
    p0, h0 = s.start_placement
    np.testing.assert_array_equal(p0, position[4])
    assert h0 == heading[2]
    assert fast.terms["position_m"] * w.position + fast.terms["heading_rad"] * w.heading + fast.terms[
        "acc_g2"
    ] * w.acc == pytest.approx(fast.cost, rel=1e-6)


def test_track_pull_is_a_first_order_filter_with_its_time_constant():
    from graphsvc.strategies.viterbi.costs import track_pull

    assert track_pull(None, 30.0) == track_pull(0.0, 30.0) == 0.0
    # After τ·rate samples the gap left is e⁻¹ of what it was.
    alpha = track_pull(0.5, 30.0)
    assert (1.0 - alpha) ** 15 == pytest.approx(np.exp(-1.0), rel=1e-12)
    with pytest.raises(InputError):
        ViterbiSearch(random_graph(np.random.default_rng(0), N=20, out=2), Weights(0.5, 1, 1), pull_s=-1.0)


@pytest.mark.parametrize("seed", range(3))
def test_pulled_placements_equal_the_reference_and_the_reported_terms(seed):
    # The pull moves each path's placement toward the tracker after its position term
    # is scored: the numpy reference, which pulls its per-node positions the same way,
    # finds the same path, and the terms summed along it (with the same pull) add up to
    # the search's cost. Positions missing at some samples are not pulled toward.
    g, meas, position, heading = random_walk_problem(seed, T=80)
    position += np.array([3.0, -2.0]) * np.linspace(0, 1, len(position))[:, None]  # a track the edges do not follow
    position[::9] = np.nan
    changed = False
    for w in (Weights(0.5, 1, 1), Weights(0.5, 2, 0)):
        plain = viterbi_search(g, meas, position, heading, w)
        fast = viterbi_search(g, meas, position, heading, w, pull_s=0.1)
        ref_path, ref_cost = reference_viterbi(g, meas, position, heading, w, pull_s=0.1)
        np.testing.assert_array_equal(fast.node_path, ref_path)
        assert fast.cost == pytest.approx(ref_cost, rel=1e-6)
        t = fast.terms
        assert t["acc_g2"] * w.acc + t["position_m"] * w.position + t["heading_rad"] * w.heading == pytest.approx(
            fast.cost, rel=1e-6
        )
        # Following the tracker, the paths score far less position cost than placed once.
        assert t["position_m"] < 0.5 * plain.terms["position_m"]
        changed |= not np.array_equal(plain.node_path, fast.node_path)
    assert changed
    # …and with measured sensor orientations (C_R, chord², some missing)
    rng = np.random.default_rng(100 + seed)
    g.edge_up = random_up(rng, g.edge_acc.shape)
    up = random_up(rng, meas.shape)
    up[rng.random(up.shape[:2]) < 0.1] = np.nan
    for w in (Weights(0.5, 1, 1, 3.0), Weights(0, 1, 1, 2.0)):
        fast = viterbi_search(g, meas, position, heading, w, pull_s=0.1, up=up)
        ref_path, ref_cost = reference_viterbi(g, meas, position, heading, w, pull_s=0.1, up=up)
        np.testing.assert_array_equal(fast.node_path, ref_path)
        assert fast.cost == pytest.approx(ref_cost, rel=1e-6)
        t = fast.terms
        assert t["orientation_chord2"] > 0
        assert (
            t["acc_g2"] * w.acc
            + t["position_m"] * w.position
            + t["heading_rad"] * w.heading
            + t["orientation_chord2"] * w.orientation
        ) == pytest.approx(fast.cost, rel=1e-6)


def test_a_pulled_track_closes_the_gap_to_the_tracker_geometrically():
    # Standing still (zero offsets) with the tracker one metre off from sample 1 on:
    # the pulled position after k samples is 1 − (1 − α)^k, and a missing measurement
    # leaves the position where it was.
    from graphsvc.graph.metadata import integrate_path

    alpha = 0.2
    K = 12
    targets = np.tile([1.0, -2.0], (K, 1))
    targets[5] = np.nan
    ground, heading = integrate_path(np.zeros(2), 0.4, np.zeros((K, 2)), np.zeros(K), targets, alpha)
    pulls = np.cumsum(np.isfinite(targets[:, 0]))
    np.testing.assert_allclose(ground[1:, 0], 1.0 - (1.0 - alpha) ** pulls, rtol=1e-12)
    np.testing.assert_allclose(ground[1:, 1], -2.0 * (1.0 - (1.0 - alpha) ** pulls), rtol=1e-12)
    np.testing.assert_allclose(heading, 0.4)
    unpulled, _ = integrate_path(np.zeros(2), 0.4, np.zeros((K, 2)), np.zeros(K), targets, 0.0)
    np.testing.assert_array_equal(unpulled, 0.0)
