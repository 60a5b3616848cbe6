"""Viterbi search over a motion graph (SPEC §4, K §5).

State = graph node. At each input sample the path advances along one edge:
    G(n, t) = min over edges e = (m → n) of [L(e, t) + G(m, t−1)],  G(n, 0) = 0,
    L(e, t) = W_A·C_A + W_P·C_P + W_O·C_O,
C_A the mean over sensors of the squared reading difference in g² (K eq. 4), C_P the
distance in metres between the path-carried ground position advanced by the edge
and the measured one, C_O the wrapped heading difference in radians (K eq. 5–7).
NaN measurements contribute nothing. With γ annotation constraint sets each path also
carries γ counts of broken constraints, compared lexicographically before G (K eq. 8).

Memory (K §5.1, after Abbasfar & Yao): instead of the N × T back-pointer lattice the
search keeps the newest samples' lattice rows dense — one byte a node: which of its
incoming edges its best path arrived by — in a ring of BLOCK + STORE_WINDOW rows
(a batch search: twice both).
When the ring is full it traces back from all live nodes through every row and
appends only the oldest BLOCK rows' points that some live path passes through to a
survivor store (rows in sample order, parent before child); by then they are
STORE_WINDOW samples old and most paths have merged. When the store has doubled, one
backward sweep keeps what the live paths still reach. The compression ratio reported
is the full lattice's memory (N·T points of 4 bytes) over the peak memory held for it
(dense rows plus store rows). Once every survivor passes through one point, the
prefix up to it is final (the converged-prefix commit of streaming decoders).

Speed (a step is bound by scattered reads of the source nodes' state and, with
position and heading, by the arithmetic per edge; this machine's share of the L3
cache is a few MB, so what is read from scattered nodes is kept small):
- Each node's best incoming edge is chosen in float32, with the chosen path's cost
  then recomputed in float64; nodes whose two best candidates are closer than
  float32 rounding could blur are decided again in float64 (see `_approx_select_py`),
  so paths, costs and ties are exactly the float64 search's. Constrained searches
  (γ > 0) keep the float64 passes throughout.
- C_A is computed once per distinct edge reading (transition edges read what their
  destination reads, so many edges share one), as float32 in g, from a transposed
  table; a batch search does 16 samples per pass over the table. Each node's shared
  reading (what most of its incoming edges read) has the column of the node's place in
  the float32 pass's layout, so that pass reads those edges' C_A in order.
- The placement is carried only when position or heading counts. The per-edge
  position and heading terms read 16-byte float32 rows relative to the measurement.
- Edges are visited in slot-major order (every node's first incoming edge, then every
  second one, …), so choosing each node's best edge is a flat, branch-free loop; the
  float32 pass takes eight edges at a time (AVX2 gathers, or eight 16-byte row loads).
- The walk back through the dense rows marks each row's predecessors in a byte map and
  lists them by scanning it, 8 nodes at a time; rows with few nodes go as lists.
"""

from __future__ import annotations

import time
import types
from dataclasses import dataclass, field

import numba
import numba.extending
import numpy as np

from graphsvc.errors import InputError, SearchCancelled
from graphsvc.graph.model import MotionGraph, incoming_offsets
from graphsvc.search._llvm import fma as _fma
from graphsvc.search._llvm import fmax as _fmax
from graphsvc.search._llvm import fmin as _fmin
from graphsvc.search._llvm import keep_two_gathered8 as _keep_two_gathered8
from graphsvc.search._llvm import keep_two_placed8 as _keep_two_placed8
from graphsvc.search._llvm import pick as _pick
from graphsvc.search._llvm import prefetch as _prefetch
from graphsvc.search._llvm import tag as _tag
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.options import Weights  # noqa: F401  (the value type; imported here by older callers)

REQ_NONE, REQ_CONTACT, REQ_LABEL = 0, 1, 2
CONTACT_CODES = {"none": 0, "left": 1, "right": 2, "both": 3}  # bit 0 left, bit 1 right


@numba.njit(cache=True, nogil=True)
def _wrap(a):
    """a wrapped into [−π, π) (floor, not a float modulo: this runs once per edge)."""
    return a - 2.0 * np.pi * np.floor((a + np.pi) * (0.5 / np.pi))


# Costs closer than this are equal (g², m, rad sums: far below any real difference).
# Among equal-cost candidates (standing still reads the same at any speed) the path
# with fewer non-original edges wins, then the plainer edge (original before
# slow-down, speed-up, transition, interpolated): exact input replays its own clip.
TIE = 1e-9


def _reading_costs_py(readings_t, meas, mask, scale, out):
    """C_A (K eq. 4, g²) of every distinct edge reading: readings_t (3S, R) float32 in
    g, transposed so the inner loop runs along readings (SIMD); meas (3S,) float32 in
    g; mask (3S,) 0 on the axes of missing sensors (skipped), 1 elsewhere; scale = 1 /
    sensors present. Each axis adds d² by one fused multiply-add, as every C_A kernel
    does (so a live and a batch search get the same values, bit for bit). A chunk of
    running sums stays in L1 across the axes; the pass is bound by reading the table
    (10 MB for 144k readings of 6 sensors)."""
    D, R = readings_t.shape
    chunk = 1024
    for c in numba.prange((R + chunk - 1) // chunk):
        r0 = c * chunk
        n = min(R, r0 + chunk) - r0
        sums = np.zeros(chunk, np.float32)
        for j in range(D):
            if mask[j] == 0.0:
                continue
            m = meas[j]
            row = readings_t[j, r0:r0 + n]
            for i in range(n):
                d = row[i] - m
                sums[i] = _fma(d, d, sums[i])
        for i in range(n):
            out[r0 + i] = sums[i] * scale


def _reading_costs_batch_py(readings_t, meas, mask, scale, out):
    """`_reading_costs` for B samples at once: meas, mask (B, 3S); scale (B,); out (B,
    R). Each chunk of the table is read once for all B samples instead of once per
    sample. Same arithmetic in the same order, so the same values, bit for bit, as the
    per-sample kernel (tested). (In the search this pass is bound by memory traffic —
    the table, and the costs written and read back: a version keeping 8 × 8 sums in
    registers ran twice as fast alone and no faster in the search.)"""
    D, R = readings_t.shape
    B = meas.shape[0]
    chunk = 128  # B × 128 running sums (8 KB at B = 16) stay in L1; 1,024 took 0.17 against 0.145 ms a sample
    for c in numba.prange((R + chunk - 1) // chunk):
        r0 = c * chunk
        n = min(R, r0 + chunk) - r0
        sums = np.zeros((B, chunk), np.float32)
        for j in range(D):
            row = readings_t[j, r0:r0 + n]
            for b in range(B):
                if mask[b, j] == 0.0:
                    continue
                m = meas[b, j]
                for i in range(n):
                    d = row[i] - m
                    sums[b, i] = _fma(d, d, sums[b, i])
        for b in range(B):
            for i in range(n):
                out[b, r0 + i] = sums[b, i] * scale[b]


def _compile(fn, parallel: bool):
    """fn compiled threaded (its prange loops spread over numba's threads) or serial.
    Each kernel is compiled both ways: threaded for one search using the whole machine
    (batch), serial for many searches side by side (a server's streams), where threads
    would only fight. The serial one is compiled from a copy of fn named …_serial:
    numba's disk cache files a function under its name and line and tells entries
    apart by signature, bytecode and closure, not by compile flags, so the two would
    load each other's machine code — whichever was cached first served both (seen:
    "serial" streams running threaded kernels)."""
    if not parallel:
        qualname = fn.__qualname__ + "_serial"
        fn = types.FunctionType(fn.__code__, fn.__globals__, fn.__name__ + "_serial", fn.__defaults__, fn.__closure__)
        fn.__qualname__ = qualname
    return numba.njit(cache=True, nogil=True, parallel=parallel)(fn)


_reading_costs_batch = _compile(_reading_costs_batch_py, True)
_reading_costs_batch_serial = _compile(_reading_costs_batch_py, False)
_reading_costs = _compile(_reading_costs_py, True)
_reading_costs_serial = _compile(_reading_costs_py, False)


# Per-node path state, one float64 row a node: the cost and — only when position or
# heading is measured — the placement: ground x, z in m, heading in rad and its cos,
# sin. Pass 2 reads a scattered source's whole state for every node, so the fields
# share a row (48 bytes placed), where a cost array and 40-byte placement rows cost 2–3
# scattered lines a node. Unpadded: rows padded to one 64-byte line were 1–3 % faster
# on the generated G_E graph but 5 % slower on a built one, whose sources are mostly the
# previous node, so bytes moved count more than lines. The detour counts (int32) and
# the broken-constraint counts (int32, γ per node) stay apart: in the row, the detours
# cost unplaced searches on built graphs 20 % of pass 2 in bytes moved (1.33 against
# 1.10 ms a sample on the kelly6 graph), and only constrained searches read the ranks.
COST = 0
X, Z, HEADING, COS, SIN = 1, 2, 3, 4, 5
PLACED_WIDTH, UNPLACED_WIDTH = 6, 1


def _cost_at(state, m):
    """Node m's cost from state rows (N, W), or from the cost column alone (N,)."""
    return state[m] if state.ndim == 1 else state[m, COST]


@numba.extending.overload(_cost_at, inline="always")
def _cost_at_kernel(state, m):
    # Unplaced searches hand pass 2 the cost column as a 1-D array: indexing an (N, 1)
    # array, whose row length numba only knows at run time, cost that pass 5–8 %.
    if state.ndim == 1:
        return lambda state, m: state[m]
    return lambda state, m: state[m, COST]


def _set_cost(state, n, value):
    """Set node n's cost in state rows (N, W) or in the cost column alone (N,)."""
    if state.ndim == 1:
        state[n] = value
    else:
        state[n, COST] = value


@numba.extending.overload(_set_cost, inline="always")
def _set_cost_kernel(state, n, value):
    if state.ndim == 1:

        def set_column(state, n, value):
            state[n] = value

        return set_column

    def set_row(state, n, value):
        state[n, COST] = value

    return set_row


# The per-edge position and heading terms read the source's placement relative to
# this sample's measurement, in the source's own frame, as float32 in one 16-byte row
# with the cost: [q, wrap(h − mh), cost − base] where q = R(h)ᵀ(p − m) (x, z), so an
# edge's offset o (in the source's frame) lands at distance |q + o| from the
# measurement — two additions an edge instead of a rotation (the APO pass 1: 0.91
# against 1.12 ms a sample with 32-byte rows of relative x, z, cos, sin). Scattered
# reads of 64-byte float64 rows fell off this machine's share of the L3 cache (3.7 ms
# against 0.8 ms for 32-byte rows over 317,600 edges); the relative float32 values keep
# ~1e-7 relative precision where it matters, near the measurement.
QX, QZ, RH, RC32 = 0, 1, 2, 3
_PI32 = np.float32(np.pi)
_TWO_PI32 = np.float32(2.0 * np.pi)
_INV_TWO_PI32 = np.float32(0.5 / np.pi)


# One step (K eq. 3 for every node) in two passes over float32 approximations and
# exact float64 fix-ups, because a pass over the 317,600 edges is bound by its
# scattered reads of the source nodes' state and float32 halves them:
# 1. `_approx_select`: every edge's total in float32 (the source's cost relative to
#    the lowest live cost, plus the edge's terms), each node keeping its lowest and
#    second-lowest candidate; the lowest carries which incoming edge it is in its low
#    mantissa bits (`tag`), so keeping the minimum is two min instructions, no branch.
#    Once a chunk's nodes are final, it marks the near-ties: nodes whose float32 gap
#    between their two best candidates is within what float32 rounding could have
#    hidden (plus TIE), a few a sample.
# 2. `_finish`: per node, unless marked, the lowest is the node's best edge exactly
#    as the float64 rule would choose it; a near-tie's candidates are compared again
#    in float64 with the full rule. Then the chosen path's new state, its cost
#    recomputed in float64, so costs, paths and ties are bit for bit those of the
#    float64 search (tested against the float64 kernels below, which constrained
#    searches still use).
# Pass 1 takes the shared edges (`search_tables`) eight at a time: on G_E (mode A) 0.28
# against 0.41 ms a sample, APO 0.70–0.76 against 0.90; pass 2 unchanged in isolation.
# Bound: a float32 total t differs from the float64 one less the base by at most
# alpha·t + beta/2: up to 5 roundings of 2^-24 relative to the sum of non-negative
# terms, the tag's 2^(k−23) (k label bits), and float64 roundings of 2^-52·(base + t).
# The search takes alpha = 2^-20 (3× the first) + 2^(k−22) and beta = 2^-48·base; a
# node whose second-best exceeds its best by more than TIE + alpha·(both) + beta
# keeps the float32 choice. (k counts the all-ones label too, which marks near-ties.)
DEAD32 = np.float32(1e38)  # float32 cost of a dead path (finite, so tagging keeps it ordered)
DEAD_BELOW = np.float32(1e37)  # a live path's relative cost never comes near this
# Edges ahead whose source's relative row pass 1 prefetches (eight at a time; APO pass 1 on
# G_E: 0.65 ms a sample at 32–96, 0.71 at 16, 0.67 without)
PREFETCH_AHEAD = np.uint64(32)


@numba.njit(inline="always")
def _place_terms(qx, qz, rh, ox, oz, dh):
    """Position (m) and heading (rad) terms of an edge (offset ox, oz in the source's
    frame, turn dh) from its source's relative row, in float32: the same arithmetic
    for the float32 pass and the float64 totals."""
    dx = qx + ox
    dz = qz + oz
    a = rh + dh
    return np.sqrt(dx * dx + dz * dz), abs(a - _TWO_PI32 * np.floor((a + _PI32) * _INV_TWO_PI32))


@numba.njit(inline="always")
def _exact_total(cost_m, qx, qz, rh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head):
    """L(e, t) + G(m, t−1) in float64 for an edge from m: cost_m its source's cost,
    qx, qz, rh the source's relative row (`_relative`), ca the edge reading's C_A;
    the position / heading terms only where they count."""
    t = cost_m + w_acc * ca
    if use_pos or use_head:
        p, h = _place_terms(qx, qz, rh, ox, oz, dh)
        if use_pos:
            t += w_pos * p
        if use_head:
            t += w_head * h
    return t


@numba.njit(inline="always")
def _row_total(rel, state, m, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head):
    """`_exact_total` for an edge from m, read from m's relative row (`_relative`)."""
    return _exact_total(_cost_at(state, m), rel[m, QX], rel[m, QZ], rel[m, RH], ca, ox, oz, dh, w_acc, w_pos, w_head,
                        use_pos, use_head)  # fmt: skip


@numba.njit(inline="always")
def _relative_row(state, m, mx, mz, mh):
    """m's relative row (QX, QZ, RH; see above) from its state and the measurement
    (mx, mz m, mh rad): q = R(h)ᵀ(p − m) in float64, rounded once."""
    rx, rz = state[m, X] - mx, state[m, Z] - mz
    c, s = state[m, COS], state[m, SIN]
    return np.float32(c * rx - s * rz), np.float32(s * rx + c * rz), np.float32(_wrap(state[m, HEADING] - mh))


@numba.njit(inline="always")
def _state_total(state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head):
    """`_row_total` from m's state row instead of its relative row: the same float32
    values (`_relative_row`), so the same total, bit for bit, with one scattered line
    read instead of two."""
    if use_pos or use_head:
        qx, qz, rh = _relative_row(state, m, mx, mz, mh)
    else:
        qx = qz = rh = np.float32(0.0)
    return _exact_total(state[m, COST], qx, qz, rh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head)


def _relative_py(state, meas_pos, meas_heading, base, rel):
    """The per-edge pass's source rows (see QX…RC32) for this sample's measurement:
    one sequential pass over the states. meas_pos (2,) m, zeros when not measured;
    meas_heading rad, 0 when not measured; base ≤ every live cost."""
    N = state.shape[0]
    for n in numba.prange(N):
        rel[n, QX], rel[n, QZ], rel[n, RH] = _relative_row(state, n, meas_pos[0], meas_pos[1], meas_heading)
        cost = state[n, COST]
        rel[n, RC32] = np.float32(cost - base) if cost != np.inf else DEAD32


# Inlined by LLVM, not by numba (inline="always"): numba's inlining of this writer of
# one array into pass 2's serial kernel left an atomic reference-count increment and
# decrement around every node's call, which numba's reference-count pruning did not
# remove (serial placed pass 2 on G_E: 2.5–3.0 against 3.2–4.1 ms a sample).
@numba.njit(cache=True, nogil=True)
def _carry_placement(place_prev, m, place_new, n, ox, oz, dh, tc, ts):
    """Node n's placement (state columns X…SIN): m's advanced by an edge (offset ox,
    oz in m's frame, turn dh with cos tc, sin ts), cos/sin carried by rotation — no
    trigonometry."""
    c, s = place_prev[m, COS], place_prev[m, SIN]
    place_new[n, X] = place_prev[m, X] + c * ox + s * oz
    place_new[n, Z] = place_prev[m, Z] - s * ox + c * oz
    place_new[n, HEADING] = place_prev[m, HEADING] + dh
    place_new[n, COS] = c * tc - s * ts
    place_new[n, SIN] = s * tc + c * ts


def _edge_totals_py(edge_src, edge_reading, edge_offset, edge_heading, reading_cost, w_acc, w_pos, w_head, use_pos,
                    use_head, state, rel, total):  # fmt: skip
    """total (E,): the cost of each path extended by each edge, G(src) + L(e, t)
    (inf from a dead source; state (N, W) the sources' states), float64 (the
    constrained search's pass). reading_cost (R,) C_A per distinct reading; use_pos /
    use_head: whether this sample's position / heading term counts (then rel holds
    `_relative`'s rows)."""
    E = edge_src.shape[0]
    if not (use_pos or use_head):
        for e in numba.prange(E):
            total[e] = state[edge_src[e], COST] + w_acc * reading_cost[edge_reading[e]]
        return
    for e in numba.prange(E):
        total[e] = _row_total(rel, state, edge_src[e], reading_cost[edge_reading[e]], edge_offset[e, 0],
                              edge_offset[e, 1], edge_heading[e], w_acc, w_pos, w_head, use_pos, use_head)  # fmt: skip


def _select_py(chunk_nodes, chunk_slots, slot_dst, slot_src, slot_kind, slot_edge, total, allowed, det_prev,
               rank_prev, best_slot, state_new, best_edge):  # fmt: skip
    """Each node's best incoming edge (graph edge id, −1: none alive, or the node is
    masked) and its path's cost (state_new's COST): fewest broken constraints (rank,
    lexicographic), then lowest total (within TIE counts as equal), then fewer
    non-original edges so far (det_prev, read only on a near-tie), then the
    plainer edge kind.

    Edges come in slot-major order within chunks of nodes (see `search_tables`): slot
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


@numba.njit(inline="always")
def _tie_better(i, b, slot_src, slot_kind, det_prev):
    """Between two paths of equal cost (within TIE): fewer non-original edges, then
    the plainer edge kind."""
    det = det_prev[slot_src[i]] + (1 if slot_kind[i] != 0 else 0)
    best_det = det_prev[slot_src[b]] + (1 if slot_kind[b] != 0 else 0)
    if det != best_det:
        return det < best_det
    return slot_kind[i] < slot_kind[b]


def _advance_py(best_edge, incoming, edge_src, edge_kind, edge_offset, edge_heading, edge_turn, ok, placed, state_prev,
                det_prev, rank_prev, state_new, det_new, rank_new, arrivals, none, ancestor_prev,
                ancestor_new):  # fmt: skip
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
            _carry_placement(state_prev, m, state_new, n, edge_offset[e, 0], edge_offset[e, 1], edge_heading[e],
                             edge_turn[e, 0], edge_turn[e, 1])  # fmt: skip
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
    heading (`keep_two_placed8` computes the same, eight at a time, bit for bit)."""
    pos, head = _place_terms(rel[m, QX], rel[m, QZ], rel[m, RH], ox, oz, dh)
    return rel[m, RC32] + w_acc * ca + w_pos * pos + w_head * head


@numba.njit(inline="always")
def _keep_two_run(best, second, shift, costs, src, labels, reading_cost, w_acc, s0, s1, keep):
    """`_keep_two` at positions p = i + shift of costs[src[i]] + w_acc · reading_cost[p]
    tagged with labels[i], for i in s0…s1−1 (uint64; shift wraps), eight at a time
    (`keep_two_gathered8`), the rest one by one."""
    i = s0
    while i + np.uint64(8) <= s1:
        _keep_two_gathered8(best, second, i + shift, costs, src, i, reading_cost, w_acc, keep, labels)
        i += np.uint64(8)
    while i < s1:
        _keep_two(best, second, i + shift, _tag(costs[src[i]] + w_acc * reading_cost[i + shift], keep, labels[i]))
        i += np.uint64(1)


def _approx_select_py(chunk_nodes, shared_slots, shared_src, shared_arrival, shared_offset, shared_heading,
                      own_bounds, own_src, own_reading, own_pos, own_arrival, own_offset, own_heading, reading_cost,
                      w_acc, w_pos, w_head, rows, c32, rel, keep, allowed_pos, alpha, beta, best,
                      second):  # fmt: skip
    """Pass 1 of a step (see above): best[p], second[p] (N,) float32, the lowest and
    second-lowest float32 total among the incoming edges of the node at layout
    position p (`search_tables`); best's low bits (`keep` clears them) hold which of
    the node's incoming edges it is (its arrival index, `float32_tables`); DEAD32:
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
                    _keep_two_placed8(best, second, i + shift, rel, shared_src, i, shared_offset, shared_heading,
                                      reading_cost, w_acc, w_pos, w_head, keep, shared_arrival)  # fmt: skip
                    i += np.uint64(8)
                while i < s1:
                    t = _placed_total32(rel, shared_src[i], reading_cost[i + shift], shared_offset[i, 0],
                                        shared_offset[i, 1], shared_heading[i], w_acc, w_pos, w_head)  # fmt: skip
                    _keep_two(best, second, i + shift, _tag(t, keep, shared_arrival[i]))
                    i += np.uint64(1)
            else:
                _keep_two_run(best, second, shift, c32, shared_src, shared_arrival, reading_cost, w_acc, s0, s1, keep)
        for i in range(own_bounds[c], own_bounds[c + 1]):
            m = own_src[i]
            if rows:
                t = _placed_total32(rel, m, reading_cost[own_reading[i]], own_offset[i, 0], own_offset[i, 1],
                                    own_heading[i], w_acc, w_pos, w_head)  # fmt: skip
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


@numba.njit(inline="always")
def _reading_cost(readings, r, meas, mask, scale):
    """C_A of reading r alone, from its row of readings (R, 3S) float32 in g: the same
    arithmetic in the same order as `_reading_costs_py`, so the same value, bit for
    bit (a beam step computes only the readings its edges read)."""
    total = np.float32(0.0)
    for j in range(readings.shape[1]):
        if mask[j] != 0.0:
            d = readings[r, j] - meas[j]
            total = _fma(d, d, total)
    return total * scale


def _edge_ca(reading_cost, readings, meas, mask, scale, r):
    """C_A of reading r: reading_cost[r] (every reading's, (R,)), or, where
    reading_cost is None, computed from its row (`_reading_cost`)."""


@numba.extending.overload(_edge_ca, inline="always")
def _edge_ca_kernel(reading_cost, readings, meas, mask, scale, r):
    if isinstance(reading_cost, numba.types.NoneType):
        return lambda reading_cost, readings, meas, mask, scale, r: _reading_cost(readings, r, meas, mask, scale)
    return lambda reading_cost, readings, meas, mask, scale, r: reading_cost[r]


def _source_total(placed, state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head):
    """An edge's total from its source m's state: `_state_total` when placed, else the
    cost plus W_A·C_A; state (N, W) or the cost column alone (N,) (see `_cost_at`)."""


@numba.extending.overload(_source_total, inline="always")
def _source_total_kernel(placed, state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head):
    if state.ndim == 1:  # (unplaced pass 2 hands over the cost column)
        return lambda placed, state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head: \
            state[m] + w_acc * ca

    def total(placed, state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head):
        if placed:
            return _state_total(state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head)
        return state[m, COST] + w_acc * ca

    return total


@numba.njit(inline="always")
def _exact_choice(n, incoming, edge_src, edge_reading, edge_kind, edge_offset, edge_heading, reading_cost, readings,
                  meas, mask, scale, w_acc, w_pos, w_head, use_pos, use_head, mx, mz, mh, placed, state,
                  det_prev):  # fmt: skip
    """Node n's best incoming edge by the float64 rule of `_select_py` (candidates in
    graph order; lower total beyond TIE, else fewer detours, then plainer kind), each
    total from its source's state as pass 2 computes it (`_source_total`; the relative
    rows' values, bit for bit): (arrival index, −1 if no source is live; the total).
    C_A: see `_edge_ca` (pass 2's near-ties pass every reading's, a beam step None)."""
    first = np.int64(incoming[n])
    best = np.int64(-1)
    cb = np.inf
    for e in range(first, np.int64(incoming[n + 1])):
        m = np.int64(edge_src[e])
        if _cost_at(state, m) == np.inf:  # (never the better; its C_A is not worth computing)
            continue
        ca = _edge_ca(reading_cost, readings, meas, mask, scale, edge_reading[e])
        t = _source_total(placed, state, m, mx, mz, mh, ca, edge_offset[e, 0], edge_offset[e, 1], edge_heading[e],
                          w_acc, w_pos, w_head, use_pos, use_head)  # fmt: skip
        better = t < cb - TIE
        if abs(t - cb) <= TIE:
            better = _tie_better(e, best, edge_src, edge_kind, det_prev)  # (graph order instead of slot order)
        if better:
            best, cb = e, t
    return (best - first if best >= 0 else np.int64(-1)), cb


def _finish_kernel(placed: bool, parallel: bool):
    """`_finish` compiled for placed or unplaced searches (a placed search's float32
    pass always reads the relative rows): with the flag a constant, the other kind's
    branches compile away (one generic kernel took 1.4× as long in mode A)."""

    def finish(chunk_nodes, node_pos, best, best_bits, label_mask, incoming, edge_src, edge_reading, edge_kind,
               edge_offset, edge_heading, edge_turn, reading_cost, w_acc, w_pos, w_head, use_pos, use_head, mx, mz, mh,
               state_prev, det_prev, c32_base, state_new, det_new, c32_new, arrivals, none, lowest, highest,
               ancestor_prev, ancestor_new):  # fmt: skip
        """Pass 2 of a step (see above), per node: its best edge (the float32 pass's, or
        the float64 rule's on a near-tie: best_bits' label all ones), the arrival into
        this sample's lattice row (`none`: dead or masked), the chosen path's new state
        (float64 cost and, placed, placement carried by rotation; the cost from the
        source's state row and this sample's measurement mx, mz m, mh rad, as
        `_relative` would give), detours and, unplaced, its float32 cost relative to
        c32_base (≤ every new cost: the lowest cost before the step); its ancestor as
        in `_advance_py`. lowest, highest (C,) each chunk's lowest and highest new
        cost of a live node (inf, −inf: none), for `best_node` (`_best_in_chunks`).
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
                    a, _ = _exact_choice(n, incoming, edge_src, edge_reading, edge_kind, edge_offset, edge_heading,
                                         reading_cost, None, None, None, None, w_acc, w_pos, w_head, use_pos,
                                         use_head, mx, mz, mh, placed, state_prev, det_prev)  # fmt: skip
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
                    _carry_placement(state_prev, m, state_new, n, ox, oz, dh, edge_turn[e, 0], edge_turn[e, 1])
            lowest[c], highest[c] = chunk_low, chunk_high
        return live, near_ties

    return _compile(finish, parallel)


@numba.njit(cache=True, nogil=True)
def _path_terms(edges, readings_t, edge_reading, edge_offset, edge_heading, edge_turn, meas, mask, present, meas_pos,
                meas_heading, use_pos, use_head, x, z, h, c, s):  # fmt: skip
    """Accumulated acc (g²), position (m) and heading (rad) costs along one path, with
    the search's arithmetic. edges (T−1,); meas/mask (T, 3S) float32 as the search's
    measurement vectors; present (T,) sensors present; meas_pos (T, 2), meas_heading
    (T,); use_* whether each term counted; x, z, h, c, s the start placement."""
    out = np.zeros(3)
    D = readings_t.shape[0]
    for k in range(edges.shape[0]):
        t = k + 1
        e = edges[k]
        if present[t] > 0:
            r = edge_reading[e]
            acc = np.float32(0.0)
            for j in range(D):
                if mask[t, j] != 0.0:
                    d = readings_t[j, r] - meas[t, j]
                    acc = _fma(d, d, acc)  # as the C_A kernels: the search's values, bit for bit
            out[0] += acc * np.float32(1.0 / present[t])
        ox, oz = edge_offset[e, 0], edge_offset[e, 1]
        tc, ts = edge_turn[e, 0], edge_turn[e, 1]
        x, z = x + c * ox + s * oz, z - s * ox + c * oz
        h = h + edge_heading[e]
        c, s = c * tc - s * ts, s * tc + c * ts
        if use_pos and np.isfinite(meas_pos[t, 0]) and np.isfinite(meas_pos[t, 1]):
            out[1] += np.sqrt((x - meas_pos[t, 0]) ** 2 + (z - meas_pos[t, 1]) ** 2)
        if use_head and np.isfinite(meas_heading[t]):
            out[2] += abs(_wrap(h - meas_heading[t]))
    return out


_relative, _relative_serial = _compile(_relative_py, True), _compile(_relative_py, False)
_edge_totals, _edge_totals_serial = _compile(_edge_totals_py, True), _compile(_edge_totals_py, False)
_select, _select_serial = _compile(_select_py, True), _compile(_select_py, False)
_advance, _advance_serial = _compile(_advance_py, True), _compile(_advance_py, False)
_approx_select, _approx_select_serial = _compile(_approx_select_py, True), _compile(_approx_select_py, False)
_finish = {placed: _finish_kernel(placed, True) for placed in (False, True)}
_finish_serial = {placed: _finish_kernel(placed, False) for placed in (False, True)}
_THREADED = (_reading_costs, _relative, _edge_totals, _select, _advance, _approx_select, _finish)
_SERIAL = (_reading_costs_serial, _relative_serial, _edge_totals_serial, _select_serial, _advance_serial,
           _approx_select_serial, _finish_serial)  # fmt: skip


def search_tables(graph: MotionGraph) -> dict:
    """The graph's arrays in the search's layout, made once per graph and cached on
    it. Each node's shared reading is the distinct reading most of its incoming edges
    read (the first-met among equals; on built graphs the node's own frame: 79–86 % of
    the edges read their destination's), and those edges are its shared ones. Nodes
    are laid out (node_pos (N,) uint32 each node's position) in SELECT_CHUNKS chunks
    of consecutive ids (`_chunks`), within a chunk by descending count of
    shared edges, then id. The readings, transposed (3S, R) float32 in g: column p the
    shared reading of the node at layout position p (zeros for a node without
    incoming edges), then the readings only other edges read (distinct, in order of
    first use), so the float32 pass reads its shared edges' C_A in layout order, not
    scattered; edge_reading (E,) int32 each edge's column; edge_shared (E,) bool.
    Compact edge arrays."""
    cached = getattr(graph, "_search_tables", None)
    if cached is not None:
        return cached
    N, E = graph.num_nodes, graph.num_edges
    flat = np.ascontiguousarray(graph.edge_acc, dtype=np.float32).reshape(E, -1)
    first_edge, distinct = distinct_rows(flat)
    in_g = (flat[first_edge].astype(np.float64) / GRAVITY).astype(np.float32)
    incoming = np.ascontiguousarray(graph.incoming, dtype=np.int32)  # E < 2³¹ (edge ids are int32 here)
    dst = graph.edge_dst.astype(np.int64)  # (edges are numbered by destination)
    # each node's shared reading: its longest run of one reading, sorted by node and reading
    by_reading = np.lexsort((distinct, dst))
    run_dst, run_reading = dst[by_reading], distinct[by_reading].astype(np.int64)
    starts = np.flatnonzero(np.r_[True, (run_dst[1:] != run_dst[:-1]) | (run_reading[1:] != run_reading[:-1])])
    run_len = np.diff(np.r_[starts, E])
    run_dst, run_reading = run_dst[starts], run_reading[starts]
    longest = np.lexsort((run_reading, -run_len, run_dst))  # per node: longest first, then first-met reading
    first = longest[np.r_[True, run_dst[longest][1:] != run_dst[longest][:-1]]] if len(longest) else longest
    node_shared = np.full(N, -1, dtype=np.int64)  # −1: no incoming edges
    node_shared[run_dst[first]] = run_reading[first]
    edge_shared = distinct == node_shared[dst]
    _, node_chunk = _chunks(N)
    node_pos = _layout(node_chunk, np.bincount(dst[edge_shared], minlength=N))  # by shared edges
    # columns: one per layout position, then the readings no node shares, by first use
    column = np.full(len(first_edge), N, dtype=np.int64)
    holders = np.flatnonzero(node_shared >= 0)
    np.minimum.at(column, node_shared[holders], node_pos[holders])  # (a reading several nodes share: the first)
    others = np.unique(distinct[~edge_shared])
    others = others[column[others] == N]  # (distinct numbers run in order of first use)
    column[others] = N + np.arange(len(others))
    readings = np.zeros((N + len(others), flat.shape[1]), dtype=np.float32)
    readings[node_pos[holders]] = in_g[node_shared[holders]]
    readings[N:] = in_g[others]
    edge_reading = np.where(edge_shared, node_pos[dst], column[distinct]).astype(np.int32)
    tables = {
        "readings_t": np.ascontiguousarray(readings.T),
        "edge_reading": edge_reading,
        "edge_shared": edge_shared,
        "node_pos": node_pos.astype(np.uint32),
        "incoming": incoming,
        "edge_src": np.ascontiguousarray(graph.edge_src, dtype=np.int32),
        "edge_kind": np.ascontiguousarray(graph.edge_kind, dtype=np.uint8),
        "edge_offset": np.ascontiguousarray(graph.edge_offset, dtype=np.float32),
        "edge_heading": np.ascontiguousarray(graph.edge_heading, dtype=np.float32),
        "edge_turn": np.ascontiguousarray(np.stack([np.cos(graph.edge_heading.astype(np.float64)),
                                                    np.sin(graph.edge_heading.astype(np.float64))], axis=-1)),
    }
    graph._search_tables = tables
    return tables


def distinct_rows(rows: np.ndarray, hashes: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of a (E, D) 4-byte array, compared bit for bit, numbered in
    order of first appearance: (first (R,) ascending, the index of each distinct row's
    first appearance; label (E,) int32, each row's number). Rows are hashed to 64 bits
    (FNV-1a over the words) and the hashes sorted — a 1-D sort, about 5× faster than
    numpy's row-wise unique on a 400k-edge graph; rows that share a hash but differ
    (checked) fall back to the row-wise unique. hashes: (E,) uint64 to use instead
    (tests force collisions with it)."""
    words = np.ascontiguousarray(rows).view(np.uint32).reshape(len(rows), -1)
    if hashes is None:
        hashes = np.full(len(words), 0xCBF29CE484222325, dtype=np.uint64)
        for j in range(words.shape[1]):
            hashes = (hashes ^ words[:, j]) * np.uint64(0x100000001B3)
    _, first, group = np.unique(hashes, return_index=True, return_inverse=True)
    if not np.array_equal(words[first[group.reshape(-1)]], words):
        _, first, group = np.unique(words, axis=0, return_index=True, return_inverse=True)
    by_first_use = np.argsort(first, kind="stable")
    label = np.empty(len(first), dtype=np.int32)
    label[by_first_use] = np.arange(len(first), dtype=np.int32)
    return first[by_first_use], label[group.reshape(-1)]


# Nodes are split into this many chunks (contiguous ranges) for the slot-major passes
# (a chunk's float32 best / second-best pair, 8 bytes a node, stays in L1); fixed, so
# results never depend on the thread count.
SELECT_CHUNKS = 64


def _chunks(N: int) -> tuple[np.ndarray, np.ndarray]:
    """chunk_nodes (C+1,) int64, the node bounds of the SELECT_CHUNKS chunks; each
    node's chunk (N,)."""
    chunk_nodes = np.linspace(0, N, SELECT_CHUNKS + 1).astype(np.int64)
    return chunk_nodes, np.searchsorted(chunk_nodes, np.arange(N), side="right") - 1


def _layout(node_chunk: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Each node's layout position (N,) int64: by chunk, then descending count, then id."""
    N = len(count)
    node_pos = np.empty(N, dtype=np.int64)
    node_pos[np.lexsort((np.arange(N), -count, node_chunk))] = np.arange(N)
    return node_pos


def _arrivals(graph: MotionGraph, incoming: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each edge's destination (E,) int64 and its index among the destination's
    incoming edges (its arrival index, or slot) (E,) int64 (edges are numbered by
    destination)."""
    dst = graph.edge_dst.astype(np.int64)
    return dst, np.arange(graph.num_edges, dtype=np.int64) - incoming.astype(np.int64)[dst]


def _slot_major(dst: np.ndarray, slot: np.ndarray, node_chunk: np.ndarray, node_pos: np.ndarray, D: int):
    """Entries (one per edge: destination node, slot) in slot-major order within chunks:
    chunk c's entries, slot 0's first, each slot's in layout order; and (C, D+1) where
    chunk c's slot j lies in that order."""
    key = node_chunk[dst] * (D + 1) + slot
    order = np.lexsort((node_pos[dst], key))
    bounds = np.searchsorted(key[order], (np.arange(SELECT_CHUNKS)[:, None] * (D + 1) + np.arange(D + 1)))
    return order, np.ascontiguousarray(bounds, dtype=np.int64)


def slot_tables(graph: MotionGraph) -> dict:
    """For the float64 passes (constrained searches), made once per graph and cached
    on it: the per-edge arrays the edge and select passes read, permuted into
    slot-major order within chunks of nodes: chunk c's edges, first every node's first
    incoming edge, then every second one, … Within a chunk nodes are laid out by
    descending in-degree (then id), so slot j holds the chunk's first count_j layout
    positions in order. chunk_nodes (C+1,) node bounds; chunk_slots (C, D+1) where
    chunk c's slot j lies; slot_dst (E,) each entry's node; slot_edge (E,) graph edge
    id."""
    cached = getattr(graph, "_slot_tables", None)
    if cached is not None:
        return cached
    tables = search_tables(graph)
    N, E = graph.num_nodes, graph.num_edges
    degree = np.diff(tables["incoming"]).astype(np.int64)
    dst, slot = _arrivals(graph, tables["incoming"])
    D = int(slot.max()) + 1 if E else 1
    chunk_nodes, node_chunk = _chunks(N)
    node_pos = _layout(node_chunk, degree)
    order, chunk_slots = _slot_major(dst, slot, node_chunk, node_pos, D)
    graph._slot_tables = {
        "chunk_nodes": chunk_nodes,
        "chunk_slots": chunk_slots,
        "slot_edge": order.astype(np.int32),
        "slot_dst": dst[order].astype(np.int32),
        "slot_src": tables["edge_src"][order],
        "slot_kind": tables["edge_kind"][order],
        "slot_reading": tables["edge_reading"][order],
        "slot_offset": np.ascontiguousarray(tables["edge_offset"][order]),
        "slot_heading": tables["edge_heading"][order],
    }
    return graph._slot_tables


def float32_tables(graph: MotionGraph) -> dict:
    """For the float32 pass (`_approx_select`), made once per graph and cached on it,
    in `search_tables`' node layout. Shared edges in slot-major order within chunks
    (as in `slot_tables`; slot j holds each node's j-th shared edge, in graph order):
    shared_slots (C, D+1) uint64 where chunk c's slot j lies, shared_src (uint32),
    shared_arrival (uint8, or uint16 where a node has 256 incoming edges or more:
    the edge's arrival index, the label pass 1 tags it with), shared_offset (·, 2),
    shared_heading; their reading is their destination's layout position. The rest,
    one entry an edge, by chunk, arrival and layout position (so no two neighbours
    in a run share a node), own_bounds (C+1,) uint64 per chunk: own_src,
    own_reading, own_pos (layout position), own_arrival (uint32), own_offset,
    own_heading. chunk_nodes (C+1,) uint64. Only for graphs whose nodes have fewer
    than 4,096 incoming edges (the float32 pass's limit)."""
    cached = getattr(graph, "_float32_tables", None)
    if cached is not None:
        return cached
    tables = search_tables(graph)
    N = graph.num_nodes
    shared = tables["edge_shared"]
    dst, arrival = _arrivals(graph, tables["incoming"])
    chunk_nodes, node_chunk = _chunks(N)
    node_pos = tables["node_pos"].astype(np.int64)
    shared_edges = np.flatnonzero(shared)  # (by node, then graph order)
    sd = dst[shared_edges]
    rank = np.arange(len(sd)) - np.searchsorted(sd, sd)  # each shared edge's index among its node's
    order, shared_slots = _slot_major(sd, rank, node_chunk, node_pos, int(rank.max(initial=0)) + 1)
    shared_edges = shared_edges[order]
    own = np.flatnonzero(~shared)
    own = own[np.lexsort((node_pos[dst[own]], arrival[own], node_chunk[dst[own]]))]
    graph._float32_tables = {
        "chunk_nodes": chunk_nodes.astype(np.uint64),
        "shared_slots": shared_slots.astype(np.uint64),
        "shared_src": tables["edge_src"][shared_edges].view(np.uint32),
        "shared_arrival": arrival[shared_edges].astype(np.uint8 if arrival.max(initial=0) < 256 else np.uint16),
        "shared_offset": np.ascontiguousarray(tables["edge_offset"][shared_edges]),
        "shared_heading": tables["edge_heading"][shared_edges],
        "own_bounds": np.searchsorted(node_chunk[dst[own]], np.arange(SELECT_CHUNKS + 1)).astype(np.uint64),
        "own_src": tables["edge_src"][own].view(np.uint32),
        "own_reading": tables["edge_reading"][own].view(np.uint32),
        "own_pos": node_pos[dst[own]].astype(np.uint32),
        "own_arrival": arrival[own].astype(np.uint32),
        "own_offset": np.ascontiguousarray(tables["edge_offset"][own]),
        "own_heading": tables["edge_heading"][own],
    }
    return graph._float32_tables


# Survivor store: rows of one (capacity, 4) int32 array — node, edge used to arrive,
# parent row, sample. Rows are appended a block at a time in sample order, so a parent
# always precedes its children and garbage collection is one backward sweep.
NODE, EDGE, PARENT, TIME = 0, 1, 2, 3


# The walks back list each row's nodes: its predecessors are marked in a byte map and
# listed by scanning it while they are more than 1 / SPARSE_SHARE of the nodes (or 16),
# then deduplicated as a list (the byte map only telling repeats apart) and sorted only
# where the flush lists them. On G_E a flush walks 256 rows, all but the newest few
# with 1–8 nodes: 3.1 ms against 9.5 scanning the whole map for each row while marking
# the next; on the built kelly6 graph, whose paths stay apart for longer, 0.28 against
# 0.48 ms a sample (marking in a loop of its own keeps more writes in flight). Shares
# from 1/256 to 1/16384 measured alike.
SPARSE_SHARE = 256


@numba.njit(inline="always")
def _marked(alive, alive_words, nodes):
    """The nodes marked in the byte map alive (see `_block_levels`), ascending, into
    nodes; clears the map, 8 nodes at a time where none is marked. Returns their count."""
    count = 0
    for w in range(alive_words.shape[0]):
        if alive_words[w] == 0:
            continue
        for n in range(8 * w, 8 * w + 8):
            if alive[n]:
                nodes[count] = n
                count += 1
        alive_words[w] = 0
    return count


@numba.njit(inline="always")
def _predecessors(nodes, count, arrivals, row, incoming, edge_src, alive, few, preds):
    """The distinct predecessors at physical row `row` of nodes[:count], into nodes;
    preds (N,) scratch. Many (count > few): marked in the byte map alive, then listed
    by scanning it, ascending; few: listed as first met, the map only telling repeats
    apart. The map is left clear. Returns (their count, whether ascending)."""
    if count > few:
        for i in range(count):
            n = nodes[i]
            alive[edge_src[incoming[n] + arrivals[row, n]]] = 1
        return _marked(alive, alive.view(np.uint64), nodes), True
    distinct = 0
    for i in range(count):
        n = nodes[i]
        m = edge_src[incoming[n] + arrivals[row, n]]
        if not alive[m]:
            alive[m] = 1
            preds[distinct] = m
            distinct += 1
    for i in range(distinct):
        alive[preds[i]] = 0
        nodes[i] = preds[i]
    return distinct, False


@numba.njit(cache=True, nogil=True)
def _block_levels(arrivals, first, used, flush, incoming, edge_src, alive, level_nodes, level_start, ancestor,
                  state):  # fmt: skip
    """Walk back from logical row used − 1, one row at a time, to the oldest:
    level_nodes[level_start[k]:level_start[k+1]] are the distinct nodes, ascending,
    that logical row k's surviving paths pass through, listed for the oldest `flush`
    rows (the newer ones are only walked through). The paths alive now (state (N, W)
    with a finite cost) pass through ancestor[n] (N,) at row used − 1. arrivals (R, N)
    the dense window, a ring: logical row k is physical row (first + k) % R; each entry
    is which of the node's incoming edges its best path arrived by, so its predecessor
    is edge_src[incoming[n] + arrival]. alive (N rounded up to 8,) uint8 scratch, zero
    on entry and on return. A row's predecessors are marked in that byte map and
    listed by one sequential scan of it while they are many (the scattered writes land
    in N bytes, which stay in cache); once few (see SPARSE_SHARE), as a list.
    Returns (total, converged_row): converged_row is the highest row walked where a
    single node remains (−1 if none); total = −1 when level_nodes is too small (the
    caller grows it and asks again)."""
    R, N = arrivals.shape
    for n in range(N):
        if state[n, COST] != np.inf:
            alive[ancestor[n]] = 1
    nodes, preds = np.empty(N, np.int32), np.empty(N, np.int32)
    count, ascending = _marked(alive, alive.view(np.uint64), nodes), True
    few = max(N // SPARSE_SHARE, 16)
    end = level_nodes.shape[0]
    pos = end  # filled downwards, newest row first: rows end up in order
    counts = np.zeros(used, np.int64)
    for k in range(used - 1, -1, -1):
        row = (first + k) % R
        if k < flush:
            if pos < count:
                return -1, -1  # (the byte map is clear)
            if not ascending:
                nodes[:count].sort()
            for i in range(count - 1, -1, -1):
                pos -= 1
                level_nodes[pos] = nodes[i]
        counts[k] = count
        if k > 0:
            count, ascending = _predecessors(nodes, count, arrivals, row, incoming, edge_src, alive, few, preds)
    total = end - pos
    level_nodes[:total] = level_nodes[pos:end].copy()
    level_start[0] = 0
    for k in range(flush):
        level_start[k + 1] = level_start[k] + counts[k]
    converged_row = -1
    for k in range(used):
        if counts[k] == 1:
            converged_row = k
    return total, converged_row


@numba.njit(cache=True, nogil=True)
def _converged_row(arrivals, first, used, lowest, incoming, edge_src, none, alive):
    """`_block_levels` without the lists, for the dense-window mode: the highest logical
    row in [lowest, used) where the paths of every node alive at the newest row pass
    through a single node, or −1. Stops there (every older row then holds one node too)."""
    R, N = arrivals.shape
    top = (first + used - 1) % R
    nodes, preds = np.empty(N, np.int32), np.empty(N, np.int32)
    count = 0
    for n in range(N):
        if arrivals[top, n] != none:
            nodes[count] = n
            count += 1
    few = max(N // SPARSE_SHARE, 16)
    for k in range(used - 1, lowest - 1, -1):
        if count == 1:
            return k
        if k > lowest:
            count, _ = _predecessors(nodes, count, arrivals, (first + k) % R, incoming, edge_src, alive, few, preds)
    return -1


@numba.njit(cache=True, nogil=True)
def _append_block(arrivals, first, flush, t_first, incoming, edge_src, heads, store, size, level_nodes, level_start,
                  row_of):  # fmt: skip
    """Append the surviving lattice points (see `_block_levels`) of the window's
    oldest `flush` rows (samples t_first…) to the store in sample order; heads (N,):
    each node's store row at the sample before them on entry, at their last sample on
    return (−1: no surviving path passes). row_of (N,) scratch. Returns the new size."""
    R = arrivals.shape[0]
    for k in range(flush):
        row = (first + k) % R
        for i in range(level_start[k], level_start[k + 1]):
            n = level_nodes[i]
            e = incoming[n] + arrivals[row, n]
            m = edge_src[e]
            store[size, NODE] = n
            store[size, EDGE] = e
            store[size, PARENT] = heads[m] if k == 0 else row_of[m]
            store[size, TIME] = t_first + k
            size += 1
        # row_of now refers to row k (read by row k+1); a node appears once per row.
        for i in range(level_start[k], level_start[k + 1]):
            row_of[level_nodes[i]] = size - (level_start[k + 1] - i)
    heads[:] = -1
    for i in range(level_start[flush - 1], level_start[flush]):
        heads[level_nodes[i]] = row_of[level_nodes[i]]
    return size


@numba.njit(cache=True, nogil=True)
def _collect(store, size, heads, keep_from):
    """Keep only rows some live head reaches, from sample keep_from on (earlier ones
    are forgotten: a kept row whose parent is forgotten gets parent −1); renumber
    parents and heads. Returns the new size."""
    keep = np.zeros(size, np.bool_)
    for n in range(heads.shape[0]):
        if heads[n] >= 0 and store[heads[n], TIME] >= keep_from:
            keep[heads[n]] = True
    for i in range(size - 1, -1, -1):
        if keep[i] and store[i, PARENT] >= 0 and store[store[i, PARENT], TIME] >= keep_from:
            keep[store[i, PARENT]] = True
    new_row = np.empty(size, np.int32)  # store rows are int32 throughout
    j = 0
    for i in range(size):
        if keep[i]:
            new_row[i] = j
            p = store[i, PARENT]
            store[j, NODE] = store[i, NODE]
            store[j, EDGE] = store[i, EDGE]
            store[j, PARENT] = new_row[p] if p >= 0 and keep[p] else -1
            store[j, TIME] = store[i, TIME]
            j += 1
    for n in range(heads.shape[0]):
        if heads[n] >= 0:
            heads[n] = new_row[heads[n]] if keep[heads[n]] else -1
    return j


@numba.njit(cache=True, nogil=True)
def _converged_until(store, size, t_from, t_to):
    """The last sample in [t_from, t_to] up to which every sample has exactly one row
    (all survivors agree), or t_from − 1. Rows are in sample order."""
    counts = np.zeros(t_to - t_from + 1, np.int64)
    for i in range(size):
        tt = store[i, TIME]
        if t_from <= tt <= t_to:
            counts[tt - t_from] += 1
    last = t_from - 1
    for k in range(counts.shape[0]):
        if counts[k] != 1:
            break
        last = t_from + k
    return last


@numba.njit(cache=True, nogil=True)
def _trace(arrivals, first, used, t, heads, incoming, edge_src, store, node, since):
    """Nodes at samples since..t of the path ending at `node` at sample t, and the
    edge each was entered by (−1 at sample 0): through the dense window's rows (the
    newest `used` of the ring, see `_block_levels`), then the store."""
    R = arrivals.shape[0]
    count = t - since + 1
    nodes = np.empty(count, np.int64)
    edges = np.empty(count, np.int64)
    i = count - 1
    n = node
    for k in range(used - 1, -1, -1):
        if i < 0:
            break
        e = incoming[n] + arrivals[(first + k) % R, n]
        nodes[i] = n
        edges[i] = e
        n = edge_src[e]
        i -= 1
    row = heads[n] if i >= 0 else -1
    while i >= 0:
        nodes[i] = store[row, NODE]
        edges[i] = store[row, EDGE]
        row = store[row, PARENT]
        i -= 1
    return nodes, edges


@dataclass
class SearchResult:
    """node_path (T,), edge_path (T−1,) int64; cost: total weighted cost of the path;
    terms: accumulated acc (g²), position (m) and heading (rad) costs; broken: per
    constraint set, broken constraints; compression: see `ViterbiSearch.compression`;
    peak_entries: peak rows in the survivor store."""

    node_path: np.ndarray
    edge_path: np.ndarray
    cost: float
    terms: dict
    broken: list[int]
    compression: float
    peak_entries: int
    extra: dict = field(default_factory=dict)


def compile_constraints(graph: MotionGraph, constraint_sets: list, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Constraint sets (priority order; each a list of {start_s, end_s, require:
    {contact: left|right|both|none} or {label: NAME}}) → per-sample requirement kinds
    and values, (γ, T) int arrays. A sample without a requirement in a set is free."""
    gamma = len(constraint_sets)
    T = len(times_s)
    kinds = np.zeros((gamma, T), dtype=np.int64)
    values = np.zeros((gamma, T), dtype=np.int64)
    for k, cset in enumerate(constraint_sets):
        for item in cset:
            start, end = float(item["start_s"]), float(item["end_s"])
            req = item["require"]
            if "contact" in req:
                if req["contact"] not in CONTACT_CODES:
                    raise InputError(f"constraint set {k}: unknown contact requirement {req['contact']!r}")
                kind, value = REQ_CONTACT, CONTACT_CODES[req["contact"]]
            elif "label" in req:
                if req["label"] not in graph.labels:
                    raise InputError(f"constraint set {k}: unknown label {req['label']!r} (graph labels: {', '.join(graph.labels)})")
                kind, value = REQ_LABEL, graph.labels.index(req["label"])
            else:
                raise InputError(f"constraint set {k}: 'require' needs 'contact' or 'label'")
            span = (times_s >= start) & (times_s <= end)
            kinds[k, span] = kind
            values[k, span] = value
    return kinds, values


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


def _beam_step_py(active, n_active, out_start, out_dst, allowed, immortal, marks, marks_words, touched, total, keep,
                  survivors_out, incoming, edge_src, edge_reading, edge_kind, edge_offset, edge_heading, edge_turn,
                  readings, meas, mask, scale, w_acc, w_pos, w_head, use_pos, use_head, mx, mz, mh, placed, beam,
                  state_prev, det_prev, state_new, det_new, arrivals, none, ancestor_prev, ancestor_new,
                  chunk_low):  # fmt: skip
    """One step of a beam search (γ = 0) while few nodes are live (see
    `ViterbiSearch.BEAM_DENSE_SHARE`; else the exact step and `_beam_prune`).

    In: active[:n_active], the live nodes at t−1, ascending (every other row of
    state_prev has cost inf); state_new with cost inf at every row; this sample's
    measurement as `_reading_costs_py` takes it (meas, mask (3S,), scale; readings
    (R, 3S) row by row, `beam_tables`) and as pass 2 takes the rest.

    1. The nodes the live ones reach (out_start, out_dst: `beam_tables`; only allowed
       ones) are marked in marks ((8·⌈N/8⌉,) uint8, zero, left zero; marks_words its
       uint64 view, scanned eight nodes at a time) and listed ascending in touched.
    2. Each takes its best incoming edge by the float64 rule (`_exact_choice`): the
       dense search's choice and total, bit for bit, as long as the sources the dense
       search would pick are live (always with an infinite beam).
    3. Survive: the nodes whose total is within beam of the lowest total of an
       immortal node (`_immortal`; of any node when none is reached), so a path that
       can go on always survives, whatever dead ends lie ahead of the others. Their
       new state (cost, detours, ancestor, placement) is written as pass 2 writes it,
       their arrival into this sample's lattice row (every other entry `none`), and
       they are listed ascending in survivors_out (N,).

    total (N,) float64, keep (N,) uint8, chunk_low (BEAM_CHUNKS, 2): scratch. Returns
    the number of survivors and the lowest cost (which always survives)."""
    arrivals[:] = none
    for i in range(n_active):
        m = active[i]
        for k in range(out_start[m], out_start[m + 1]):
            n = out_dst[k]
            if allowed[n]:
                marks[n] = 1
    count = 0
    for w in range(marks_words.shape[0]):  # eight marks at a time: most words are empty
        if marks_words[w]:
            for n in range(8 * w, 8 * w + 8):
                if marks[n]:
                    marks[n] = 0
                    touched[count] = n
                    count += 1
    per = (count + BEAM_CHUNKS - 1) // BEAM_CHUNKS
    for c in numba.prange(BEAM_CHUNKS):
        low, low_immortal = np.inf, np.inf
        for i in range(c * per, min(count, (c + 1) * per)):
            n = touched[i]
            a, t = _exact_choice(n, incoming, edge_src, edge_reading, edge_kind, edge_offset, edge_heading, None,
                                 readings, meas, mask, scale, w_acc, w_pos, w_head, use_pos, use_head, mx, mz, mh,
                                 placed, state_prev, det_prev)  # fmt: skip
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
                _carry_placement(state_prev, m, state_new, n, edge_offset[e, 0], edge_offset[e, 1], edge_heading[e],
                                 edge_turn[e, 0], edge_turn[e, 1])  # fmt: skip
    survivors = 0
    for i in range(count):
        if keep[i]:
            survivors_out[survivors] = touched[i]
            survivors += 1
    return survivors, low


@numba.njit(cache=True, nogil=True)
def _best_in_list(state, det, nodes, count):
    """`_best_node` without constraint sets over the live nodes nodes[:count] (every
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


_beam_step, _beam_step_serial = _compile(_beam_step_py, True), _compile(_beam_step_py, False)


def beam_tables(graph: MotionGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a beam step reads besides `search_tables`: each node's successors, out_start
    (N+1,) int64 and out_dst (E,) int32 (node m's at out_dst[out_start[m]:out_start[m+1]],
    in edge order), and the readings row by row, (R, 3S) float32 in g (the transpose of
    readings_t: a step computes C_A reading by reading; 25 MB on the 268k-node kelly6
    graph, plus 4 MB of successors).
    Made once per graph and cached on it (as `search_tables`)."""
    cached = getattr(graph, "_beam_tables", None)
    if cached is not None:
        return cached
    src = np.asarray(graph.edge_src, dtype=np.int64)
    order = np.argsort(src, kind="stable")
    out_start = incoming_offsets(src, graph.num_nodes)  # (the same offsets, by source)
    readings = np.ascontiguousarray(search_tables(graph)["readings_t"].T)
    tables = (out_start, np.ascontiguousarray(graph.edge_dst[order], dtype=np.int32), readings)
    graph._beam_tables = tables
    return tables


class ViterbiSearch:
    """Incremental search: `start(first sample)`, `step(sample)` per sample, then
    `trace(best_node())`. Used by the batch search and by streaming decoders alike.

    Samples: acc (S, 3) m/s² (NaN = missing), position (2,) m or NaN, heading rad or NaN."""

    def __init__(self, graph: MotionGraph, weights: Weights = Weights(), gamma: int = 0, allowed: np.ndarray | None = None,
                 threads: bool = True, placed: bool | None = None, window: int | None = None,
                 ring: tuple[int, int] | None = None, beam: float | None = None):  # fmt: skip
        """allowed: (N,) bool, nodes the search may use (None: all); masked nodes are
        never entered, which is how leave-one-out evaluation hides a clip. threads:
        spread each step over numba's threads (one search at a time) or not (many
        searches in parallel, e.g. a server's streams). placed: carry each path's
        ground placement (needed for position and heading costs); default: when the
        position or heading weight is non-zero. Without it, position and heading
        measurements are ignored and a step skips the placement passes. window: keep
        only the back-pointers of the last `window` samples or more, dense, and no
        survivor store — for a fixed-lag decoder, which never traces back further
        (traces must start inside the window). It saves the store's appends and sweeps
        for (window + BLOCK) × N bytes. None: the survivor store, any trace. ring:
        (BLOCK, STORE_WINDOW) instead of the class's (a warm-up makes the rarely run
        walk-back kernels run within a few samples). beam: keep only the paths whose
        cost is within this much of the best one's after each sample (see
        `_beam_step_py`), and visit only the nodes they reach — faster, but the path is
        no longer always the cheapest (None: the exact search; no constraint sets; inf:
        the exact search's results by the beam's step). Weights must be finite and ≥ 0
        (InputError); the float32 pass serves searches without constraint sets whose
        weights are at most 1e6 and whose nodes have fewer than 4,096 incoming edges,
        the float64 passes the rest, with the same results."""
        self.graph = graph
        self.threads = threads
        if not all(np.isfinite(w) and w >= 0 for w in (weights.acc, weights.position, weights.heading)):
            raise InputError(f"weights must be finite and ≥ 0, got {weights}")
        self.weights = weights
        self.placed = bool(weights.position != 0 or weights.heading != 0) if placed is None else bool(placed)
        N = graph.num_nodes
        self.N = N
        self.gamma = gamma
        tables = search_tables(graph)
        self.edge_src = tables["edge_src"]
        self.edge_kind = tables["edge_kind"]
        self.edge_offset = tables["edge_offset"]
        self.edge_heading = tables["edge_heading"]
        self.edge_turn = tables["edge_turn"]
        self.readings_t = tables["readings_t"]
        self.edge_reading = tables["edge_reading"]
        c = graph.node_contacts
        self.contact_code = (c[:, 0].astype(np.int64) | (c[:, 1].astype(np.int64) << 1))
        self.label = np.ascontiguousarray(graph.node_label, dtype=np.int64)
        P = N if self.placed else 1  # unplaced searches pass a dummy row to the kernels
        width = PLACED_WIDTH if self.placed else UNPLACED_WIDTH
        self.state, self._state_new = np.zeros((N, width)), np.zeros((N, width))  # (see COST…SIN)
        self.det, self._det_new = np.zeros(N, dtype=np.int32), np.zeros(N, dtype=np.int32)  # detour counts
        self.rank, self._rank_new = np.zeros((N, gamma), dtype=np.int32), np.zeros((N, gamma), dtype=np.int32)
        self.rel = np.zeros((P, 4), dtype=np.float32)
        # The float32 pass and float64 fix-ups (see `_approx_select_py`) for searches
        # without constraint sets; constrained ones keep the float64 passes (rank first).
        # bits for an arrival index < max in-degree, and all ones (which none is) marking a near-tie
        label_bits = max(int(np.diff(tables["incoming"]).max(initial=0)), 1).bit_length()
        # (weights ≤ 1e6 keep every live float32 total far from overflow)
        heaviest = max(weights.acc, weights.position, weights.heading)
        self.float32_pass = gamma == 0 and label_bits <= 12 and heaviest <= 1e6
        self.near_ties = 0  # nodes whose choice the float64 rule settled (a check on the bound's width)
        if self.float32_pass:
            self._keep = np.uint32(0xFFFFFFFF ^ ((1 << label_bits) - 1))
            self._label_mask = np.uint32((1 << label_bits) - 1)
            self._alpha = 2.0**-20 + 2.0 ** (label_bits - 22)
            self._best32, self._second32 = np.empty(N, np.float32), np.empty(N, np.float32)
            self._best_bits = self._best32.view(np.uint32)  # pass 2 reads the labels through it
            pass1 = float32_tables(graph)
            self.node_pos = tables["node_pos"]
            self._pass1 = tuple(pass1[k] for k in (
                "chunk_nodes", "shared_slots", "shared_src", "shared_arrival", "shared_offset", "shared_heading",
                "own_bounds", "own_src", "own_reading", "own_pos", "own_arrival", "own_offset", "own_heading"))
            # unsigned views of the index tables pass 2 reads (see `_approx_select_py`)
            self._unsigned = {
                "incoming": tables["incoming"].view(np.uint32), "edge_src": tables["edge_src"].view(np.uint32),
                "edge_reading": tables["edge_reading"].view(np.uint32),
            }  # fmt: skip
            self._chunk_nodes = pass1["chunk_nodes"]
            self._chunk_low = np.empty(len(self._chunk_nodes) - 1)
            self._chunk_high = np.empty_like(self._chunk_low)
            self.c32 = np.zeros(N if not self.placed else 1, dtype=np.float32)
            self._c32_new = np.zeros_like(self.c32)
        else:
            self.slots = tuple(slot_tables(graph)[k] for k in (
                "chunk_nodes", "chunk_slots", "slot_dst", "slot_src", "slot_kind", "slot_edge", "slot_reading",
                "slot_offset", "slot_heading"))
            self.total = np.full(graph.num_edges + 1, np.inf)  # slot order; total[E] = inf (no candidate)
            self.best_slot = np.full(N, graph.num_edges, dtype=np.int64)
        self.low = 0.0  # lowest live cost (the float32 costs' base)
        self._chunks_t = -1  # the sample the chunks' lowest and highest costs describe (−1: none)
        self.c32_base = 0.0  # what c32 is relative to
        self.reading_cost = np.zeros(self.readings_t.shape[1], dtype=np.float32)
        self._meas = np.zeros(self.readings_t.shape[0], dtype=np.float32)
        self._mask = np.ones(self.readings_t.shape[0], dtype=np.float32)
        self._scale = np.float32(1.0)  # (see `_set_measurement`)
        self.ok = np.ones((gamma, N), dtype=bool)
        if allowed is None:
            self.allowed = np.ones(N, dtype=bool)
        else:
            self.allowed = np.ascontiguousarray(allowed, dtype=bool)
            if self.allowed.shape != (N,):
                raise InputError(f"node mask must have {N} entries, got {self.allowed.shape}")
            if not self.allowed.any():
                raise InputError("the node mask leaves no node to search")
        if self.float32_pass:
            self._allowed_pos = np.empty(N, dtype=bool)  # in the float32 pass's layout order
            self._allowed_pos[self.node_pos] = self.allowed
        self.beam = None if beam is None else float(beam)
        if self.beam is not None:
            if not self.beam > 0:
                raise InputError(f"the beam must be a cost > 0 (or inf), got {beam}")
            if gamma:
                raise InputError("a beam search takes no constraint sets (their counts rank before the cost)")
            self._out_start, self._out_dst, self._readings = beam_tables(graph)
            self._immortal = _immortal(tables["incoming"], self.edge_src, self.allowed)
            self._marks = np.zeros(8 * ((N + 7) // 8), dtype=np.uint8)
            self._marks_words = self._marks.view(np.uint64)
            # live nodes ascending: at the newest sample (state's), at the one before
            # (_state_new's, whose costs a step resets to inf before writing)
            self._live, self._live_before = np.empty(N, dtype=np.int32), np.empty(N, dtype=np.int32)
            self._n_live = self._n_live_before = 0
            self._touched, self._total = np.empty(N, dtype=np.int32), np.empty(N)
            self._survives = np.empty(N, dtype=np.uint8)
            self._beam_low = np.empty((BEAM_CHUNKS, 2))
            self._no_c32 = np.zeros(0, dtype=np.float32)
            self._step_seconds = (None, None)  # sparse steps' seconds a live node, dense steps' (see `narrow`)
        self._c32_stale = False  # (see `_rebase_c32`)
        self.converged_t = -1  # every sample ≤ this one has a single surviving entry (or was forgotten)
        self.keep_from = 0  # samples before this one are forgotten (see forget_before)
        # The lattice of the newest samples, dense: one row per sample, each node's
        # arrival (which of its incoming edges its best path came by; 1 byte a node
        # while no node has 255 incoming edges), written sequentially each step, in a
        # ring of rows. In store mode (K §5.1's periodic trace-back from all live
        # nodes), when the ring is full the walk back from the live nodes moves the
        # surviving points of its oldest BLOCK rows into the survivor store; they are
        # then STORE_WINDOW samples old, by when most paths have merged (on built
        # graphs, whose clips run as long single-predecessor chains, a third of the
        # nodes still had distinct paths 32 samples back, 8 % at 128). In window mode
        # the oldest rows are dropped instead.
        self.incoming = tables["incoming"]
        most = int(np.diff(self.incoming).max(initial=0))
        dtype = next(d for d in (np.uint8, np.uint16, np.uint32) if most < np.iinfo(d).max)
        self.none = int(np.iinfo(dtype).max)  # arrival of a dead node
        if ring is not None:
            self.BLOCK, self.STORE_WINDOW = max(int(ring[0]), 1), max(int(ring[1]), 0)
        self.window = None if window is None else max(int(window), 1)
        rows = self.BLOCK + (self.STORE_WINDOW if window is None else self.window)
        self.arrivals = np.full((rows, N), self.none, dtype=dtype)
        self._best_edge = np.full(N, -1, dtype=np.int32)
        self.first = 0  # physical row of the oldest filled row
        self.used = 0  # rows filled
        self.alive_map = np.zeros(8 * ((N + 7) // 8), dtype=np.uint8)
        small = window is not None  # window mode never appends to the store
        self.row_of = np.zeros(1 if small else N, dtype=np.int64)
        self.level_nodes = np.zeros(16 if small else N + 16, dtype=np.int32)
        self.level_start = np.zeros(self.BLOCK + 1, dtype=np.int64)
        self.store = np.zeros((N + 16 if small else 2 * N + 16, 4), dtype=np.int32)  # 16 bytes a row; doubles when full
        self.size = 0  # rows of the store in use (live or garbage)
        self.live_rows = 0  # rows alive after the last collection
        self.heads = np.full(N, -1, dtype=np.int64)
        # Store mode, while paths stay apart (see ANCESTOR_SHARE): each live path's node
        # at sample ancestor_t (one gather a node a step), so a flush walks back from
        # there instead of through the newest rows (on the built kelly6 graph that walk
        # was a quarter of a step's time: 80k of 268k nodes on distinct paths 32
        # samples back).
        self._identity = np.arange(0 if small else N, dtype=np.int32)
        self.ancestor, self._ancestor_new = self._identity.copy(), self._identity.copy()
        self._no_ancestors = np.zeros(0, dtype=np.int32)  # the kernels' "not carried"
        self.carry_ancestors = False  # decided at each flush
        self.ancestor_t = -1  # −1: not carried since the last flush
        self.t = -1
        self.peak_entries = 0
        self.peak_bytes = 0

    # Rows moved into the store (or dropped) at a time, and rows kept dense beyond them:
    # each walk back through the ring is shared by BLOCK samples. On the built Bandai
    # dataset-2 graph (268k nodes) 128 + 128 took 4.6 ms a sample in steady state,
    # 64 + 128 5.2 ms, and 32 + 0 (the store taking every row at once) 8.3 ms. A batch
    # search, which has no latency to keep low, takes BATCH_RING_SCALE times both: fewer,
    # longer walks, over paths that have merged more (built kelly6 graph, 2,880 samples:
    # mode A 2.28 against 2.47–2.54 ms a sample, APO 5.80 against 6.01; 512 + 256 rows
    # 2.21 and 5.62, for 1.5 times the memory; G_E unchanged), unless its input is too
    # short to fill a block (`batch_ring`).
    BLOCK = 128
    STORE_WINDOW = 128
    BATCH_RING_SCALE = 2
    # Carry ancestors (see __init__) while more than this share of the nodes are distinct
    # paths' nodes at the newest row a flush lists: then the walk through the newer rows
    # costs more than a gather a node a step (built kelly6 graph: 7.5 %, where carrying
    # took a flush from 0.83 to 0.28 ms a sample; generated G_E: under 0.05 %, where
    # carrying cost 4 % of a step and saved nothing).
    ANCESTOR_SHARE = 0.01
    # A beam search steps sparsely (`_beam_step_py`: only the nodes its live paths reach,
    # C_A only for the edges read) while at most BEAM_DENSE_SHARE of the nodes are live,
    # by the exact search's passes and then a cut (`_beam_prune`) while more than
    # BEAM_SPARSE_SHARE are, and in between by whichever its past steps predict to be
    # faster (`narrow`). The same survivors and states either way, but which is faster
    # depends on the graph: with a fifth of the nodes live, sparse steps took 4 times an
    # exact step on the generated G_E (random transitions, three incoming edges a node)
    # and were the faster on the built kelly6 graph (evaluation with beam 10: 418–449
    # samples/s switching at a quarter, 288–307 at 5 %, 291–330 always sparse); with
    # every node live they took 3 times an exact step on G_E.
    BEAM_DENSE_SHARE = 0.05
    BEAM_SPARSE_SHARE = 0.5

    @property
    def threads(self) -> bool:
        """Whether steps spread over numba's threads (see __init__). May change between
        steps — a server gives them to a stream while it is the only one running —
        without changing any result: both kinds of kernel compute the same values."""
        return self._kernels is _THREADED

    @threads.setter
    def threads(self, on: bool) -> None:
        self._kernels = _THREADED if on else _SERIAL

    @property
    def cost(self) -> np.ndarray:
        """(N,) float64 each node's best path's cost (inf: none alive), a view."""
        return self.state[:, COST]

    @property
    def place(self) -> np.ndarray | None:
        """(N, 5) float64 each node's best path's placement (x, z m, heading rad, its
        cos, sin), a view; None when the search is not placed."""
        return self.state[:, X:SIN + 1] if self.placed else None

    @property
    def live_entries(self) -> int:
        """Store rows in use (survivors plus garbage not yet collected)."""
        return self.size

    def start(self, position=None, heading=None, kinds_t=None, values_t=None):
        """Sample 0: every node starts a path at the measured position / heading; one
        not measured yet is taken from the first sample that has it (see `_anchor`)."""
        self.t = 0
        self.anchor_position = None  # every path's start, once measured: (2,) m
        self.anchor_heading = None  # rad
        if self.placed:
            self.state[:, X] = self.state[:, Z] = self.state[:, HEADING] = self.state[:, SIN] = 0.0
            self.state[:, COS] = 1.0
        self._anchor(position, heading)
        self.state[:, COST] = np.where(self.allowed, 0.0, np.inf)
        self.det[:] = 0
        if self.beam is not None:
            live = np.flatnonzero(self.allowed)
            self._live[: len(live)], self._n_live, self._n_live_before = live, len(live), 0
            self._state_new[:, COST] = np.inf
        self._c32_stale = False
        self.low = self.c32_base = 0.0
        self._chunks_t = -1
        if self.float32_pass and not self.placed:
            self.c32[:] = np.where(self.allowed, np.float32(0.0), DEAD32)
        if self.gamma:
            _satisfied(kinds_t, values_t, self.contact_code, self.label, self.ok)
            self.rank[:] = (~self.ok).T
        live = np.nonzero(self.allowed)[0]
        self.size = len(live)
        self.store[: self.size, NODE] = live
        self.store[: self.size, EDGE] = -1
        self.store[: self.size, PARENT] = -1
        self.store[: self.size, TIME] = 0
        self.heads[:] = -1
        self.heads[live] = np.arange(self.size)
        self.live_rows = self.size
        self.first = self.used = 0
        self.carry_ancestors, self.ancestor_t = False, -1
        self.converged_t = 0 if len(live) == 1 else -1
        self.peak_entries = self.size
        self.peak_bytes = self.lattice_bytes

    def _anchor(self, position, heading) -> None:
        """Until a position (a heading) has been measured, paths run from the origin
        (facing +Z) and no position (heading) term has counted, so the first one
        measured can become every path's start: all placements are turned about the
        start by the heading and moved onto the position, rigidly — the same as if the
        search had started there (as a batch search given them at sample 0 does)."""
        place = self.state if self.placed else np.zeros((1, PLACED_WIDTH))  # (unplaced: only noted)
        if self.anchor_heading is None and heading is not None and np.isfinite(heading):
            self.anchor_heading = h = float(heading)
            ax, az = (0.0, 0.0) if self.anchor_position is None else self.anchor_position
            c, s = np.cos(h), np.sin(h)
            dx, dz = place[:, X] - ax, place[:, Z] - az
            place[:, X], place[:, Z] = ax + c * dx + s * dz, az - s * dx + c * dz
            cos, sin = place[:, COS].copy(), place[:, SIN].copy()
            place[:, HEADING] += h
            place[:, COS], place[:, SIN] = cos * c - sin * s, sin * c + cos * s
        if self.anchor_position is None and position is not None and np.all(np.isfinite(position)):
            self.anchor_position = p = (float(position[0]), float(position[1]))
            place[:, X] += p[0]
            place[:, Z] += p[1]

    @property
    def start_placement(self) -> tuple[np.ndarray, float]:
        """Where every path starts: ground position (2,) m and heading rad (the origin and
        +Z for what has not been measured yet)."""
        p = np.zeros(2) if self.anchor_position is None else np.asarray(self.anchor_position, dtype=np.float64)
        return p, 0.0 if self.anchor_heading is None else self.anchor_heading

    def step(self, acc, position=None, heading=None, kinds_t=None, values_t=None, reading_cost=None):
        """Advance by one sample. reading_cost: this sample's row of `reading_costs`,
        when a batch caller computed it ahead (else it is computed here)."""
        if (self.anchor_position is None and position is not None) or (self.anchor_heading is None and
                                                                           heading is not None):
            self._anchor(position, heading)
        if self.used == self.arrivals.shape[0]:
            self._flush() if self.window is None else self._slide()
        self.t += 1
        arrivals = self.arrivals[(self.first + self.used) % self.arrivals.shape[0]]
        if self.gamma:
            _satisfied(kinds_t, values_t, self.contact_code, self.label, self.ok)
        w = self.weights
        wa, wp, wh = float(w.acc), float(w.position), float(w.heading)
        use_pos = self.placed and wp != 0.0 and position is not None and bool(np.all(np.isfinite(position)))
        use_head = self.placed and wh != 0.0 and heading is not None and bool(np.isfinite(heading))
        reading_costs, relative, edge_totals, select, advance, approx_select, finish = self._kernels
        narrow = self.narrow
        if self.beam is not None:
            started, live_before = time.perf_counter(), self._n_live
        if narrow:
            self._set_measurement(acc)  # (a narrow beam step computes the C_A it reads from it)
        elif reading_cost is None:
            # Computed even at W_A = 0: the report carries each path's accelerometer cost.
            self._set_measurement(acc)
            if self._scale:
                reading_costs(self.readings_t, self._meas, self._mask, self._scale, self.reading_cost)
            else:
                self.reading_cost[:] = 0.0
            reading_cost = self.reading_cost
        # Placed searches read their sources' relative rows (which hold the float32 cost)
        # every sample, whether or not this sample's position or heading counts.
        rows = self.placed and (self.float32_pass or use_pos or use_head)
        meas_pos = np.asarray(position, dtype=np.float64) if use_pos else np.zeros(2)
        meas_heading = float(heading) if use_head else 0.0
        ancestors = ((self.ancestor, self._ancestor_new) if self.carry_ancestors else
                     (self._no_ancestors, self._no_ancestors))  # fmt: skip
        if rows and not narrow:
            relative(self.state, meas_pos, meas_heading, self.low, self.rel)
        if narrow:
            live = self._beam_step(wa, wp, wh, use_pos, use_head, meas_pos, meas_heading, arrivals, ancestors)
        elif self.float32_pass:
            if self._c32_stale and not self.placed:  # (narrow beam steps leave the unplaced float32 costs behind)
                self._rebase_c32()
            u = self._unsigned
            base = self.low if rows else self.c32_base  # what the float32 costs read are relative to
            approx_select(*self._pass1, reading_cost, np.float32(wa), np.float32(wp if use_pos else 0.0),
                          np.float32(wh if use_head else 0.0), rows, self.c32, self.rel, self._keep, self._allowed_pos,
                          self._alpha, 2.0**-48 * base + 1e-30, self._best32, self._second32)  # fmt: skip
            # (unplaced: the cost column alone, 1-D — see `_cost_at`)
            state, state_new = (self.state, self._state_new) if self.placed else (self.cost, self._state_new[:, COST])
            live, near_ties = finish[self.placed](
                self._chunk_nodes, self.node_pos, self._best32, self._best_bits, self._label_mask, u["incoming"],
                u["edge_src"], u["edge_reading"], self.edge_kind, self.edge_offset, self.edge_heading,
                self.edge_turn, reading_cost, wa, wp, wh, use_pos, use_head, meas_pos[0], meas_pos[1], meas_heading,
                state, self.det, self.low, state_new, self._det_new, self._c32_new, arrivals, self.none,
                self._chunk_low, self._chunk_high, *ancestors)  # fmt: skip
            self.near_ties += near_ties
            if live:
                self.c32_base, self.low = self.low, float(self._chunk_low.min())
                self._chunks_t = self.t
                self.c32, self._c32_new = self._c32_new, self.c32
        else:
            chunk_nodes, chunk_slots, slot_dst, slot_src, slot_kind, slot_edge, slot_reading, slot_offset, \
                slot_heading = self.slots
            edge_totals(slot_src, slot_reading, slot_offset, slot_heading, reading_cost, wa, wp, wh, use_pos, use_head,
                        self.state, self.rel, self.total)  # fmt: skip
            select(chunk_nodes, chunk_slots, slot_dst, slot_src, slot_kind, slot_edge, self.total, self.allowed,
                   self.det, self.rank, self.best_slot, self._state_new, self._best_edge)  # fmt: skip
            live = advance(self._best_edge, self.incoming, self.edge_src, self.edge_kind, self.edge_offset,
                           self.edge_heading, self.edge_turn, self.ok, self.placed, self.state, self.det, self.rank,
                           self._state_new, self._det_new, self._rank_new, arrivals, self.none,
                           *ancestors)  # fmt: skip
        if self.beam is not None:
            if not narrow and live:
                live = self._cut(arrivals)
            self._time_beam_step(narrow, time.perf_counter() - started, live_before)
        if live == 0:
            raise InputError(f"no graph path reaches sample {self.t}: every path ran into a dead end")
        self.used += 1
        if self.carry_ancestors:
            self.ancestor, self._ancestor_new = self._ancestor_new, self.ancestor
        if self.used == self.BLOCK:  # the newest row is the next flush's newest listed one
            self._restart_ancestors()
        self.peak_bytes = max(self.peak_bytes, self.lattice_bytes)
        # Swap buffers: the new state becomes the previous one.
        self.state, self._state_new = self._state_new, self.state
        self.det, self._det_new = self._det_new, self.det
        self.rank, self._rank_new = self._rank_new, self.rank

    @property
    def narrow(self) -> bool:
        """Whether the next step is a beam search's sparse one: always while few nodes are
        live, never while most are, else whichever this search's steps so far predict to
        be faster (sparse steps cost about the same per live node; the results are the
        same either way, so timing only chooses the work)."""
        if self.beam is None:
            return False
        if self._n_live <= self.BEAM_DENSE_SHARE * self.N:
            return True
        if self._n_live > self.BEAM_SPARSE_SHARE * self.N:
            return False
        per_node, dense = self._step_seconds
        if per_node is None or dense is None:
            return dense is not None  # (each kind tried once before comparing)
        return per_node * self._n_live < dense

    def _time_beam_step(self, narrow: bool, seconds: float, live_before: int) -> None:
        """Fold a beam step's time into `narrow`'s estimates (running means, recent steps
        weighted most): seconds a live node for sparse steps, a step for dense ones."""
        per_node, dense = self._step_seconds
        if narrow:
            x = seconds / max(live_before, 1)
            per_node = x if per_node is None else 0.75 * per_node + 0.25 * x
        else:
            dense = seconds if dense is None else 0.75 * dense + 0.25 * seconds
        self._step_seconds = (per_node, dense)

    def _beam_step(self, wa, wp, wh, use_pos, use_head, meas_pos, meas_heading, arrivals, ancestors) -> int:
        """`step`'s passes for a beam search while few nodes are live (`_beam_step_py`);
        returns the survivors."""
        _reset_costs(self._state_new, self._live_before, self._n_live_before)
        kernel = _beam_step if self.threads else _beam_step_serial
        live, low = kernel(self._live, self._n_live, self._out_start, self._out_dst, self.allowed, self._immortal,
                           self._marks, self._marks_words, self._touched, self._total, self._survives,
                           self._live_before, self.incoming, self.edge_src, self.edge_reading, self.edge_kind,
                           self.edge_offset, self.edge_heading, self.edge_turn, self._readings, self._meas, self._mask,
                           self._scale, wa, wp, wh, use_pos, use_head, meas_pos[0], meas_pos[1],
                           meas_heading, self.placed, self.beam, self.state, self.det, self._state_new,
                           self._det_new, arrivals, self.none, *ancestors, self._beam_low)  # fmt: skip
        self._live, self._live_before = self._live_before, self._live
        self._n_live, self._n_live_before = live, self._n_live
        if live:
            self.low = low
        self._c32_stale = True
        return live

    def _cut(self, arrivals) -> int:
        """A beam search's cut after an exact step (`_beam_prune`); returns the survivors."""
        c32 = self.c32 if self.float32_pass else self._no_c32  # (swapped in by the step already)
        none = arrivals.dtype.type(self.none)  # (the arrivals' own type, for a select)
        live, low = _beam_prune(self._state_new, self._immortal, self.beam, arrivals, none, c32, self._live_before)
        self._live, self._live_before = self._live_before, self._live
        self._n_live, self._n_live_before = live, self._n_live
        self.low = low
        return live

    def _rebase_c32(self) -> None:
        """The unplaced float32 pass's costs from the cost column, relative to the
        lowest live cost (any base at most every live cost keeps the pass's bound)."""
        cost = self.cost
        live = np.isfinite(cost)
        self.c32[:] = DEAD32
        self.c32[live] = (cost[live] - self.low).astype(np.float32)
        self.c32_base = self.low
        self._c32_stale = False

    @staticmethod
    def measurements(acc) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Accelerations (B, S, 3) m/s² → the kernels' measurement vectors (B, 3S)
        float32 in g, masks (B, 3S) float32 and the sensors present (B,): a sensor with
        any NaN axis is left out (K eq. 4 averages over sensors present)."""
        a = np.asarray(acc, dtype=np.float32)
        a = a.reshape(len(a), -1, 3)
        valid = np.isfinite(a).all(axis=-1)
        # float32(m/s²) / g in float64, rounded once — exactly as the readings table.
        g = (a.astype(np.float64) / GRAVITY).astype(np.float32)
        meas = np.where(valid[..., None], g, np.float32(0.0)).reshape(len(a), -1)
        mask = np.repeat(valid, 3, axis=1).astype(np.float32)
        return meas, mask, mask.sum(axis=1) / 3.0

    def reading_costs(self, acc, measured=None) -> np.ndarray:
        """C_A (B, R) float32 in g² of every distinct edge reading for B samples of
        accelerations (B, S, 3) m/s² at once (see `_reading_costs_batch_py`);
        measured: their `measurements`, when the caller has them already."""
        meas, mask, present = self.measurements(acc) if measured is None else measured
        B = len(meas)
        scale = np.where(present > 0, 1.0 / np.maximum(present, 1.0), 0.0).astype(np.float32)
        out = np.empty((B, self.readings_t.shape[1]), np.float32)
        kernel = _reading_costs_batch if self.threads else _reading_costs_batch_serial
        kernel(self.readings_t, meas, mask, scale, out)
        return out

    def _set_measurement(self, acc) -> None:
        """One sample's accelerations (S, 3) m/s² → self._meas, self._mask (see
        `measurements`) and self._scale, float32 1 / sensors present (0: none)."""
        meas, mask, present = self.measurements(np.asarray(acc)[None])
        self._meas[:], self._mask[:] = meas[0], mask[0]
        self._scale = np.float32(1.0 / float(present[0])) if present[0] else np.float32(0.0)

    @property
    def lattice_bytes(self) -> int:
        """Memory held for the trace-back now: the dense rows filled and the store's rows
        in use (survivors and garbage not yet collected)."""
        return self.used * self.arrivals.shape[1] * self.arrivals.itemsize + self.size * self.store.itemsize * 4

    @property
    def compression(self) -> float:
        """K §5.1's memory reduction: the full back-pointer lattice (N·T points of 4
        bytes) over the peak memory the search held for it (`lattice_bytes`)."""
        return self.N * (self.t + 1) * 4 / max(self.peak_bytes, 1)

    def _flush(self) -> None:
        """Store mode, ring full: walk back from the live nodes through every dense row
        and move the surviving points of the oldest BLOCK rows into the store (collect
        the store's garbage first when it has doubled); those rows are then free. With
        ancestors carried, the walk starts at the row of ancestor_t, from the live
        paths' nodes there; else at the newest row."""
        t_first = self.t - self.used + 1  # the sample of the oldest row
        if self.ancestor_t >= 0:
            walk, ancestor = self.ancestor_t - t_first + 1, self.ancestor  # rows walked through: to ancestor_t's
            assert self.BLOCK <= walk <= self.used, (walk, self.BLOCK, self.used)
        else:
            walk, ancestor = self.used, self._identity
        while True:  # grown on demand: the worst case (nothing merges) is used × N
            total, converged_row = _block_levels(self.arrivals, self.first, walk, self.BLOCK, self.incoming,
                                                 self.edge_src, self.alive_map, self.level_nodes, self.level_start,
                                                 ancestor, self.state)  # fmt: skip
            if total >= 0:
                break
            self.level_nodes = np.zeros(2 * self.level_nodes.shape[0], dtype=np.int32)
        flush = self.BLOCK
        appended = int(self.level_start[flush])
        if self.size + appended > self.store.shape[0]:
            self._collect()
            if self.size + appended > self.store.shape[0] // 2:
                # np.empty: rows past `size` are always written before they are read
                bigger = np.empty((2 * (self.size + appended), 4), dtype=np.int32)
                bigger[: self.size] = self.store[: self.size]
                self.store = bigger
        self.size = _append_block(self.arrivals, self.first, flush, t_first, self.incoming, self.edge_src, self.heads,
                                  self.store, self.size, self.level_nodes, self.level_start, self.row_of)  # fmt: skip
        self.peak_entries = max(self.peak_entries, self.live_rows + appended)
        self.peak_bytes = max(self.peak_bytes, self.lattice_bytes)
        self.first = (self.first + flush) % self.arrivals.shape[0]
        self.used -= flush
        apart = self.level_start[flush] - self.level_start[flush - 1]  # distinct nodes at the newest listed row
        self.carry_ancestors = bool(apart > self.ANCESTOR_SHARE * self.N)
        self.ancestor_t = -1
        if self.used >= self.BLOCK:  # (else when the row BLOCK − 1 is written)
            self._restart_ancestors()
        if converged_row >= 0:  # one node left at that row: everything up to it is agreed
            self.converged_t = max(self.converged_t, t_first + converged_row)

    def _restart_ancestors(self) -> None:
        """When carrying them: from now on, ancestor[n] is node n's path's node at this
        sample."""
        if self.carry_ancestors:
            self.ancestor[:] = self._identity
            self.ancestor_t = self.t

    def _slide(self) -> None:
        """Dense-window mode, ring full: note whether the live paths have come to agree
        on a sample not yet forgotten (the converged-prefix commit), then drop the
        oldest BLOCK rows."""
        t_first = self.t - self.used + 1  # the sample of the oldest row
        lowest = max(0, self.keep_from - t_first, self.converged_t + 1 - t_first)
        if lowest < self.used:
            row = _converged_row(self.arrivals, self.first, self.used, lowest, self.incoming, self.edge_src, self.none,
                                 self.alive_map)  # fmt: skip
            if row >= 0:
                self.converged_t = max(self.converged_t, t_first + row)
        self.first = (self.first + self.BLOCK) % self.arrivals.shape[0]
        self.used -= self.BLOCK

    def forget_before(self, t: int) -> None:
        """Let the next garbage collection drop survivors of samples before t: a
        streaming decoder that has emitted them never traces back past them, and on
        graphs whose paths rarely merge they are over a third of the store. Traces must
        then start at t or later; such samples count as agreed (converged_t)."""
        self.keep_from = max(self.keep_from, min(int(t), self.t))

    def _collect(self) -> None:
        self.size = _collect(self.store, self.size, self.heads, self.keep_from)
        self.live_rows = self.size
        self.peak_entries = max(self.peak_entries, self.size)
        if self.converged_t < self.t:
            t_from = max(self.converged_t + 1, self.keep_from)
            self.converged_t = max(self.converged_t, _converged_until(self.store, self.size, t_from, self.t))

    @property
    def alive(self) -> np.ndarray:
        return np.isfinite(self.cost)

    def best_node(self) -> int:
        """The live node whose path ranks first: fewest broken constraints, then cost
        (within TIE counts as equal), then fewer non-original edges, then lower node id."""
        if self.beam is not None:
            return int(_best_in_list(self.state, self.det, self._live, self._n_live))
        if self._chunks_t == self.t:  # (the float32 pass's steps: γ = 0)
            return int(_best_in_chunks(self.state, self.det, self._chunk_nodes, self._chunk_low, self._chunk_high))
        return int(_best_node(self.state, self.rank, self.det))

    def trace_arrivals(self, node: int, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (t+1−since,) at samples since..t of the path ending at `node` now and
        the edge each was entered by (−1 at sample 0). Walks back only to `since`, so
        a fixed-lag trace costs the lag, not the input length."""
        earliest = self.keep_from
        if self.window is not None and self.used < self.t:  # the window has slid past sample 0
            earliest = max(earliest, self.t - self.used + 1)
        if not earliest <= since <= self.t:
            raise InputError(f"cannot trace from sample {since}: the search is at sample {self.t}"
                             f" and has forgotten samples before {earliest}")  # fmt: skip
        return _trace(self.arrivals, self.first, self.used, self.t, self.heads, self.incoming, self.edge_src, self.store,
                      int(node), int(since))  # fmt: skip

    def trace(self, node: int, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (t+1−since,) at samples since..t of the path ending at `node` now,
        and the edges (t−since,) between them."""
        nodes, edges = self.trace_arrivals(node, since)
        return nodes, edges[1:]


def path_terms(search: ViterbiSearch, nodes: np.ndarray, edges: np.ndarray, acc, position=None, heading=None,
               measured=None) -> dict:  # fmt: skip
    """The accelerometer (g²), position (m) and heading (rad) costs accumulated along a
    path found by `search` (unweighted; a term counts where the search used it).
    measured: `search.measurements(acc)`, when the caller has it already."""
    T = nodes.shape[0]
    meas, mask, present = search.measurements(acc[:T]) if measured is None else measured
    pos = np.full((T, 2), np.nan) if position is None else np.asarray(position, dtype=np.float64)
    head = np.full(T, np.nan) if heading is None else np.asarray(heading, dtype=np.float64)
    p0, h0 = search.start_placement
    w = search.weights
    out = _path_terms(edges.astype(np.int64), search.readings_t, search.edge_reading, search.edge_offset,
                      search.edge_heading, search.edge_turn, meas, mask, present, pos, head, w.position != 0,
                      w.heading != 0, float(p0[0]), float(p0[1]), h0, np.cos(h0), np.sin(h0))  # fmt: skip
    return {"acc_g2": float(out[0]), "position_m": float(out[1]), "heading_rad": float(out[2])}


def needs_placement(weights: Weights, position=None, heading=None) -> bool:
    """Whether some sample's position (T, 2) or heading (T,) term will count, so the
    search must carry each path's placement (see ViterbiSearch's `placed`)."""
    pos = position is not None and weights.position != 0 and bool(np.isfinite(position).all(axis=-1).any())
    head = heading is not None and weights.heading != 0 and bool(np.isfinite(heading).any())
    return pos or head


def warm_up_search(graph: MotionGraph, threads: bool = True) -> None:
    """Run a few random samples through searches with a tiny ring, in store and in
    window mode, placed and not, with a constraint set (the float64 passes) and with a
    narrow beam (one exact step and cut, then sparse steps), then through batch
    searches: numba compiles (or loads from its cache) the step kernels,
    the walk back through the dense rows, the batch C_A and the path's terms for this
    graph's array types now, not when a search first fills its ring (every BLOCK
    samples) or first meets constraints."""
    rng = np.random.default_rng(0)
    T = 16
    acc = rng.normal(0.0, 9.81, (T, len(graph.sensor_names), 3))
    position = np.cumsum(rng.normal(0.0, 0.02, (T, 2)), axis=0)
    free = np.zeros(1, np.int64)
    placed, unplaced = Weights(0.5, 1, 1), Weights(1, 0, 0)
    for window, gamma, weights, beam in ((None, 0, placed, None), (2, 0, placed, None), (None, 0, unplaced, None),
                                         (None, 1, placed, None), (2, 0, placed, 1e-6)):  # fmt: skip
        search = ViterbiSearch(graph, weights, gamma, threads=threads, window=window, ring=(4, 2), beam=beam)
        search.start(position[0], 0.0, free[:gamma], free[:gamma])
        for t in range(1, T):
            search.step(acc[t], position[t], 0.0, free[:gamma], free[:gamma])
        search.trace(search.best_node(), since=search.t - 1)
    for weights, pos, head in ((placed, position, np.zeros(T)), (unplaced, None, None)):  # batch C_A, path terms
        viterbi_search(graph, acc, pos, head, weights, threads=threads)
    graph._search_warmed = getattr(graph, "_search_warmed", frozenset()) | {bool(threads)}  # (as the table caches)


def warm_up_search_once(graph: MotionGraph, threads: bool = True) -> float:
    """`warm_up_search` unless it has run for this graph and thread mode in this
    process (a server warms up at load). Returns the seconds it took, 0.0 if it had run."""
    if bool(threads) in getattr(graph, "_search_warmed", ()):
        return 0.0
    t0 = time.perf_counter()
    warm_up_search(graph, threads)
    return time.perf_counter() - t0


# A batch search computes C_A for this many samples in one pass over the readings
# table (bound by memory traffic when done one sample at a time).
READING_BATCH = 16


def batch_ring(samples: int) -> tuple[int, int]:
    """The lattice ring (BLOCK, STORE_WINDOW) of a batch search of this many samples:
    BATCH_RING_SCALE times a stream's, or, when the input is too short to fill a block
    (so that ring would never flush), one row a sample and no more. The ring is filled
    when made (N bytes a row): on the 268k-node built graph the full one took 114 ms to
    make against 13 for 170 rows, and a 170-sample search ran 4–5 % faster. Either way
    no flush and no ancestor restart happen, so the search is the same."""
    scale = ViterbiSearch.BATCH_RING_SCALE
    block, window = scale * ViterbiSearch.BLOCK, scale * ViterbiSearch.STORE_WINDOW
    return (block, window) if samples > block else (max(int(samples), 1), 0)


def viterbi_search(graph: MotionGraph, acc: np.ndarray, position=None, heading=None, weights: Weights = Weights(),
                   constraint_sets: list | None = None, rate_hz: float | None = None,
                   allowed: np.ndarray | None = None, threads: bool = True, should_stop=None,
                   beam: float | None = None) -> SearchResult:  # fmt: skip
    """Batch search. acc: (T, S, 3) m/s² in the graph's layout (NaN = missing);
    position: (T, 2) m or None; heading: (T,) rad or None; constraint_sets: see
    `compile_constraints` (times from sample index / graph rate); allowed: (N,) bool
    node mask or None; threads: see ViterbiSearch; should_stop: a callable polled
    every READING_BATCH (16) samples — when it returns true the search raises SearchCancelled (a
    server stops work for a client that went away); beam: see ViterbiSearch."""
    acc = np.asarray(acc)
    T = acc.shape[0]
    if T == 0:
        raise InputError("the input has no samples")
    if acc.ndim != 3 or acc.shape[1:] != (len(graph.sensor_names), 3):
        raise InputError(f"accelerations must be (samples, {len(graph.sensor_names)}, 3) for the graph's layout, got {acc.shape}")
    constraint_sets = constraint_sets or []
    gamma = len(constraint_sets)
    times = np.arange(T) / (rate_hz or graph.rate_hz)
    kinds, values = compile_constraints(graph, constraint_sets, times)
    search = ViterbiSearch(graph, weights, gamma, allowed, threads, needs_placement(weights, position, heading),
                           ring=batch_ring(T), beam=beam)  # fmt: skip
    pos = (lambda t: None) if position is None else (lambda t: position[t])
    head = (lambda t: None) if heading is None else (lambda t: heading[t])
    search.start(pos(0), head(0), kinds[:, 0], values[:, 0])
    measured = search.measurements(acc)  # once: the C_A batches and the path's terms share it
    for t0 in range(1, T, READING_BATCH):
        if should_stop is not None and should_stop():
            raise SearchCancelled(f"search stopped at sample {t0} of {T}")
        block = slice(t0, t0 + READING_BATCH)
        # (a beam search's sparse steps compute only the readings they read)
        costs = None if search.narrow else search.reading_costs(acc[block], tuple(m[block] for m in measured))
        for t in range(t0, min(T, t0 + READING_BATCH)):
            search.step(acc[t], pos(t), head(t), kinds[:, t], values[:, t], None if costs is None else costs[t - t0])
    best = search.best_node()
    nodes, edges = search.trace(best)
    terms = path_terms(search, nodes, edges, acc, position, heading, measured)
    return SearchResult(
        node_path=nodes, edge_path=edges, cost=float(search.cost[best]), terms=terms,
        broken=[int(v) for v in search.rank[best]],
        compression=float(search.compression), peak_entries=int(search.peak_entries),
    )  # fmt: skip
