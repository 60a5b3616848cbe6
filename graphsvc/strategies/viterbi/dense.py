"""The exact search's step over every node and edge (Kelly et al. 2013, eq. 3), in
dense passes, and the choice of the best live node.

A step without constraint sets (the float32 pass):
1. `_approx_select_py`: each node's lowest and second-lowest candidate total in
   float32, from its sources' rows relative to the measurement (`costs`), eight edges
   at a time; near-ties marked.
2. `_finish_kernel`: the choice (re-decided in float64 on a near-tie), the chosen
   path's float64 cost and its new state.
A constrained step (γ > 0) runs the float64 passes `_edge_totals_py`, `_select_py`,
`_advance_py`. Both give the same paths, costs and ties, bit for bit. The cost terms
themselves, and every other place they are computed, are listed in `costs`.

Every kernel is compiled threaded and serial (`intrinsics.compile_kernel`):
`_THREADED` and `_SERIAL` are the sets a search steps with.
"""

from __future__ import annotations

import numba
import numpy as np

from graphsvc.strategies.viterbi.costs import (
    COST,
    DEAD32,
    DEAD_BELOW,
    QX,
    QZ,
    RC32,
    RH,
    TIE,
    _carry_placement,
    _cost_at,
    _exact_choice,
    _place_terms,
    _reading_costs,
    _reading_costs_serial,
    _relative,
    _relative_serial,
    _row_total,
    _set_cost,
    _state_total,
    _tie_better,
)
from graphsvc.strategies.viterbi.intrinsics import compile_kernel as _compile
from graphsvc.strategies.viterbi.intrinsics import fmax as _fmax
from graphsvc.strategies.viterbi.intrinsics import fmin as _fmin
from graphsvc.strategies.viterbi.intrinsics import keep_two_gathered8 as _keep_two_gathered8
from graphsvc.strategies.viterbi.intrinsics import keep_two_placed8 as _keep_two_placed8
from graphsvc.strategies.viterbi.intrinsics import pick as _pick
from graphsvc.strategies.viterbi.intrinsics import prefetch as _prefetch
from graphsvc.strategies.viterbi.intrinsics import tag as _tag

# One step (Kelly et al. 2013, eq. 3, for every node) in two passes over float32 approximations and
# exact float64 fix-ups, because a pass over the 317,600 edges is bound by its
# scattered reads of the source nodes' state and float32 halves them:
# 1. `_approx_select`: every edge's total in float32 (the source's cost relative to
#    the lowest live cost, plus the edge's terms), each node keeping its lowest and
#    second-lowest candidate; the lowest carries which incoming edge it is in its low
#    mantissa bits (`intrinsics.tag`), so keeping the minimum is two min instructions, no branch.
#    Once a chunk's nodes are final, it marks the near-ties: nodes whose float32 gap
#    between their two best candidates is within what float32 rounding could have
#    hidden (plus TIE), a few a sample.
# 2. `_finish`: per node, unless marked, the lowest is the node's best edge exactly
#    as the float64 rule would choose it; a near-tie's candidates are compared again
#    in float64 with the full rule. Then the chosen path's new state, its cost
#    recomputed in float64, so costs, paths and ties are bit for bit those of the
#    float64 search (tested against the float64 kernels below, which constrained
#    searches still use).
# Pass 1 takes the shared edges (`tables.search_tables`) eight at a time: on G_E (mode A) 0.28
# against 0.41 ms a sample, APO 0.70–0.76 against 0.90; pass 2 unchanged in isolation.
# Bound: a float32 total t differs from the float64 one less the base by at most
# alpha·t + beta/2: up to 5 roundings of 2^-24 relative to the sum of non-negative
# terms, the tag's 2^(k−23) (k label bits), and float64 roundings of 2^-52·(base + t).
# The search takes alpha = 2^-20 (3× the first) + 2^(k−22) and beta = 2^-48·base; a
# node whose second-best exceeds its best by more than TIE + alpha·(both) + beta
# keeps the float32 choice. (k counts the all-ones label too, which marks near-ties.)

# Edges ahead whose source's relative row pass 1 prefetches (eight at a time; APO pass 1 on
# G_E: 0.65 ms a sample at 32–96, 0.71 at 16, 0.67 without)
PREFETCH_AHEAD = np.uint64(32)


def _edge_totals_py(
    edge_src,
    edge_reading,
    edge_offset,
    edge_heading,
    reading_cost,
    w_acc,
    w_pos,
    w_head,
    use_pos,
    use_head,
    state,
    rel,
    total,
):
    """total (E,): the cost of each path extended by each edge, G(src) + L(e, t)
    (inf from a dead source; state (N, W) the sources' states), float64 (the
    constrained search's pass). reading_cost (R,) C_A per distinct reading; use_pos /
    use_head: whether this sample's position / heading term counts (then rel holds
    `costs._relative`'s rows)."""
    E = edge_src.shape[0]
    if not (use_pos or use_head):
        for e in numba.prange(E):
            total[e] = state[edge_src[e], COST] + w_acc * reading_cost[edge_reading[e]]
        return
    for e in numba.prange(E):
        total[e] = _row_total(
            rel,
            state,
            edge_src[e],
            reading_cost[edge_reading[e]],
            edge_offset[e, 0],
            edge_offset[e, 1],
            edge_heading[e],
            w_acc,
            w_pos,
            w_head,
            use_pos,
            use_head,
        )


def _select_py(
    chunk_nodes,
    chunk_slots,
    slot_dst,
    slot_src,
    slot_kind,
    slot_edge,
    total,
    allowed,
    det_prev,
    rank_prev,
    best_slot,
    state_new,
    best_edge,
):
    """Each node's best incoming edge (graph edge id, −1: none alive, or the node is
    masked) and its path's cost (state_new's COST): fewest broken constraints (rank,
    lexicographic), then lowest total (within TIE counts as equal), then fewer
    non-original edges so far (det_prev, read only on a near-tie), then the
    plainer edge kind.

    Edges come in slot-major order within chunks of nodes (see `tables.search_tables`): slot
    j holds every node's j-th incoming edge, so a node's candidates are met in their
    graph order, one per pass, and a pass is a flat loop over independent nodes — no
    per-node loop whose varying length the branch predictor keeps missing. total (E+1,)
    in that order, total[E] = inf; best_slot (N,) scratch, E for nodes without
    incoming edges."""
    E = total.shape[0] - 1
    gamma = rank_prev.shape[1]
    for c in numba.prange(chunk_nodes.shape[0] - 1):
        for j in range(chunk_slots.shape[1] - 1):
            first = j == 0
            for i in range(chunk_slots[c, j], chunk_slots[c, j + 1]):
                n = slot_dst[i]
                t = total[i]
                b = E if first else best_slot[n]
                cb = total[b]
                if gamma == 0:
                    # Branch-free but for the rare near-tie: the comparison's outcome is
                    # random, and a mispredicted branch per edge cost more than the pass.
                    better = t < cb - TIE
                    if abs(t - cb) <= TIE:  # near-tie: fewer detours, then plainer edge
                        better = _tie_better(i, b, slot_src, slot_kind, det_prev)
                else:
                    better = False
                    if t != np.inf:
                        if b == E:
                            better = True
                        else:
                            m, mb = slot_src[i], slot_src[b]
                            decided = False
                            for k in range(gamma):
                                if rank_prev[m, k] != rank_prev[mb, k]:
                                    better = rank_prev[m, k] < rank_prev[mb, k]
                                    decided = True
                                    break
                            if not decided:
                                better = t < cb - TIE
                                if abs(t - cb) <= TIE:
                                    better = _tie_better(i, b, slot_src, slot_kind, det_prev)
                best_slot[n] = _pick(better & allowed[n], np.int64(i), b)
        for n in range(chunk_nodes[c], chunk_nodes[c + 1]):
            b = best_slot[n]
            best_edge[n] = -1 if b == E else slot_edge[b]
            state_new[n, COST] = total[b]


def _advance_py(
    best_edge,
    incoming,
    edge_src,
    edge_kind,
    edge_offset,
    edge_heading,
    edge_turn,
    ok,
    placed,
    state_prev,
    det_prev,
    rank_prev,
    state_new,
    det_new,
    rank_new,
    arrivals,
    none,
    ancestor_prev,
    ancestor_new,
    pull,
):
    """The new state of every live path from its predecessor's along its best edge:
    the arrival (which of the node's incoming edges, `none`: dead) into this sample's
    lattice row, detour count, broken constraints, its node at an earlier sample
    (ancestor, (N,) int32, or (0,): not kept) and, when placed, the placement (cos/sin
    carried by rotation, no trigonometry). (Per-term costs are summed along the final
    path afterwards.) Returns how many nodes are live."""
    N = best_edge.shape[0]
    gamma = rank_prev.shape[1]
    live = 0
    for n in numba.prange(N):
        e = best_edge[n]
        if e < 0:
            arrivals[n] = none
            continue
        live += 1
        arrivals[n] = e - incoming[n]
        m = edge_src[e]
        det_new[n] = det_prev[m] + (1 if edge_kind[e] != 0 else 0)
        if ancestor_prev.shape[0]:
            ancestor_new[n] = ancestor_prev[m]
        for k in range(gamma):
            rank_new[n, k] = rank_prev[m, k] + (0 if ok[k, n] else 1)
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
    return live


@numba.njit(inline="always")
def _keep_two(best, second, p, t):
    """Layout position p keeps its lowest and second-lowest tagged candidate (branch-free)."""
    b = best[p]
    second[p] = _fmin(second[p], _fmax(t, b))
    best[p] = _fmin(t, b)


@numba.njit(inline="always")
def _placed_total32(rel, m, ca, ox, oz, dh, w_acc, w_pos, w_head):
    """Pass 1's float32 total of an edge (offset ox, oz, turn dh, reading's C_A ca) from
    its source m's relative row: cost − base + w_acc · C_A + w_pos · position + w_head ·
    heading (`intrinsics.keep_two_placed8` computes the same, eight at a time, bit for bit)."""
    pos, head = _place_terms(rel[m, QX], rel[m, QZ], rel[m, RH], ox, oz, dh)
    return rel[m, RC32] + w_acc * ca + w_pos * pos + w_head * head


@numba.njit(inline="always")
def _keep_two_run(best, second, shift, costs, src, labels, reading_cost, w_acc, s0, s1, keep):
    """`_keep_two` at positions p = i + shift of costs[src[i]] + w_acc · reading_cost[p]
    tagged with labels[i], for i in s0…s1−1 (uint64; shift wraps), eight at a time
    (`intrinsics.keep_two_gathered8`), the rest one by one."""
    i = s0
    while i + np.uint64(8) <= s1:
        _keep_two_gathered8(best, second, i + shift, costs, src, i, reading_cost, w_acc, keep, labels)
        i += np.uint64(8)
    while i < s1:
        _keep_two(best, second, i + shift, _tag(costs[src[i]] + w_acc * reading_cost[i + shift], keep, labels[i]))
        i += np.uint64(1)


def _approx_select_py(
    chunk_nodes,
    shared_slots,
    shared_src,
    shared_arrival,
    shared_offset,
    shared_heading,
    own_bounds,
    own_src,
    own_reading,
    own_pos,
    own_arrival,
    own_offset,
    own_heading,
    reading_cost,
    w_acc,
    w_pos,
    w_head,
    rows,
    c32,
    rel,
    keep,
    allowed_pos,
    alpha,
    beta,
    best,
    second,
):
    """Pass 1 of a step (see above): best[p], second[p] (N,) float32, the lowest and
    second-lowest float32 total among the incoming edges of the node at layout
    position p (`tables.search_tables`); best's low bits (`keep` clears them) hold which of
    the node's incoming edges it is (its arrival index, `tables.float32_tables`); DEAD32:
    none. Per chunk of nodes:
    1. Shared edges, in slot-major order: slot j's entries are positions n0, n0+1, …
       — no destination index to read — and their C_A is reading_cost[p], read in
       order. Unplaced, eight edges at a time (`_keep_two_run`).
    2. The rest (`own_*`: one entry an edge, with its reading, layout position and
       label).
    3. Positions masked out (allowed_pos (N,) bool, layout order) become DEAD32, and
       near-ties (the bound above: alpha, beta) get all ones as their label (no
       incoming edge has that label), so pass 2 reads one word a node. (No uint32
       view of best is written here: numba compiles a parallel loop's body as if its
       arrays did not overlap.)
    rows: read sources from the relative rows (placed searches; w_pos / w_head 0 when
    that term does not count this sample) instead of c32 (N,) (cost − base, float32).
    All indices unsigned: numba's negative-index fix-up on signed ones cost half the
    pass's speed (fewer loads in flight)."""
    E = np.uint64(shared_src.shape[0])
    for c in numba.prange(chunk_nodes.shape[0] - 1):
        n0, n1 = chunk_nodes[c], chunk_nodes[c + 1]
        for p in range(n0, n1):
            best[p] = DEAD32
            second[p] = DEAD32
        for j in range(shared_slots.shape[1] - 1):
            s0, s1 = shared_slots[c, j], shared_slots[c, j + 1]
            shift = n0 - s0  # slot entry i belongs to position i + shift (uint64, wraps)
            if rows:
                i = s0
                while i + np.uint64(8) <= s1:
                    for k in range(8):
                        if i + PREFETCH_AHEAD + k < E:
                            _prefetch(rel, shared_src[i + PREFETCH_AHEAD + k])
                    _keep_two_placed8(
                        best,
                        second,
                        i + shift,
                        rel,
                        shared_src,
                        i,
                        shared_offset,
                        shared_heading,
                        reading_cost,
                        w_acc,
                        w_pos,
                        w_head,
                        keep,
                        shared_arrival,
                    )
                    i += np.uint64(8)
                while i < s1:
                    t = _placed_total32(
                        rel,
                        shared_src[i],
                        reading_cost[i + shift],
                        shared_offset[i, 0],
                        shared_offset[i, 1],
                        shared_heading[i],
                        w_acc,
                        w_pos,
                        w_head,
                    )
                    _keep_two(best, second, i + shift, _tag(t, keep, shared_arrival[i]))
                    i += np.uint64(1)
            else:
                _keep_two_run(best, second, shift, c32, shared_src, shared_arrival, reading_cost, w_acc, s0, s1, keep)
        for i in range(own_bounds[c], own_bounds[c + 1]):
            m = own_src[i]
            if rows:
                t = _placed_total32(
                    rel,
                    m,
                    reading_cost[own_reading[i]],
                    own_offset[i, 0],
                    own_offset[i, 1],
                    own_heading[i],
                    w_acc,
                    w_pos,
                    w_head,
                )
            else:
                t = c32[m] + w_acc * reading_cost[own_reading[i]]
            _keep_two(best, second, np.uint64(own_pos[i]), _tag(t, keep, own_arrival[i]))
        # The chunk's positions are final: mark masked nodes dead and near-ties (the
        # label all ones, which no incoming edge has), so pass 2 reads one word a node.
        # (Branch-free, so the loop is vectorised.)
        for p in range(n0, n1):
            b1, b2 = best[p], second[p]
            wide1, wide2 = np.float64(b1), np.float64(b2)
            near = (b2 < DEAD_BELOW) & (wide2 - wide1 <= TIE + alpha * (wide1 + wide2) + beta)
            best[p] = _pick(allowed_pos[p], _pick(near, _tag(b1, keep, ~keep), b1), DEAD32)


def _finish_kernel(placed: bool, parallel: bool):
    """`_finish` compiled for placed or unplaced searches (a placed search's float32
    pass always reads the relative rows): with the flag a constant, the other kind's
    branches compile away (one generic kernel took 1.4× as long in mode A)."""

    def finish(
        chunk_nodes,
        node_pos,
        best,
        best_bits,
        label_mask,
        incoming,
        edge_src,
        edge_reading,
        edge_kind,
        edge_offset,
        edge_heading,
        edge_turn,
        reading_cost,
        w_acc,
        w_pos,
        w_head,
        use_pos,
        use_head,
        mx,
        mz,
        mh,
        state_prev,
        det_prev,
        c32_base,
        state_new,
        det_new,
        c32_new,
        arrivals,
        none,
        lowest,
        highest,
        ancestor_prev,
        ancestor_new,
        pull,
    ):
        """Pass 2 of a step (see above), per node: its best edge (the float32 pass's, or
        the float64 rule's on a near-tie: best_bits' label all ones), the arrival into
        this sample's lattice row (`none`: dead or masked), the chosen path's new state
        (float64 cost and, placed, placement carried by rotation; the cost from the
        source's state row and this sample's measurement mx, mz m, mh rad, as
        `costs._relative` would give), detours and, unplaced, its float32 cost relative to
        c32_base (≤ every new cost: the lowest cost before the step); its ancestor as
        in `_advance_py`. lowest, highest (C,) each chunk's lowest and highest new
        cost of a live node (inf, −inf: none), for `search.ViterbiSearch.best_node` (`_best_in_chunks`).
        Returns (live nodes, near-ties resolved in float64).

        Per chunk, first every node's choice, prefetching its source's state; then the
        new states: the source reads are scattered over megabytes, and one loop doing
        both kept too few of them in flight."""
        live = 0
        near_ties = 0
        for c in numba.prange(chunk_nodes.shape[0] - 1):
            n0, n1 = chunk_nodes[c], chunk_nodes[c + 1]
            source = np.empty(n1 - n0, np.uint32)
            for n in range(n0, n1):
                p = node_pos[n]
                if best[p] >= DEAD_BELOW:  # no live candidate, or masked
                    arrivals[n] = none
                    continue
                label = best_bits[p] & label_mask
                if label == label_mask:  # a near-tie (marked by pass 1)
                    near_ties += 1
                    a, _ = _exact_choice(
                        n,
                        incoming,
                        edge_src,
                        edge_reading,
                        edge_kind,
                        edge_offset,
                        edge_heading,
                        reading_cost,
                        None,
                        None,
                        None,
                        None,
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
                    )
                    arrival = np.uint32(a)  # a ≥ 0: a live candidate exists
                else:
                    arrival = label
                arrivals[n] = arrival
                e = np.uint64(incoming[n]) + np.uint64(arrival)
                m = edge_src[e]
                source[n - n0] = m
                _prefetch(state_prev, m)
                _prefetch(reading_cost, edge_reading[e])  # (columns in layout order: scattered over the chunk)
                _prefetch(det_prev, m)
                if ancestor_prev.shape[0]:
                    _prefetch(ancestor_prev, m)
            chunk_low, chunk_high = np.inf, -np.inf
            for n in range(n0, n1):
                arrival = arrivals[n]
                if arrival == none:
                    _set_cost(state_new, n, np.inf)
                    if not placed:
                        c32_new[n] = DEAD32
                    continue
                live += 1
                e = np.uint64(incoming[n]) + np.uint64(arrival)
                m = source[n - n0]
                ca = reading_cost[edge_reading[e]]
                ox, oz, dh = edge_offset[e, 0], edge_offset[e, 1], edge_heading[e]
                if placed:
                    t = _state_total(state_prev, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head)
                else:
                    t = _cost_at(state_prev, m) + w_acc * ca
                    c32_new[n] = np.float32(t - c32_base)
                _set_cost(state_new, n, t)
                chunk_low, chunk_high = _fmin(chunk_low, t), _fmax(chunk_high, t)
                det_new[n] = det_prev[m] + (1 if edge_kind[e] != 0 else 0)
                if ancestor_prev.shape[0]:
                    ancestor_new[n] = ancestor_prev[m]
                if placed:
                    _carry_placement(state_prev, m, state_new, n, ox, oz, dh, edge_turn[e, 0], edge_turn[e, 1], pull)
            lowest[c], highest[c] = chunk_low, chunk_high
        return live, near_ties

    return _compile(finish, parallel)


_edge_totals, _edge_totals_serial = _compile(_edge_totals_py, True), _compile(_edge_totals_py, False)
_select, _select_serial = _compile(_select_py, True), _compile(_select_py, False)
_advance, _advance_serial = _compile(_advance_py, True), _compile(_advance_py, False)
_approx_select, _approx_select_serial = _compile(_approx_select_py, True), _compile(_approx_select_py, False)
_finish = {placed: _finish_kernel(placed, True) for placed in (False, True)}
_finish_serial = {placed: _finish_kernel(placed, False) for placed in (False, True)}
_THREADED = (_reading_costs, _relative, _edge_totals, _select, _advance, _approx_select, _finish)
_SERIAL = (
    _reading_costs_serial,
    _relative_serial,
    _edge_totals_serial,
    _select_serial,
    _advance_serial,
    _approx_select_serial,
    _finish_serial,
)


@numba.njit(cache=True, nogil=True)
def _satisfied(kinds_t, values_t, contact_code, label, ok):
    """ok (γ, N): does each node meet each set's requirement at this sample."""
    gamma, N = ok.shape
    for k in range(gamma):
        for n in range(N):
            if kinds_t[k] == 1:
                ok[k, n] = contact_code[n] == values_t[k]
            elif kinds_t[k] == 2:
                ok[k, n] = label[n] == values_t[k]
            else:
                ok[k, n] = True


@numba.njit(cache=True, nogil=True)
def _best_node(state, rank, det):
    """`ViterbiSearch.best_node` in sequential passes over the nodes (a live decoder asks
    once per sample; numpy's narrowing took 0.65 ms on 100k nodes), from state (N, W),
    rank (N, γ) and det (N,): the live nodes (finite cost) with the fewest broken
    constraints, lexicographically; among them the lowest cost, costs compared as
    round(cost / TIE) while all are below 1e6 (then as they are); then the fewest
    non-original edges; then the lowest id. −1: none live."""
    N, gamma = rank.shape
    cost = state[:, COST]
    first = -1  # a node with the best constraint counts
    for n in range(N):
        if not np.isfinite(cost[n]):
            continue
        if first < 0:
            first = n
            if gamma == 0:
                break
            continue
        for k in range(gamma):
            if rank[n, k] != rank[first, k]:
                if rank[n, k] < rank[first, k]:
                    first = n
                break
    if first < 0:
        return -1
    small = True
    lowest = np.inf
    for n in range(first, N):
        if np.isfinite(cost[n]) and (gamma == 0 or _same_rank(rank, n, first)):
            small = small and abs(cost[n]) < 1e6
            lowest = min(lowest, cost[n])
    # round() is monotone: only costs within 2·TIE of the lowest can share its key.
    near = lowest + 2 * TIE if small else lowest
    best = -1
    best_key = np.inf
    for n in range(first, N):
        if cost[n] <= near and (gamma == 0 or _same_rank(rank, n, first)):
            best, best_key = _ranked(n, cost[n], det, small, best, best_key)
    return best


@numba.njit(inline="always")
def _ranked(n, cost, det, small, best, best_key):
    """`_best_node`'s running choice (best, best_key) after candidate n (cost its cost):
    the lower key — round(cost / TIE) if small, else the cost — then fewer detours;
    among equals the earlier node stays. best −1: none yet."""
    key = np.round(cost / TIE) if small else cost
    if best < 0 or key < best_key or key == best_key and det[n] < det[best]:
        return n, key
    return best, best_key


@numba.njit(inline="always")
def _same_rank(rank, a, b):
    for k in range(rank.shape[1]):
        if rank[a, k] != rank[b, k]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _best_in_chunks(state, det, chunk_nodes, lowest, highest):
    """`_best_node` without constraint sets, from each chunk's lowest and highest live
    cost (lowest, highest (C,), inf / −inf for a chunk with none; chunk c holds the
    nodes chunk_nodes[c] … chunk_nodes[c+1]−1), as pass 2 leaves them: only chunks
    whose lowest cost is within 2·TIE of the lowest are read, where `_best_node`
    reads every node's cost twice (0.38 ms a sample on G_E: a live decoder asks every
    sample). Costs are ≥ 0, so all are below 1e6 when the highest is. −1: none live."""
    low = np.inf
    high = -np.inf
    for c in range(lowest.shape[0]):
        low = min(low, lowest[c])
        high = max(high, highest[c])
    if not np.isfinite(low):
        return -1
    small = high < 1e6
    near = low + 2 * TIE if small else low
    best = -1
    best_key = np.inf
    for c in range(lowest.shape[0]):
        if lowest[c] > near:
            continue
        for n in range(np.int64(chunk_nodes[c]), np.int64(chunk_nodes[c + 1])):
            if state[n, COST] <= near:
                best, best_key = _ranked(n, state[n, COST], det, small, best, best_key)
    return best
