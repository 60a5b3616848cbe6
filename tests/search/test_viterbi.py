"""The Viterbi search against brute force, the full-lattice reference and crafted graphs."""

import itertools

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from graphsvc.errors import InputError
from graphsvc.graph.model import graph_from_edges
from graphsvc.strategies.viterbi.reference import reference_viterbi
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.batch import viterbi_search
from graphsvc.strategies.viterbi.search import ViterbiSearch


def tiny_graph(src, dst, acc, offsets=None, dheading=None, contacts=None, labels=None, kinds=None):
    """A MotionGraph with N nodes and the given edges (sorted by destination here)."""
    return graph_from_edges(src, dst, acc, offsets, dheading, contacts, labels, kinds)


def path_cost(g, nodes, meas):
    total = 0.0
    for t in range(1, len(nodes)):
        e = np.nonzero((g.edge_src == nodes[t - 1]) & (g.edge_dst == nodes[t]))[0]
        if not len(e):
            return None
        total += np.mean(np.sum((g.edge_acc[e[0]].astype(float) / 9.81 - meas[t] / 9.81) ** 2, axis=-1))
    return total


@st.composite
def random_problem(draw):
    N = draw(st.integers(2, 5))
    pairs = draw(st.lists(st.tuples(st.integers(0, N - 1), st.integers(0, N - 1)), min_size=N, max_size=12, unique=True))
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
    # the float64 brute force to float32 precision.
    assert r.cost == pytest.approx(best, rel=1e-6, abs=1e-9)
    assert path_cost(g, r.node_path, meas) == pytest.approx(r.cost, rel=1e-6, abs=1e-9)
    assert len(r.node_path) == T and len(r.edge_path) == T - 1
    np.testing.assert_array_equal(g.edge_src[r.edge_path], r.node_path[:-1])
    np.testing.assert_array_equal(g.edge_dst[r.edge_path], r.node_path[1:])


def random_graph(rng, N=40, out=3, S=2):
    src = np.repeat(np.arange(N), out)
    dst = rng.integers(0, N, len(src))
    pairs = np.unique(np.stack([src, dst], 1), axis=0)
    E = len(pairs)
    return tiny_graph(pairs[:, 0], pairs[:, 1], rng.normal(0, 9.81, (E, S, 3)), offsets=rng.normal(0, 0.05, (E, 2)),
                      dheading=rng.normal(0, 0.05, E), contacts=rng.random((N, 2)) < 0.6,
                      labels=rng.integers(0, 2, N))  # fmt: skip


def random_up(rng, shape):
    """Random unit vectors (…, 3)."""
    u = rng.normal(size=shape)
    return u / np.linalg.norm(u, axis=-1, keepdims=True)


def random_walk_problem(seed, T=70):
    """random_graph and T samples for it: random readings (T, 2, 3) m/s², a random-walk
    ground track (T, 2) m and heading (T,) rad."""
    rng = np.random.default_rng(seed)
    g = random_graph(rng)
    meas = rng.normal(0, 9.81, (T, 2, 3))
    position = np.cumsum(rng.normal(0, 0.05, (T, 2)), axis=0)
    heading = np.cumsum(rng.normal(0, 0.05, T))
    return g, meas, position, heading


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
    constraints = [[{"start_s": 0.5, "end_s": 1.5, "require": {"contact": "both"}}],
                   [{"start_s": 1.0, "end_s": 3.0, "require": {"label": "b"}}]]  # fmt: skip
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
        viterbi_search(g, np.zeros((3, 1, 3)), constraint_sets=[[{"start_s": 0, "end_s": 1, "require": {"label": "zzz"}}]])


def test_noise_free_input_decodes_to_its_own_clip():
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.motion.procedural import generate_knowledge_base
    from graphsvc.sensors.layout import PRESETS
    from graphsvc.sensors.noise import PRESETS as NOISE
    from graphsvc.sensors.simulate import simulate_recording

    kb = generate_knowledge_base(seed=3, minutes=0.8)
    g, _ = build_graph(kb, BuildOptions(progress=False))
    for c in range(len(kb)):
        rec = simulate_recording(kb[c], PRESETS["wrists-ankles"], NOISE["none"])
        first = g.clips[c]["first_node"]
        for w in (Weights(1, 0, 0), Weights(0.5, 1, 1)):
            r = viterbi_search(g, rec.accelerations, rec.ground_position, rec.heading, weights=w)
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
            total, _ = V._block_levels(self.arrivals, self.first, self.used, self.BLOCK, self.incoming, self.edge_src,
                                       self.alive_map, level_nodes, level_start, whole,
                                       self.state)  # fmt: skip
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
                want_nodes, want_start, want_converged = _levels_by_sets(*args, listed, self.incoming, self.edge_src,
                                                                         ancestor, self.cost)  # fmt: skip
                for short in (len(want_nodes) - 1, len(want_nodes) // 2, 0):  # runs out: -1, nothing left marked
                    total, _ = V._block_levels(*args, listed, *scratch, np.zeros(short, np.int32),
                                               np.zeros(listed + 1, np.int64), ancestor, self.state)  # fmt: skip
                    assert total == -1 and not self.alive_map.any()
                level_nodes, level_start = np.zeros(len(want_nodes), np.int32), np.zeros(listed + 1, np.int64)
                total, converged = V._block_levels(*args, listed, *scratch, level_nodes, level_start, ancestor,
                                                   self.state)  # fmt: skip
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
                assert V._converged_row(*args, lowest, *scratch[:2], self.none, self.alive_map) == want
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
        done = subprocess.run([sys.executable, "-c", code.format(name=name)], env=env, capture_output=True, text=True,
                              timeout=600)  # fmt: skip
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
        "from tests.search.test_viterbi import random_graph\n"
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


def shared_reading_graph(rng, N=1200, out=3, S=2):
    """A graph shaped like a built one: edges mostly read their destination's own
    reading (a node's shared edges), a fifth of the rest a reading of their own; big
    enough (N / SELECT_CHUNKS ≫ 8) that pass 1 runs its eight-wide loops."""
    src = np.repeat(np.arange(N), out)
    dst = rng.integers(0, N, len(src))
    pairs = np.unique(np.stack([src, dst], 1), axis=0)
    E = len(pairs)
    node_reading = rng.normal(0, 9.81, (N, S, 3))
    acc = node_reading[pairs[:, 1]]
    own = rng.random(E) < 0.2
    acc[own] = rng.normal(0, 9.81, (int(own.sum()), S, 3))
    return tiny_graph(pairs[:, 0], pairs[:, 1], acc, offsets=rng.normal(0, 0.05, (E, 2)),
                      dheading=rng.normal(0, 0.03, E), kinds=(rng.random(E) < 0.3).astype(np.uint8))  # fmt: skip


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
    assert sorted((int(p), int(m), int(a)) for p, m, a in seen) == sorted(zip(position.tolist(), g.edge_src.tolist(),
                                                                             arrival.tolist()))  # fmt: skip
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
    from graphsvc.strategies.viterbi.intrinsics import keep_two_gathered8, keep_two_placed8
    from graphsvc.strategies.viterbi.costs import RC32, _place_terms
    from graphsvc.strategies.viterbi.dense import _keep_two
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
        "from tests.search.test_viterbi import test_eight_wide_candidates_equal_the_scalar_loop_bit_for_bit as t\n"
        "from tests.search.test_viterbi import _keep_two_scalar_and_eight_wide as k\n"
        "t(False)\n"
        "scalar, wide = k(False)\n"
        "asm = ''.join(wide.inspect_asm().values())\n"
        "print('vgatherdps' in asm, 'vpgatherdd' in asm)\n"
    )  # fmt: skip
    env = {"NUMBA_CPU_FEATURES": features.replace("+avx2", "-avx2"), "NUMBA_CACHE_DIR": str(tmp_path),
           "PATH": "/usr/bin:/bin"}  # fmt: skip
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
    assert fast.terms["position_m"] * w.position + fast.terms["heading_rad"] * w.heading + \
        fast.terms["acc_g2"] * w.acc == pytest.approx(fast.cost, rel=1e-6)


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
        assert t["acc_g2"] * w.acc + t["position_m"] * w.position + t["heading_rad"] * w.heading == \
            pytest.approx(fast.cost, rel=1e-6)
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
        assert (t["acc_g2"] * w.acc + t["position_m"] * w.position + t["heading_rad"] * w.heading
                + t["orientation_chord2"] * w.orientation) == pytest.approx(fast.cost, rel=1e-6)


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
