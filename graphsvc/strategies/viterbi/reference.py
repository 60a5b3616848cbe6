"""A plain numpy Viterbi with the full N × T back-pointer lattice.

The reference the numba search is checked against (its survivor-tree pruning must
never change the result) and the baseline of `tools/bench_viterbi.py`'s speed ratio.
Vectorised over edges per sample; memory O(N·T). Ties are broken by edge order, so
compare with the fast search on inputs without exact ties."""

from __future__ import annotations

import numpy as np

from graphsvc.graph.model import MotionGraph
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.orientation import normalised_rows
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.batch import compile_constraints, orientation_counts
from graphsvc.strategies.viterbi.costs import track_pull


def reference_viterbi(
    graph: MotionGraph,
    acc,
    position=None,
    heading=None,
    weights: Weights = Weights(),
    constraint_sets=None,
    pull_s=None,
    up=None,
) -> tuple[np.ndarray, float]:
    """(node path (T,), cost) — same inputs and meaning as `batch.viterbi_search`."""
    oriented = orientation_counts(graph, weights, up)
    if oriented:  # rows scaled to their norm, rounded to float32, as the search's tables and measurements
        u, valid = normalised_rows(up)
        u = np.where(valid[..., None], u, np.nan).astype(np.float32).astype(np.float64)
        e_up = graph.edge_up.astype(np.float32).astype(np.float64)
    alpha = track_pull(pull_s, graph.rate_hz)
    # Readings and measurements rounded to float32 in g as the search stores them; the
    # arithmetic after that is float64 over the full N × T lattice.
    acc = (np.asarray(acc, dtype=np.float32).astype(np.float64) / GRAVITY).astype(np.float32).astype(np.float64)
    T, N = acc.shape[0], graph.num_nodes
    src, dst = graph.edge_src.astype(np.int64), graph.edge_dst.astype(np.int64)
    e_acc = (graph.edge_acc.astype(np.float32).astype(np.float64) / GRAVITY).astype(np.float32).astype(np.float64)
    off, dhead = graph.edge_offset.astype(np.float64), graph.edge_heading.astype(np.float64)
    sets = constraint_sets or []
    gamma = len(sets)
    kinds, values = compile_constraints(graph, sets, np.arange(T) / graph.rate_hz)
    code = graph.node_contacts[:, 0].astype(np.int64) | (graph.node_contacts[:, 1].astype(np.int64) << 1)

    def ok(t):
        out = np.ones((gamma, N), dtype=bool)
        for k in range(gamma):
            if kinds[k, t] == 1:
                out[k] = code == values[k, t]
            elif kinds[k, t] == 2:
                out[k] = graph.node_label == values[k, t]
        return out

    cost = np.zeros(N)
    alive = np.ones(N, dtype=bool)
    rank = (~ok(0)).T.astype(np.int64) if gamma else np.zeros((N, 0), np.int64)
    # Paths start at the first measured position and heading (the origin facing +Z
    # without): until one is measured no term of it counts, so it may as well be sample 0's.
    p0 = next((p for p in ([] if position is None else position) if np.all(np.isfinite(p))), np.zeros(2))
    h0 = next((h for h in ([] if heading is None else heading) if np.isfinite(h)), 0.0)
    pos = np.tile(p0, (N, 1)).astype(float)
    head = np.full(N, float(h0))
    lattice = np.full((T, N), -1, dtype=np.int64)
    for t in range(1, T):
        m = acc[t]
        valid = np.all(np.isfinite(m), axis=-1)
        ca = np.zeros(len(src))
        if valid.any() and weights.acc:
            ca = np.sum((e_acc[:, valid] - m[valid]) ** 2, axis=(1, 2)) / valid.sum()
        h = head[src]
        c, s = np.cos(h), np.sin(h)
        px = pos[src, 0] + c * off[:, 0] + s * off[:, 1]
        pz = pos[src, 1] - s * off[:, 0] + c * off[:, 1]
        nh = h + dhead
        cp = np.zeros(len(src))
        pulled = position is not None and np.all(np.isfinite(position[t])) and weights.position
        if pulled:
            cp = np.hypot(px - position[t, 0], pz - position[t, 1])
        co = np.zeros(len(src))
        if heading is not None and np.isfinite(heading[t]) and weights.heading:
            co = np.abs((nh - heading[t] + np.pi) % (2 * np.pi) - np.pi)
        cr = np.zeros(len(src))
        if oriented:  # C_R: the mean chord² between the sensors' "up" vectors
            ok_r = np.all(np.isfinite(u[t]), axis=-1)
            if ok_r.any():
                cr = np.sum((e_up[:, ok_r] - u[t, ok_r]) ** 2, axis=(1, 2)) / ok_r.sum()
            cr = weights.orientation * cr
        total = cost[src] + weights.acc * ca + weights.position * cp + weights.heading * co + cr
        usable = alive[src]
        keys = [np.where(usable, total, np.inf)] + [rank[src, k] for k in range(gamma - 1, -1, -1)] + [dst]
        order = np.lexsort(keys)
        order = order[usable[order]]
        first = np.ones(len(order), dtype=bool)
        first[1:] = dst[order][1:] != dst[order][:-1]
        best = order[first]
        new_alive = np.zeros(N, dtype=bool)
        new_alive[dst[best]] = True
        n = dst[best]
        new_cost = np.full(N, np.inf)
        new_cost[n] = total[best]
        new_rank = np.zeros_like(rank)
        if gamma:
            new_rank[n] = rank[src[best]] + (~ok(t)).T[n]
        new_pos = np.zeros_like(pos)
        new_pos[n, 0], new_pos[n, 1] = px[best], pz[best]
        if pulled and alpha:  # (after C_P: the placement follows the tracker, `costs.track_pull`)
            new_pos[n] = (1.0 - alpha) * new_pos[n] + alpha * position[t]
        new_head = np.zeros(N)
        new_head[n] = nh[best]
        lattice[t, n] = src[best]
        cost, rank, pos, head, alive = new_cost, new_rank, new_pos, new_head, new_alive
    live = np.nonzero(alive)[0]
    keys = [cost[live]] + [rank[live, k] for k in range(gamma - 1, -1, -1)]
    node = int(live[np.lexsort(keys)[0]])
    path = np.empty(T, dtype=np.int64)
    path[-1] = node
    for t in range(T - 1, 0, -1):
        path[t - 1] = lattice[t, path[t]]
    return path, float(cost[node])
