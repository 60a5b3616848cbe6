"""The SSG's subsequence DTW, local cost and cheapest path against brute force and
networkx on small inputs."""

import itertools

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from graphsvc.strategies.ssg import dtw
from graphsvc.strategies.ssg.index import WindowPoints

STEPS = ((1, 1, 1.0), (1, 2, 1.0), (2, 1, 2.0))  # (rows back, columns back, weight) of eq. 4.2


def brute_force_paths(C, run_of):
    """Every warping path of eq. 4.2 enumerated step sequence by step sequence: {end
    column: (cost, start column)} of each end's cheapest path."""
    N, F = C.shape
    best = {}
    for end in range(F):
        for k in range(1, N + 1):
            for steps in itertools.product(STEPS, repeat=k):
                n, m, cost, ok = N - 1, end, 0.0, True
                for dn, dm, w in steps:
                    if n == 0:
                        ok = False  # (more steps than rows)
                        break
                    cost += w * C[n, m]
                    n, m = n - dn, m - dm
                    if n < 0 or m < 0 or run_of[m] != run_of[end]:
                        ok = False
                        break
                if not ok or n != 0:
                    continue
                cost += C[0, m]
                if end not in best or cost < best[end][0]:
                    best[end] = (cost, m)
    return best


def test_subsequence_dtw_equals_brute_force():
    rng = np.random.default_rng(1)
    N, F = 5, 23
    C = rng.random((N, F)).astype(np.float32)
    run_start = np.zeros(F, dtype=bool)
    run_start[[0, 9, 10, 17]] = True  # runs 0–8, 9 (one frame), 10–16, 17–22
    run_of = np.cumsum(run_start) - 1
    D = np.empty((N, F))
    step = np.empty((N, F), dtype=np.int8)
    dtw.subsequence_dtw(C, run_start, D, step)
    want = brute_force_paths(C.astype(np.float64), run_of)
    for parts in (1, 3, 16):  # (threads take whole chunks cut at run starts: the same cells)
        bounds = dtw.run_chunks(run_start, parts)
        assert run_start[bounds[:-1]].all() and bounds[0] == 0 and bounds[-1] == F
        D2, step2 = np.empty((N, F)), np.empty((N, F), dtype=np.int8)
        dtw.subsequence_dtw(C, run_start, D2, step2, bounds)
        np.testing.assert_array_equal(D2, D)
        np.testing.assert_array_equal(step2, step)
    for m in range(F):
        if m in want:
            assert D[-1, m] == pytest.approx(want[m][0], rel=1e-9), m
            frames = np.empty(N)
            dtw.backtrack(step, m, frames)
            assert frames[0] == want[m][1] and frames[-1] == m
            assert run_of[int(frames[0])] == run_of[m]
        else:
            assert np.isinf(D[-1, m]), m  # no path fits in the run before it


def test_k_best_equals_a_brute_force_selection():
    rng = np.random.default_rng(4)
    N, F, k = 4, 60, 5
    C = rng.random((N, F)).astype(np.float32)
    run_start = np.zeros(F, dtype=bool)
    run_start[[0, 30]] = True
    run_of = np.cumsum(run_start) - 1
    D = np.empty((N, F))
    step = np.empty((N, F), dtype=np.int8)
    dtw.subsequence_dtw(C, run_start, D, step)
    got = dtw.k_best(D, step, k)
    # Brute force: ends by cost; an end inside a taken range, or whose path overlaps one, is passed over.
    paths = brute_force_paths(C.astype(np.float64), run_of)
    taken, want = [], []
    for end, (cost, start) in sorted(paths.items(), key=lambda kv: kv[1][0]):
        if any(a <= end <= b for a, b in taken) or any(not (end < a or start > b) for a, b in taken):
            continue
        taken.append((start, end))
        want.append((cost, start, end))
        if len(want) == k:
            break
    assert [(round(c, 9), int(f[0]), int(f[-1])) for c, f in got] == [(round(c, 9), s, e) for c, s, e in want]


def test_the_plain_kernels_agree_with_the_cost_matrix_kernel_and_brute_force():
    rng = np.random.default_rng(7)
    q, s = rng.random((5, 3)), rng.random((40, 3))
    C = ((q[:, None, :] - s[None, :, :]) ** 2).sum(-1)
    D = np.empty(C.shape)
    step = np.empty(C.shape, dtype=np.int8)
    run_start = np.zeros(40, dtype=bool)
    run_start[0] = True
    dtw.subsequence_dtw(C.astype(np.float32), run_start, D, step)
    last = np.empty(40)
    dtw.bounded_dtw(q, s, last)
    np.testing.assert_allclose(last, D[-1], rtol=1e-6)
    # Eq. 4.1 (steps (1,1) and (1,0) weight 2, (0,1) weight 1), by explicit recursion.
    N, F = C.shape
    want = np.full((N, F), np.inf)
    for m in range(F):
        for n in range(N):
            if n == 0:
                want[n, m] = C[0, m]
            elif m == 0:
                want[n, m] = want[n - 1, m] + C[n, m]
            else:
                want[n, m] = min(
                    want[n - 1, m - 1] + 2 * C[n, m], want[n - 1, m] + 2 * C[n, m], want[n, m - 1] + C[n, m]
                )
    dtw.classic_dtw(q, s, last)
    np.testing.assert_allclose(last, want[-1], rtol=1e-12)


def _kovar(q, k, w):
    """min over θ, (tx, tz) of Σ w |q − (R_y(θ) k + t)|² / Σ w, numerically."""

    def cost(theta):
        c, s = np.cos(theta), np.sin(theta)
        r = np.stack([c * k[:, 0] + s * k[:, 2], k[:, 1], -s * k[:, 0] + c * k[:, 2]], axis=1)
        t = (w[:, None] * (q - r)).sum(0) / w.sum()
        t[1] = 0.0
        return float((w * ((q - r - t) ** 2).sum(1)).sum() / w.sum())

    grid = np.linspace(-np.pi, np.pi, 721)
    th = grid[np.argmin([cost(g) for g in grid])]
    return minimize_scalar(cost, bounds=(th - 0.01, th + 0.01), method="bounded", options={"xatol": 1e-10}).fun


def test_local_cost_is_the_aligned_point_cloud_distance():
    """Eq. 4.3 over the visible markers of a window of frames, against a numerical
    minimisation over the rotation about +Y and the ground translation."""
    rng = np.random.default_rng(11)
    T, M, F = 9, 3, 7
    taus = np.array([-1, 0, 1])
    weights = np.array([0.5, 1.0, 0.5])
    points = rng.normal(size=(T, M, 3)) + np.array([5.0, 1.0, -3.0])
    seen = rng.random((T, M)) > 0.3
    kbm = rng.normal(size=(F, len(taus), M, 3))
    flat = kbm.reshape(F, -1, 3)
    kb = WindowPoints(
        *(np.ascontiguousarray(flat[..., i], dtype=np.float32) for i in range(3)),
        np.ascontiguousarray((flat**2).sum(-1), dtype=np.float32),
        taus,
        weights,
    )
    frames = np.array([0, 4, 8])
    got = dtw.local_costs(kb, points, seen, frames, np.ones(F, dtype=bool))
    for b, n in enumerate(frames):
        for m in range(F):
            q, k, w = [], [], []
            for i, tau in enumerate(taus):
                t = n + tau
                if 0 <= t < T:
                    for j in range(M):
                        if seen[t, j]:
                            q.append(points[t, j])
                            k.append(kbm[m, i, j])
                            w.append(weights[i])
            want = _kovar(np.array(q), np.array(k), np.array(w))
            assert got[b, m] == pytest.approx(want, rel=2e-4, abs=2e-5), (n, m)
    hidden = np.ones(F, dtype=bool)
    hidden[2] = False
    assert np.isinf(dtw.local_costs(kb, points, seen, frames, hidden)[:, 2]).all()
    none_seen = np.zeros_like(seen)
    assert (dtw.local_costs(kb, points, none_seen, frames, np.ones(F, dtype=bool)) == 0).all()  # (says nothing)


def test_cheapest_path_equals_networkx():
    """The forward pass over the subsequence graph's layers against networkx's shortest
    path on the same graph (edges that do not exist: inf; a node weight added to the
    edges into it)."""
    import networkx as nx

    from graphsvc.strategies.ssg.graph import Layer, cheapest_path

    rng = np.random.default_rng(5)
    sizes = [3, 5, 2, 6, 4, 4]
    layers = []
    for K in sizes:
        layer = Layer(0, 1, False)
        layer.add(0, np.arange(K), rng.random(K))
        layers.append(layer)
    edges = [np.where(rng.random((a, b)) < 0.3, np.inf, rng.random((a, b))) for a, b in zip(sizes, sizes[1:])]
    for weight in (0.0, 1.0, 4.0):
        G = nx.DiGraph()
        for k in range(sizes[0]):
            G.add_edge("s", (0, k), weight=layers[0].cost[k])
        for z, e in enumerate(edges):
            for a, b in zip(*np.nonzero(np.isfinite(e))):
                G.add_edge((z, a), (z + 1, b), weight=weight * e[a, b] + layers[z + 1].cost[b])
        for k in range(sizes[-1]):
            G.add_edge((len(sizes) - 1, k), "t", weight=0.0)
        want = nx.shortest_path_length(G, "s", "t", weight="weight")
        path, cost = cheapest_path(layers, edges, weight)
        assert cost == pytest.approx(want, rel=1e-12)
        total = layers[0].cost[path[0]] + sum(
            layers[z + 1].cost[path[z + 1]] + weight * edges[z][path[z], path[z + 1]] for z in range(len(edges))
        )
        assert total == pytest.approx(cost, rel=1e-12)
