"""The Viterbi search's cost terms, and the per-node path state they read.

    G(n, t) = min over edges e = (m → n) of [L(e, t) + G(m, t−1)],   G(n, 0) = 0,
    L(e, t) = W_A·C_A + W_P·C_P + W_O·C_O + W_R·C_R   (Kelly et al. 2013, eq. 3–7; C_R ours)

- C_A, accelerometers: the mean over the sensors present of the squared difference
  between the edge's simulated reading and the measured one, in g² (eq. 4). A sensor
  with a NaN axis is left out; with none present C_A is 0.
- C_P, ground position: the distance in metres between the path's placement advanced
  by the edge (its offset, in the source's frame) and the tracker's position. Where it
  counts, the placement is then pulled toward the measured position by a share α
  (`track_pull`: a first-order filter with a time constant in seconds), so a path's
  ground track follows the tracker instead of drifting from where it started: C_P
  scores how far each step's edge carried the path from the measurement, and the
  synthesized root follows the same pulled track (`graph.metadata.integrate_path`).
- C_O, heading: |wrap(h + Δh − measured)| in radians, the path's heading advanced by
  the edge's turn against the measured heading.
- C_R, sensor orientation (where the recording has orientations and the graph their
  metadata, `graph.edge_up`): per sensor, the angle between the measured and the
  edge's sensor orientation after the best rotation about the vertical — the angle θ
  between the two sensor-frame "up" vectors — as the chord² |u_meas − u_edge|² =
  2 − 2·cos θ (≈ θ², at most 4), the mean over the sensors present. Yaw-free: a
  magnetometer-free IMU's yaw drift costs nothing. It rides in the C_A kernels as 3S
  more axes of each reading (`tables.search_tables(oriented)`), the mask weighting
  them by (W_R / W_A)·(n_A / n_R) (`search.ViterbiSearch.measurements`), so W_A·C_A +
  W_R·C_R is one per-reading value everywhere C_A is (at W_A = 0 the kernels'
  value is C_R, weighted by W_R).
A term counts at a sample where its weight is non-zero and it is measured (finite);
the placement is carried only when C_P or C_O can count. With γ annotation constraint
sets each path also carries γ counts of broken constraints, compared lexicographically
before G (eq. 8): `dense._satisfied`, `dense._select_py`, `dense._advance_py`,
`dense._best_node`.

Where each term is computed. A change to a term is made in every place listed for it;
the tests hold them equal (the float32 pass against the float64 passes step by step,
brute force over all paths, and `reference.reference_viterbi`, a plain numpy search):

- Which terms count at a sample: `search.ViterbiSearch.step` (use_pos, use_head).
- The measurement: `search.ViterbiSearch.measurements` (float32 in g, the sensor
  mask, the sensors present).
- C_A (and C_R with it): of every distinct reading, per sample, `_reading_costs_py` and, 16 samples at a
  time, `_reading_costs_batch_py`; of one reading `_reading_cost` (beam steps); along
  the final path `_path_terms`; `reference.reference_viterbi`.
- C_P and C_O: of an edge, from its source's row relative to the measurement
  (`_relative_row`, `_relative_py`), `_place_terms`, and eight edges at a time
  `intrinsics.keep_two_placed8` (LLVM IR); along the final path `_path_terms`;
  `reference.reference_viterbi`.
- The placement carried along an edge, and its pull: `_carry_placement`;
  `_path_terms`; `reference.reference_viterbi`; for synthesis
  `graph.metadata.integrate_path`.
- L(e, t) + G(m, t−1) in float64: `_exact_total` (through `_row_total`,
  `_state_total`, `_source_total`); unplaced, G + W_A·C_A: `dense._edge_totals_py`,
  `dense._finish_kernel`.
- The same less a base in float32 (pass 1): `dense._placed_total32`; unplaced:
  `dense._keep_two_run` with `intrinsics.keep_two_gathered8`, and
  `dense._approx_select_py`.
- Equal costs and the tie rule: `TIE`, `_tie_better`, `_exact_choice`;
  `dense._select_py`, `dense._best_node`, `dense._best_in_chunks`,
  `beam._best_in_list`.
- Each term summed along the final path, for the report: `_path_terms`.
"""

from __future__ import annotations

import numba
import numba.extending
import numpy as np

from graphsvc.strategies.options import track_pull  # noqa: F401  (the pull's α, for the search)
from graphsvc.strategies.viterbi.intrinsics import compile_kernel as _compile
from graphsvc.strategies.viterbi.intrinsics import fma as _fma


def pull_row(alpha: float, position, counts: bool) -> np.ndarray:
    """The pull `_carry_placement` applies this sample: (1 − α, α·mx, α·mz) where the
    position term counts, else (1, 0, 0)."""
    if not counts or alpha == 0.0:
        return np.array([1.0, 0.0, 0.0])
    return np.array([1.0 - alpha, alpha * float(position[0]), alpha * float(position[1])])


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
    """C_A (Kelly et al. 2013, eq. 4, g²) of every distinct edge reading: readings_t (3S, R) float32 in
    g, transposed so the inner loop runs along readings (SIMD); meas (3S,) float32 in
    g; mask (3S,) 0 on the axes of missing sensors (skipped), 1 elsewhere; scale = 1 /
    sensors present. An oriented search's readings and measurement carry 3S more axes,
    the sensors' "up" vectors, whose mask holds the root of the orientation term's
    weight relative to C_A's (`search.ViterbiSearch.measurements`): each axis adds
    ((r − m)·mask)² (×1 exact: C_A's arithmetic is unchanged) by one fused multiply-add, as every C_A kernel
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
            m, w = meas[j], mask[j]
            row = readings_t[j, r0 : r0 + n]
            for i in range(n):
                d = (row[i] - m) * w
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
            row = readings_t[j, r0 : r0 + n]
            for b in range(B):
                if mask[b, j] == 0.0:
                    continue
                m, w = meas[b, j], mask[b, j]
                for i in range(n):
                    d = (row[i] - m) * w
                    sums[b, i] = _fma(d, d, sums[b, i])
        for b in range(B):
            for i in range(n):
                out[b, r0 + i] = sums[b, i] * scale[b]


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


DEAD32 = np.float32(1e38)  # float32 cost of a dead path (finite, so tagging keeps it ordered)
DEAD_BELOW = np.float32(1e37)  # a live path's relative cost never comes near this


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
    return _exact_total(
        _cost_at(state, m), rel[m, QX], rel[m, QZ], rel[m, RH], ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head
    )


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
def _carry_placement(place_prev, m, place_new, n, ox, oz, dh, tc, ts, pull):
    """Node n's placement (state columns X…SIN): m's advanced by an edge (offset ox,
    oz in m's frame, turn dh with cos tc, sin ts), cos/sin carried by rotation — no
    trigonometry — then pulled toward the measured position: pull = (1 − α, α·mx,
    α·mz) (`track_pull`; (1, 0, 0) leaves it where the edge put it, bit for bit)."""
    c, s = place_prev[m, COS], place_prev[m, SIN]
    place_new[n, X] = pull[0] * (place_prev[m, X] + c * ox + s * oz) + pull[1]
    place_new[n, Z] = pull[0] * (place_prev[m, Z] - s * ox + c * oz) + pull[2]
    place_new[n, HEADING] = place_prev[m, HEADING] + dh
    place_new[n, COS] = c * tc - s * ts
    place_new[n, SIN] = s * tc + c * ts


@numba.njit(inline="always")
def _tie_better(i, b, slot_src, slot_kind, det_prev):
    """Between two paths of equal cost (within TIE): fewer non-original edges, then
    the plainer edge kind."""
    det = det_prev[slot_src[i]] + (1 if slot_kind[i] != 0 else 0)
    best_det = det_prev[slot_src[b]] + (1 if slot_kind[b] != 0 else 0)
    if det != best_det:
        return det < best_det
    return slot_kind[i] < slot_kind[b]


@numba.njit(inline="always")
def _reading_cost(readings, r, meas, mask, scale):
    """C_A of reading r alone, from its row of readings (R, 3S) float32 in g: the same
    arithmetic in the same order as `_reading_costs_py`, so the same value, bit for
    bit (a beam step computes only the readings its edges read)."""
    total = np.float32(0.0)
    for j in range(readings.shape[1]):
        if mask[j] != 0.0:
            d = (readings[r, j] - meas[j]) * mask[j]
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
        return lambda placed, state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head: (
            state[m] + w_acc * ca
        )

    def total(placed, state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head):
        if placed:
            return _state_total(state, m, mx, mz, mh, ca, ox, oz, dh, w_acc, w_pos, w_head, use_pos, use_head)
        return state[m, COST] + w_acc * ca

    return total


def _dead(live, state, m):
    """Whether source m has no live path: its mark in live ((N,) uint8, 1 on the live
    nodes), or where live is None its cost (inf)."""


@numba.extending.overload(_dead, inline="always")
def _dead_kernel(live, state, m):
    # A beam step's few live sources are marked in an array of N bytes, which stays in
    # the core's cache; the cost rows (N, W) do not, and most sources read are dead.
    if isinstance(live, numba.types.NoneType):
        return lambda live, state, m: _cost_at(state, m) == np.inf
    return lambda live, state, m: live[m] == 0


@numba.njit(inline="always")
def _exact_choice(
    n,
    incoming,
    edge_src,
    edge_reading,
    edge_kind,
    edge_offset,
    edge_heading,
    reading_cost,
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
    state,
    det_prev,
    live=None,
):
    """Node n's best incoming edge by the float64 rule of `dense._select_py` (candidates in
    graph order; lower total beyond TIE, else fewer detours, then plainer kind), each
    total from its source's state as pass 2 computes it (`_source_total`; the relative
    rows' values, bit for bit): (arrival index, −1 if no source is live; the total).
    C_A: see `_edge_ca` (pass 2's near-ties pass every reading's, a beam step None).
    live: see `_dead` (a beam step's marks of its live sources; None: the costs tell)."""
    first = np.int64(incoming[n])
    best = np.int64(-1)
    cb = np.inf
    for e in range(first, np.int64(incoming[n + 1])):
        m = np.int64(edge_src[e])
        if _dead(live, state, m):  # (never the better; its C_A is not worth computing)
            continue
        ca = _edge_ca(reading_cost, readings, meas, mask, scale, edge_reading[e])
        t = _source_total(
            placed,
            state,
            m,
            mx,
            mz,
            mh,
            ca,
            edge_offset[e, 0],
            edge_offset[e, 1],
            edge_heading[e],
            w_acc,
            w_pos,
            w_head,
            use_pos,
            use_head,
        )
        better = t < cb - TIE
        if abs(t - cb) <= TIE:
            better = _tie_better(e, best, edge_src, edge_kind, det_prev)  # (graph order instead of slot order)
        if better:
            best, cb = e, t
    return (best - first if best >= 0 else np.int64(-1)), cb


@numba.njit(cache=True, nogil=True)
def _path_terms(
    edges,
    readings_t,
    edge_reading,
    edge_offset,
    edge_heading,
    edge_turn,
    meas,
    mask,
    present,
    meas_pos,
    meas_heading,
    use_pos,
    use_head,
    x,
    z,
    h,
    c,
    s,
    alpha,
):
    """Accumulated acc (g²), position (m) and heading (rad) costs along one path, with
    the search's arithmetic. edges (T−1,); meas/mask (T, 3S) float32 as the search's
    measurement vectors; present (T,) sensors present; meas_pos (T, 2), meas_heading
    (T,); use_* whether each term counted; x, z, h, c, s the start placement; alpha
    the search's pull toward each measured position (`track_pull`)."""
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
                    d = (readings_t[j, r] - meas[t, j]) * mask[t, j]
                    acc = _fma(d, d, acc)  # as the C_A kernels: the search's values, bit for bit
            out[0] += acc * np.float32(1.0 / present[t])
        ox, oz = edge_offset[e, 0], edge_offset[e, 1]
        tc, ts = edge_turn[e, 0], edge_turn[e, 1]
        x, z = x + c * ox + s * oz, z - s * ox + c * oz
        h = h + edge_heading[e]
        c, s = c * tc - s * ts, s * tc + c * ts
        if use_pos and np.isfinite(meas_pos[t, 0]) and np.isfinite(meas_pos[t, 1]):
            out[1] += np.sqrt((x - meas_pos[t, 0]) ** 2 + (z - meas_pos[t, 1]) ** 2)
            if alpha != 0.0:  # (after the term: C_P scores where the edge put the path)
                x = (1.0 - alpha) * x + alpha * meas_pos[t, 0]
                z = (1.0 - alpha) * z + alpha * meas_pos[t, 1]
        if use_head and np.isfinite(meas_heading[t]):
            out[2] += abs(_wrap(h - meas_heading[t]))
    return out


_relative, _relative_serial = _compile(_relative_py, True), _compile(_relative_py, False)
