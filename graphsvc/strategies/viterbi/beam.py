"""The beam search's step: only the paths within `beam` of the best survive a sample,
and while few are live a step visits only the nodes they reach.

`_beam_step_py` takes each reached node's best incoming edge by the float64 rule
(`costs._exact_choice`), computing C_A only for the readings it reads; while many
nodes are live the search takes the exact dense step and then the cut
(`_beam_prune`). `_immortal` marks the nodes from which a path can go on forever, so
the cut never keeps only dead ends. Which kind of step runs is chosen by
`search.ViterbiSearch.narrow`; the survivors and states are the same either way.
"""

from __future__ import annotations

import numba
import numpy as np

from graphsvc.strategies.viterbi.costs import COST, DEAD32, TIE, _carry_placement, _exact_choice
from graphsvc.strategies.viterbi.dense import _ranked
from graphsvc.strategies.viterbi.intrinsics import compile_kernel as _compile
from graphsvc.strategies.viterbi.intrinsics import fmin as _fmin
from graphsvc.strategies.viterbi.intrinsics import pick as _pick

# ----------------------------------------------------------------------------------
# Beam search (opt-in): only the paths within `beam` of the best survive a step, and a
# step visits only the nodes they reach, where the exact search's dense passes visit
# every node and edge. On a walk through the built kelly6 graph (268k nodes) beam 10
# kept a median of 40 nodes live with positions and heading, 170 without
# (`tools/bench_beam.py`).


@numba.njit(cache=True, nogil=True)
def _immortal(incoming, edge_src, allowed):
    """(N,) bool: the allowed nodes from which a path through allowed nodes can go on
    forever (it reaches a cycle). The others run into a dead end within a bounded
    number of samples; peeled off sink by sink through the incoming edges (edges are
    numbered by destination)."""
    N = allowed.shape[0]
    ahead = np.zeros(N, np.int64)  # allowed out-edges of each allowed node not yet peeled
    for n in range(N):
        if allowed[n]:
            for e in range(incoming[n], incoming[n + 1]):
                if allowed[edge_src[e]]:
                    ahead[edge_src[e]] += 1
    immortal = allowed.copy()
    stack = np.empty(N, np.int64)
    top = 0
    for n in range(N):
        if allowed[n] and ahead[n] == 0:
            stack[top] = n
            top += 1
    while top:
        top -= 1
        n = stack[top]
        immortal[n] = False
        for e in range(incoming[n], incoming[n + 1]):
            m = edge_src[e]
            if allowed[m]:
                ahead[m] -= 1
                if ahead[m] == 0:
                    stack[top] = m
                    top += 1
    return immortal


BEAM_CHUNKS = 64
# A beam step lists the nodes its live paths reach by sorting them as met while they
# are at most one in MARKS_SCAN_SHARE of the nodes, else by scanning a mark a node
# (a sort of k nodes against a pass over N/8 words: on a 9.3M-node graph the scan
# alone was about 1 ms a step).
MARKS_SCAN_SHARE = 64


def _beam_step_py(
    active,
    n_active,
    out_start,
    out_dst,
    allowed,
    immortal,
    marks,
    marks_words,
    sources,
    touched,
    total,
    keep,
    survivors_out,
    incoming,
    edge_src,
    edge_reading,
    edge_kind,
    edge_offset,
    edge_heading,
    edge_turn,
    readings,
    meas,
    mask,
    scale,
    w_acc,
    w_pos,
    w_head,
    use_pos,
    use_head,
    mx,
    mz,
    mh,
    placed,
    beam,
    state_prev,
    det_prev,
    state_new,
    det_new,
    arrivals,
    none,
    clear,
    reset,
    ancestor_prev,
    ancestor_new,
    chunk_low,
    pull,
):
    """One step of a beam search (γ = 0) while few nodes are live (see
    `ViterbiSearch.BEAM_DENSE_SHARE`; else the exact step and `_beam_prune`).

    In: active[:n_active], the live nodes at t−1, ascending (every other row of
    state_prev has cost inf); state_new with cost inf at every row; this sample's
    measurement as `costs._reading_costs_py` takes it (meas, mask (3S,), scale; readings
    (R, 3S) row by row, `tables.beam_tables`) and as pass 2 takes the rest.

    1. The nodes the live ones reach (out_start, out_dst: `tables.beam_tables`; only allowed
       ones) are listed ascending in touched: marked in marks ((8·⌈N/8⌉,) uint8, zero,
       left zero) as first met, then sorted — or, when they are more than a
       MARKS_SCAN_SHARE of the nodes, found by scanning marks_words (its uint64 view,
       eight nodes at a time); the live ones are marked in sources ((N,) uint8, zero,
       left zero).
    2. Each takes its best incoming edge by the float64 rule (`costs._exact_choice`): the
       dense search's choice and total, bit for bit, as long as the sources the dense
       search would pick are live (always with an infinite beam).
    3. Survive: the nodes whose total is within beam of the lowest total of an
       immortal node (`_immortal`; of any node when none is reached), so a path that
       can go on always survives, whatever dead ends lie ahead of the others. Their
       new state (cost, detours, ancestor, placement) is written as pass 2 writes it,
       their arrival into this sample's lattice row (every other entry `none`), and
       they are listed ascending in survivors_out (N,).

    total (N,) float64, keep (N,) uint8, chunk_low (BEAM_CHUNKS, 2): scratch. Returns
    the number of survivors and the lowest cost (which always survives).

    clear: set every entry of arrivals (this sample's lattice row) to `none` first;
    else only the entries reset (int32) lists — those an earlier beam step left set
    there (its survivors): a step then costs what its live nodes reach, not N."""
    if clear:
        arrivals[:] = none
    else:
        for i in range(reset.shape[0]):
            arrivals[reset[i]] = none
    for i in range(n_active):
        sources[active[i]] = 1
    count = 0
    for i in range(n_active):
        m = active[i]
        for k in range(out_start[m], out_start[m + 1]):
            n = out_dst[k]
            if allowed[n] and not marks[n]:
                marks[n] = 1
                touched[count] = n
                count += 1
    if count * MARKS_SCAN_SHARE > marks.shape[0]:  # many: a scan of the marks, eight at a time
        count = 0
        for w in range(marks_words.shape[0]):
            if marks_words[w]:
                for n in range(8 * w, 8 * w + 8):
                    if marks[n]:
                        marks[n] = 0
                        touched[count] = n
                        count += 1
    else:  # few: the list made as they were met, sorted
        touched[:count].sort()
        for i in range(count):
            marks[touched[i]] = 0
    per = (count + BEAM_CHUNKS - 1) // BEAM_CHUNKS
    for c in numba.prange(BEAM_CHUNKS):
        low, low_immortal = np.inf, np.inf
        for i in range(c * per, min(count, (c + 1) * per)):
            n = touched[i]
            a, t = _exact_choice(
                n,
                incoming,
                edge_src,
                edge_reading,
                edge_kind,
                edge_offset,
                edge_heading,
                None,
                readings,
                meas,
                mask,
                scale,
                w_acc,
                w_pos,
                w_head,
                use_pos,
                use_head,
                mx,
                mz,
                mh,
                placed,
                state_prev,
                det_prev,
                sources,
            )
            total[i] = t
            if a >= 0:
                arrivals[n] = a
                low = min(low, t)
                if immortal[n]:
                    low_immortal = min(low_immortal, t)
        chunk_low[c, 0], chunk_low[c, 1] = low, low_immortal
    low, low_immortal = np.inf, np.inf
    for c in range(BEAM_CHUNKS):
        low, low_immortal = min(low, chunk_low[c, 0]), min(low_immortal, chunk_low[c, 1])
    limit = (low_immortal if low_immortal != np.inf else low) + beam
    for c in numba.prange(BEAM_CHUNKS):
        for i in range(c * per, min(count, (c + 1) * per)):
            n = touched[i]
            t = total[i]
            if t == np.inf or not t <= limit:
                arrivals[n] = none
                keep[i] = 0
                continue
            keep[i] = 1
            e = np.int64(incoming[n]) + np.int64(arrivals[n])
            m = edge_src[e]
            state_new[n, COST] = t
            det_new[n] = det_prev[m] + (1 if edge_kind[e] != 0 else 0)
            if ancestor_prev.shape[0]:
                ancestor_new[n] = ancestor_prev[m]
            if placed:
                _carry_placement(
                    state_prev,
                    m,
                    state_new,
                    n,
                    edge_offset[e, 0],
                    edge_offset[e, 1],
                    edge_heading[e],
                    edge_turn[e, 0],
                    edge_turn[e, 1],
                    pull,
                )
    for i in range(n_active):
        sources[active[i]] = 0
    survivors = 0
    for i in range(count):
        if keep[i]:
            survivors_out[survivors] = touched[i]
            survivors += 1
    return survivors, low


@numba.njit(cache=True, nogil=True)
def _best_in_list(state, det, nodes, count):
    """`dense._best_node` without constraint sets over the live nodes nodes[:count] (every
    other node dead), ascending: the same node. −1: none."""
    low, high = np.inf, -np.inf
    for i in range(count):
        c = state[nodes[i], COST]
        low, high = min(low, c), max(high, c)
    if count == 0:
        return -1
    small = high < 1e6
    near = low + 2 * TIE if small else low
    best = -1
    best_key = np.inf
    for i in range(count):
        n = nodes[i]
        if state[n, COST] <= near:
            best, best_key = _ranked(n, state[n, COST], det, small, best, best_key)
    return best


@numba.njit(cache=True, nogil=True)
def _reset_costs(state, nodes, count):
    """The cost of nodes[:count] in state (N, W) set to inf (dead)."""
    for i in range(count):
        state[nodes[i], COST] = np.inf


@numba.njit(cache=True, nogil=True)
def _beam_prune(state, immortal, beam, arrivals, none, c32, live_out):
    """The beam's cut after an exact step (state (N, W) its new states; every node with
    a live candidate has a finite cost): the nodes beyond the beam (the rule of
    `_beam_step_py`) get cost inf, arrival `none` and, when c32 is the unplaced float32
    pass's (N,) costs, DEAD32; the survivors are listed ascending in live_out. Returns
    their number and the lowest cost. Branch-free, one array a loop, so each loop
    vectorises: with one loop writing all (with or without branches), 0.5–0.7 ms on
    G_E's 100k nodes, against 0.13 split."""
    N = state.shape[0]
    low, low_immortal = np.inf, np.inf
    for n in range(N):
        c = state[n, COST]
        low = _fmin(low, c)
        low_immortal = _fmin(low_immortal, _pick(immortal[n], c, np.inf))
    limit = (low_immortal if low_immortal != np.inf else low) + beam
    count = 0
    for n in range(N):
        live_out[count] = n
        count += state[n, COST] <= limit
    for n in range(N):
        c = state[n, COST]
        arrivals[n] = _pick((c != np.inf) & (c > limit), none, arrivals[n])
    if c32.shape[0] == N:
        for n in range(N):
            c = state[n, COST]
            c32[n] = _pick((c != np.inf) & (c > limit), DEAD32, c32[n])
    for n in range(N):
        c = state[n, COST]
        state[n, COST] = _pick(c <= limit, c, np.inf)
    return count, low


@numba.njit(cache=True, nogil=True)
def _bound_live(state, live, count, most, immortal, arrivals, none, c32):
    """A bound on the live paths (after the beam's cut): of the live nodes
    live[:count] (ascending; their costs in state (N, W)), keep the `most` cheapest —
    ties at the `most`-th cost kept in ascending node order — and the cheapest node
    that can go on forever (`_immortal`) when none of those can; the others get cost
    inf, arrival `none` and, when c32 is the unplaced float32 pass's (N,) costs,
    DEAD32. The kept ones stay listed ascending in live. Returns their number."""
    if count <= most:
        return count
    costs = np.empty(count)
    for i in range(count):
        costs[i] = state[live[i], COST]
    kth = np.partition(costs, most - 1)[most - 1]
    below = 0
    spare_immortal, spare_cost = -1, np.inf  # the cheapest immortal node
    for i in range(count):
        c = costs[i]
        below += c < kth
        if immortal[live[i]] and c < spare_cost:
            spare_immortal, spare_cost = i, c
    ties = most - below  # nodes at exactly kth kept, in ascending order
    kept = 0
    any_immortal = False
    keep = np.zeros(count, np.uint8)
    for i in range(count):
        c = costs[i]
        if c < kth or (c == kth and ties > 0):
            if c == kth:
                ties -= 1
            keep[i] = 1
            any_immortal |= immortal[live[i]]
    if not any_immortal and spare_immortal >= 0:
        keep[spare_immortal] = 1
    for i in range(count):
        n = live[i]
        if keep[i]:
            live[kept] = n
            kept += 1
        else:
            state[n, COST] = np.inf
            arrivals[n] = none
            if c32.shape[0] == state.shape[0]:
                c32[n] = DEAD32
    return kept


_beam_step, _beam_step_serial = _compile(_beam_step_py, True), _compile(_beam_step_py, False)
