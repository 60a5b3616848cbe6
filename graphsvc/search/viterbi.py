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
search keeps the last 32 samples' back-pointers as a dense (32, N) block, written
sequentially, and every 32 samples traces back from all live nodes through it,
appending only the lattice points some live path passes through to a survivor store
(rows in sample order, parent before child). When the store has doubled, one backward
sweep keeps what the live paths still reach. The compression ratio reported is N·T over
the peak number of surviving lattice points. Once every survivor passes through one
point, the prefix up to it is final (the converged-prefix commit of streaming decoders).

Speed: the accelerometer cost is computed once per distinct edge reading (transition
edges read what their destination reads, so many edges share one), as float32 in g;
the per-node pass reads each incoming edge's source cost from one compact array.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from graphsvc.errors import InputError, SearchCancelled
from graphsvc.graph.model import MotionGraph
from graphsvc.sensors.accelerometer import GRAVITY

REQ_NONE, REQ_CONTACT, REQ_LABEL = 0, 1, 2
CONTACT_CODES = {"none": 0, "left": 1, "right": 2, "both": 3}  # bit 0 left, bit 1 right


@dataclass(frozen=True)
class Weights:
    """K eq. 6: accelerometers (per g²), position (per metre), orientation (per radian)."""

    acc: float = 1.0
    position: float = 1.0
    heading: float = 1.0


@numba.njit(cache=True, nogil=True)
def _wrap(a):
    """a wrapped into [−π, π) (floor, not a float modulo: this runs once per edge)."""
    return a - 2.0 * np.pi * np.floor((a + np.pi) * (0.5 / np.pi))


# Costs closer than this are equal (g², m, rad sums: far below any real difference).
# Among equal-cost candidates (standing still reads the same at any speed) the path
# with fewer non-original edges wins, then the plainer edge (original before
# slow-down, speed-up, transition, interpolated): exact input replays its own clip.
TIE = 1e-9


def _reading_costs_py(readings, meas, mask, scale, out):
    """C_A (K eq. 4, g²) of every distinct edge reading: readings (R, 3S) float32 in g,
    meas (3S,) float32 in g with missing sensors zeroed and `mask` 0 there (1
    elsewhere), scale = 1 / sensors present. One sequential pass: the bulk of the
    arithmetic, kept apart from the scattered per-node reads."""
    R, D = readings.shape
    for r in numba.prange(R):
        acc = np.float32(0.0)
        for j in range(D):
            d = readings[r, j] - meas[j]
            acc += mask[j] * d * d
        out[r] = acc * scale


# Each kernel twice: threaded for one search using the whole machine (batch), serial
# for many searches side by side (a server's streams), where threads would only fight.
_reading_costs = numba.njit(cache=True, nogil=True, parallel=True, fastmath=True)(_reading_costs_py)
_reading_costs_serial = numba.njit(cache=True, nogil=True, fastmath=True)(_reading_costs_py)


# Per-node path state. The cost is its own array — the one value read for every
# incoming edge, from a scattered source node, so it should stay in cache; the
# placement (ground x, z in m, heading in rad and its cos, sin) is read per edge only
# when position or heading is measured; the detour count only on near-ties.
X, Z, HEADING, COS, SIN, DET = 0, 1, 2, 3, 4, 5
PLACE_WIDTH = 8  # padded: one 64-byte row, one cache line per scattered read


# One step is three passes, each branch-light so the scattered reads of one edge or
# node overlap with the next (a single loop doing all three stalled on every read):
# edge totals, then each node's best incoming edge, then the chosen paths' state.


def _edge_totals_py(edge_src, edge_reading, edge_offset, edge_heading, reading_cost, meas_pos, meas_heading,
                    w_acc, w_pos, w_head, cost_prev, place_prev, total):  # fmt: skip
    """total (E,): the cost of each path extended by each edge, cost_prev[src] + L(e, t)
    (inf from a dead source). reading_cost (R,) C_A per distinct reading; meas_pos (2,)
    metres or NaN; meas_heading radians or NaN."""
    E = edge_src.shape[0]
    use_pos = np.isfinite(meas_pos[0]) and np.isfinite(meas_pos[1]) and w_pos != 0.0
    use_head = np.isfinite(meas_heading) and w_head != 0.0
    if not (use_pos or use_head):
        for e in numba.prange(E):
            total[e] = cost_prev[edge_src[e]] + w_acc * reading_cost[edge_reading[e]]
        return
    for e in numba.prange(E):
        m = edge_src[e]
        t = cost_prev[m] + w_acc * reading_cost[edge_reading[e]]
        if use_pos:
            ox, oz = edge_offset[e, 0], edge_offset[e, 1]
            c, s = place_prev[m, COS], place_prev[m, SIN]
            dx = place_prev[m, X] + c * ox + s * oz - meas_pos[0]
            dz = place_prev[m, Z] - s * ox + c * oz - meas_pos[1]
            t += w_pos * np.sqrt(dx * dx + dz * dz)
        if use_head:
            t += w_head * abs(_wrap(place_prev[m, HEADING] + edge_heading[e] - meas_heading))
        total[e] = t


def _select_py(incoming, edge_src, edge_kind, total, allowed, place_prev, rank_prev, cost_new, best_edge):
    """Each node's best incoming edge (−1: none alive, or the node is masked): fewest
    broken constraints (rank, lexicographic), then lowest total (within TIE counts as
    equal), then fewer non-original edges so far (det, read only on a near-tie), then
    the plainer edge kind."""
    N = incoming.shape[0] - 1
    gamma = rank_prev.shape[1]
    for n in numba.prange(N):
        best = -1
        best_cost = np.inf
        best_det = -1.0
        if allowed[n]:
            for e in range(incoming[n], incoming[n + 1]):
                t = total[e]
                if t == np.inf:
                    continue
                if best < 0:
                    best, best_cost, best_det = e, t, -1.0
                    continue
                m, mb = edge_src[e], edge_src[best]
                decided = False
                better = False
                for k in range(gamma):
                    if rank_prev[m, k] != rank_prev[mb, k]:
                        better = rank_prev[m, k] < rank_prev[mb, k]
                        decided = True
                        break
                det = -1.0
                if not decided:
                    if t < best_cost - TIE:
                        better = True
                    elif t > best_cost + TIE:
                        better = False
                    else:
                        det = place_prev[m, DET] + (1.0 if edge_kind[e] != 0 else 0.0)
                        if best_det < 0.0:
                            best_det = place_prev[mb, DET] + (1.0 if edge_kind[best] != 0 else 0.0)
                        if det != best_det:
                            better = det < best_det
                        else:
                            better = edge_kind[e] < edge_kind[best]
                if better:
                    best, best_cost, best_det = e, t, det
        best_edge[n] = best
        cost_new[n] = best_cost


def _advance_py(best_edge, edge_src, edge_kind, edge_offset, edge_heading, edge_turn, ok, place_prev, rank_prev,
                place_new, rank_new):  # fmt: skip
    """The new state of every live path from its predecessor's along its best edge:
    placement (cos/sin carried by rotation, no trigonometry), detour count, broken
    constraints. (Per-term costs are summed along the final path afterwards.)"""
    N = best_edge.shape[0]
    gamma = rank_prev.shape[1]
    for n in numba.prange(N):
        e = best_edge[n]
        if e < 0:
            continue
        m = edge_src[e]
        ox, oz = edge_offset[e, 0], edge_offset[e, 1]
        c, s = place_prev[m, COS], place_prev[m, SIN]
        tc, ts = edge_turn[e, 0], edge_turn[e, 1]
        place_new[n, X] = place_prev[m, X] + c * ox + s * oz
        place_new[n, Z] = place_prev[m, Z] - s * ox + c * oz
        place_new[n, HEADING] = place_prev[m, HEADING] + edge_heading[e]
        place_new[n, COS] = c * tc - s * ts
        place_new[n, SIN] = s * tc + c * ts
        place_new[n, DET] = place_prev[m, DET] + (1.0 if edge_kind[e] != 0 else 0.0)
        for k in range(gamma):
            rank_new[n, k] = rank_prev[m, k] + (0 if ok[k, n] else 1)


@numba.njit(cache=True, nogil=True)
def _path_terms(edges, readings, edge_reading, edge_offset, edge_heading, edge_turn, meas, mask, present, meas_pos,
                meas_heading, use_pos, use_head, x, z, h, c, s):  # fmt: skip
    """Accumulated acc (g²), position (m) and heading (rad) costs along one path, with
    the search's arithmetic. edges (T−1,); meas/mask (T, 3S) float32 as the search's
    measurement vectors; present (T,) sensors present; meas_pos (T, 2), meas_heading
    (T,); use_* whether each term counted; x, z, h, c, s the start placement."""
    out = np.zeros(3)
    D = readings.shape[1]
    for k in range(edges.shape[0]):
        t = k + 1
        e = edges[k]
        if present[t] > 0:
            r = edge_reading[e]
            acc = np.float32(0.0)
            for j in range(D):
                d = readings[r, j] - meas[t, j]
                acc += mask[t, j] * d * d
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


def _compile(fn, parallel: bool):
    return numba.njit(cache=True, nogil=True, parallel=parallel)(fn)


_edge_totals, _edge_totals_serial = _compile(_edge_totals_py, True), _compile(_edge_totals_py, False)
_select, _select_serial = _compile(_select_py, True), _compile(_select_py, False)
_advance, _advance_serial = _compile(_advance_py, True), _compile(_advance_py, False)


def search_tables(graph: MotionGraph) -> dict:
    """The graph's arrays in the search's layout, made once per graph and cached on
    it: distinct edge readings (R, 3S) float32 in g and each edge's reading (E,) int32
    (transition edges read what their destination reads in its own clip, so many
    edges share one), compact edge arrays."""
    cached = getattr(graph, "_search_tables", None)
    if cached is not None:
        return cached
    E = graph.num_edges
    flat = np.ascontiguousarray(graph.edge_acc, dtype=np.float32).reshape(E, -1)
    readings, edge_reading = np.unique(flat, axis=0, return_inverse=True)
    tables = {
        "readings": np.ascontiguousarray((readings.astype(np.float64) / GRAVITY).astype(np.float32)),
        "edge_reading": edge_reading.reshape(-1).astype(np.int32),
        "incoming": np.ascontiguousarray(graph.incoming, dtype=np.int64),
        "edge_src": np.ascontiguousarray(graph.edge_src, dtype=np.int32),
        "edge_kind": np.ascontiguousarray(graph.edge_kind, dtype=np.uint8),
        "edge_offset": np.ascontiguousarray(graph.edge_offset, dtype=np.float32),
        "edge_heading": np.ascontiguousarray(graph.edge_heading, dtype=np.float32),
        "edge_turn": np.ascontiguousarray(np.stack([np.cos(graph.edge_heading.astype(np.float64)),
                                                    np.sin(graph.edge_heading.astype(np.float64))], axis=-1)),
    }
    graph._search_tables = tables
    return tables


# Survivor store: rows of one (capacity, 4) int32 array — node, edge used to arrive,
# parent row, sample. Rows are appended a block at a time in sample order, so a parent
# always precedes its children and garbage collection is one backward sweep.
NODE, EDGE, PARENT, TIME = 0, 1, 2, 3


@numba.njit(cache=True, nogil=True)
def _block_levels(block, used, edge_src, mark, stamp, level_nodes, level_start):
    """Walk back from every node alive at the block's last row, one row at a time:
    level_nodes[level_start[k]:level_start[k+1]] are the distinct nodes row k's
    surviving paths pass through. block (B, N) int32 best incoming edges (−1 dead).
    Returns (total, stamp, converged_row): converged_row is the highest row where a
    single node remains (−1 if none); total = −1 when level_nodes is too small (the
    caller grows it and asks again)."""
    N = block.shape[1]
    # Fill from the top row down, at the end of level_nodes, then shift into place.
    end = level_nodes.shape[0]
    pos = end
    top_count = 0
    for n in range(N - 1, -1, -1):
        if block[used - 1, n] >= 0:
            pos -= 1
            level_nodes[pos] = n
            top_count += 1  # level_nodes holds at least N: the top row always fits
    counts = np.zeros(used, np.int64)
    counts[used - 1] = top_count
    hi = end
    lo = pos
    for k in range(used - 1, 0, -1):
        stamp += 1
        start = pos
        for i in range(lo, hi):
            m = edge_src[block[k, level_nodes[i]]]
            if mark[m] != stamp:
                mark[m] = stamp
                if pos == 0:
                    return -1, stamp, -1
                pos -= 1
                level_nodes[pos] = m
        counts[k - 1] = start - pos
        hi = start
        lo = pos
    total = end - pos
    # Rows in ascending order: row 0's nodes sit lowest already; record the offsets.
    level_nodes[:total] = level_nodes[pos:end].copy()
    level_start[0] = 0
    for k in range(used):
        level_start[k + 1] = level_start[k] + counts[k]
    converged_row = -1
    for k in range(used - 1, -1, -1):
        if counts[k] == 1:
            converged_row = k
            break
    return total, stamp, converged_row


@numba.njit(cache=True, nogil=True)
def _append_block(block, used, t_top, heads, edge_src, store, size, level_nodes, level_start, row_of):
    """Append the block's surviving lattice points (see `_block_levels`) to the store in
    sample order; heads (N,): each node's row at the sample before the block on entry,
    at the block's last sample on return (−1: not alive). row_of (N,) scratch.
    Returns the new size."""
    t0 = t_top - used + 1
    for k in range(used):
        for i in range(level_start[k], level_start[k + 1]):
            n = level_nodes[i]
            e = block[k, n]
            m = edge_src[e]
            parent = heads[m] if k == 0 else row_of[m]
            store[size, NODE] = n
            store[size, EDGE] = e
            store[size, PARENT] = parent
            store[size, TIME] = t0 + k
            size += 1
        # row_of now refers to row k (read by row k+1); a node appears once per row.
        for i in range(level_start[k], level_start[k + 1]):
            row_of[level_nodes[i]] = size - (level_start[k + 1] - i)
    heads[:] = -1
    for i in range(level_start[used - 1], level_start[used]):
        heads[level_nodes[i]] = row_of[level_nodes[i]]
    return size


@numba.njit(cache=True, nogil=True)
def _collect(store, size, heads):
    """Keep only rows some live head reaches; renumber parents and heads. Returns
    (new size, kept rows per sample is left to the caller)."""
    keep = np.zeros(size, np.bool_)
    for n in range(heads.shape[0]):
        if heads[n] >= 0:
            keep[heads[n]] = True
    for i in range(size - 1, -1, -1):
        if keep[i] and store[i, PARENT] >= 0:
            keep[store[i, PARENT]] = True
    new_row = np.empty(size, np.int64)
    j = 0
    for i in range(size):
        if keep[i]:
            new_row[i] = j
            p = store[i, PARENT]
            store[j, NODE] = store[i, NODE]
            store[j, EDGE] = store[i, EDGE]
            store[j, PARENT] = new_row[p] if p >= 0 else -1
            store[j, TIME] = store[i, TIME]
            j += 1
    for n in range(heads.shape[0]):
        if heads[n] >= 0:
            heads[n] = new_row[heads[n]]
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
def _trace(block, used, t, heads, edge_src, store, node, since):
    """Nodes at samples since..t of the path ending at `node` at sample t, and the
    edge each was entered by (−1 at sample 0): through the block's rows, then the
    store."""
    count = t - since + 1
    nodes = np.empty(count, np.int64)
    edges = np.empty(count, np.int64)
    i = count - 1
    n = node
    for k in range(used - 1, -1, -1):
        if i < 0:
            break
        e = block[k, n]
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
    constraint set, broken constraints; compression: N·T / peak survivor entries."""

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


class ViterbiSearch:
    """Incremental search: `start(first sample)`, `step(sample)` per sample, then
    `trace(best_node())`. Used by the batch search and by streaming decoders alike.

    Samples: acc (S, 3) m/s² (NaN = missing), position (2,) m or NaN, heading rad or NaN."""

    def __init__(self, graph: MotionGraph, weights: Weights = Weights(), gamma: int = 0, allowed: np.ndarray | None = None,
                 threads: bool = True):  # fmt: skip
        """allowed: (N,) bool, nodes the search may use (None: all); masked nodes are
        never entered, which is how leave-one-out evaluation hides a clip. threads:
        spread each step over numba's threads (one search at a time) or not (many
        searches in parallel, e.g. a server's streams)."""
        self.graph = graph
        self._kernels = ((_reading_costs, _edge_totals, _select, _advance) if threads else
                         (_reading_costs_serial, _edge_totals_serial, _select_serial, _advance_serial))  # fmt: skip
        self.weights = weights
        N = graph.num_nodes
        self.N = N
        self.gamma = gamma
        tables = search_tables(graph)
        self.incoming = tables["incoming"]
        self.edge_src = tables["edge_src"]
        self.edge_kind = tables["edge_kind"]
        self.edge_offset = tables["edge_offset"]
        self.edge_heading = tables["edge_heading"]
        self.edge_turn = tables["edge_turn"]
        self.readings = tables["readings"]
        self.edge_reading = tables["edge_reading"]
        c = graph.node_contacts
        self.contact_code = (c[:, 0].astype(np.int64) | (c[:, 1].astype(np.int64) << 1))
        self.label = np.ascontiguousarray(graph.node_label, dtype=np.int64)
        self.cost = np.zeros(N)
        self.place = np.zeros((N, PLACE_WIDTH))
        self.rank = np.zeros((N, gamma), dtype=np.int64)
        self._scratch = (np.zeros(N), np.zeros((N, PLACE_WIDTH)), np.zeros((N, gamma), np.int64))
        self.best_edge = np.zeros(N, dtype=np.int32)
        self.total = np.zeros(graph.num_edges)
        self.reading_cost = np.zeros(self.readings.shape[0], dtype=np.float32)
        self._meas = np.zeros(self.readings.shape[1], dtype=np.float32)
        self._mask = np.ones(self.readings.shape[1], dtype=np.float32)
        self.ok = np.ones((gamma, N), dtype=bool)
        if allowed is None:
            self.allowed = np.ones(N, dtype=bool)
        else:
            self.allowed = np.ascontiguousarray(allowed, dtype=bool)
            if self.allowed.shape != (N,):
                raise InputError(f"node mask must have {N} entries, got {self.allowed.shape}")
            if not self.allowed.any():
                raise InputError("the node mask leaves no node to search")
        self.converged_t = -1  # every sample ≤ this one has a single surviving entry
        # Back-pointers of the last BLOCK samples as a dense (BLOCK, N) lattice, written
        # sequentially each step; every BLOCK samples its surviving points move into the
        # reference-counted tree (K §5.1's periodic trace-back from all live nodes).
        self.block = np.full((self.BLOCK, N), -1, dtype=np.int32)
        self.used = 0  # rows of the block filled since the last compaction
        self.mark = np.zeros(N, dtype=np.int64)
        self.row_of = np.zeros(N, dtype=np.int64)
        self.stamp = 0
        self.level_nodes = np.zeros(2 * N + 16, dtype=np.int32)
        self.level_start = np.zeros(self.BLOCK + 1, dtype=np.int64)
        self.store = np.zeros((2 * N + 16, 4), dtype=np.int32)  # 16 bytes a row; doubles when full
        self.size = 0  # rows of the store in use (live or garbage)
        self.live_rows = 0  # rows alive after the last collection
        self.heads = np.full(N, -1, dtype=np.int64)
        self.t = -1
        self.peak_entries = 0

    BLOCK = 32

    @property
    def live_entries(self) -> int:
        """Store rows in use (survivors plus garbage not yet collected)."""
        return self.size

    def start(self, position=None, heading=None, kinds_t=None, values_t=None):
        """Sample 0: every node starts a path at the first measured position/heading."""
        self.t = 0
        p = np.zeros(2) if position is None or not np.all(np.isfinite(position)) else np.asarray(position, float)
        h = 0.0 if heading is None or not np.isfinite(heading) else float(heading)
        self.place[:, X], self.place[:, Z] = p
        self.place[:, HEADING], self.place[:, COS], self.place[:, SIN] = h, np.cos(h), np.sin(h)
        self.cost[:] = np.where(self.allowed, 0.0, np.inf)
        self.place[:, DET] = 0.0
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
        self.used = 0
        self.converged_t = 0 if len(live) == 1 else -1
        self.peak_entries = self.size

    def step(self, acc, position=None, heading=None, kinds_t=None, values_t=None):
        """Advance by one sample."""
        if self.used == self.BLOCK:
            self.compact()
        self.t += 1
        cost, place, rank = self._scratch
        best_edge = self.best_edge
        meas_pos = np.full(2, np.nan) if position is None else np.asarray(position, dtype=np.float64)
        meas_head = np.nan if heading is None else float(heading)
        if self.gamma:
            _satisfied(kinds_t, values_t, self.contact_code, self.label, self.ok)
        w = self.weights
        # Computed even at W_A = 0: the report carries each path's accelerometer cost.
        self._set_measurement(acc)
        present = float(self._mask.sum()) / 3.0
        reading_costs, edge_totals, select, advance = self._kernels
        if present:
            reading_costs(self.readings, self._meas, self._mask, np.float32(1.0 / present), self.reading_cost)
        else:
            self.reading_cost[:] = 0.0
        wa, wp, wh = float(w.acc), float(w.position), float(w.heading)
        edge_totals(self.edge_src, self.edge_reading, self.edge_offset, self.edge_heading, self.reading_cost, meas_pos,
                    meas_head, wa, wp, wh, self.cost, self.place, self.total)
        select(self.incoming, self.edge_src, self.edge_kind, self.total, self.allowed, self.place, self.rank, cost,
               best_edge)  # fmt: skip
        advance(best_edge, self.edge_src, self.edge_kind, self.edge_offset, self.edge_heading, self.edge_turn, self.ok,
                self.place, self.rank, place, rank)  # fmt: skip
        if not np.any(best_edge >= 0):
            raise InputError(f"no graph path reaches sample {self.t}: every path ran into a dead end")
        self.block[self.used] = best_edge
        self.used += 1
        # Swap buffers: the new state becomes the previous one.
        self._scratch = (self.cost, self.place, self.rank)
        self.cost, self.place, self.rank = cost, place, rank

    def _set_measurement(self, acc) -> None:
        """Measured accelerations (S, 3) m/s² → the kernel's (3S,) g vector and mask:
        a sensor with any NaN axis is left out (K eq. 4 averages over sensors present)."""
        a = np.asarray(acc, dtype=np.float32).reshape(-1, 3)
        valid = np.isfinite(a).all(axis=1)
        # float32(m/s²) / g in float64, rounded once — exactly as the readings table.
        g = (a.astype(np.float64) / GRAVITY).astype(np.float32)
        self._meas[:] = np.where(valid[:, None], g, 0.0).reshape(-1)
        self._mask[:] = np.repeat(valid, 3).astype(np.float32)


    def compact(self) -> None:
        """Move the block's surviving lattice points into the store (K §5.1's trace-back
        from all live nodes); collect the store's garbage when it has doubled."""
        if self.used == 0:
            return
        while True:  # grown on demand: the worst case (nothing merges) is used × N
            total, self.stamp, converged_row = _block_levels(self.block, self.used, self.edge_src, self.mark,
                                                             self.stamp, self.level_nodes, self.level_start)  # fmt: skip
            if total >= 0:
                break
            self.level_nodes = np.zeros(2 * self.level_nodes.shape[0], dtype=np.int32)
        if self.size + total > self.store.shape[0]:
            self._collect()
            if self.size + total > self.store.shape[0] // 2:
                bigger = np.zeros((2 * (self.size + total), 4), dtype=np.int32)
                bigger[: self.size] = self.store[: self.size]
                self.store = bigger
        self.size = _append_block(self.block, self.used, self.t, self.heads, self.edge_src, self.store, self.size,
                                  self.level_nodes, self.level_start, self.row_of)  # fmt: skip
        t_first = self.t - self.used + 1
        self.used = 0
        self.peak_entries = max(self.peak_entries, self.live_rows + total)
        if converged_row >= 0:  # one node left at that row: everything up to it is agreed
            self.converged_t = max(self.converged_t, t_first + converged_row)

    def _collect(self) -> None:
        self.size = _collect(self.store, self.size, self.heads)
        self.live_rows = self.size
        self.peak_entries = max(self.peak_entries, self.size)
        if self.converged_t < self.t:
            self.converged_t = _converged_until(self.store, self.size, self.converged_t + 1, self.t)

    @property
    def alive(self) -> np.ndarray:
        return np.isfinite(self.cost)

    def best_node(self) -> int:
        """The live node whose path ranks first: fewest broken constraints, then cost
        (within TIE counts as equal), then fewer non-original edges, then lower node id."""
        alive = np.nonzero(self.alive)[0]
        cost = np.round(self.cost[alive] / TIE) if np.all(np.abs(self.cost[alive]) < 1e6) else self.cost[alive]
        keys = [alive, self.place[alive, DET], cost] + [self.rank[alive, k] for k in range(self.gamma - 1, -1, -1)]
        return int(alive[np.lexsort(keys)[0]])

    def trace_arrivals(self, node: int, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (t+1−since,) at samples since..t of the path ending at `node` now and
        the edge each was entered by (−1 at sample 0). Walks back only to `since`, so
        a fixed-lag trace costs the lag, not the input length."""
        if not 0 <= since <= self.t:
            raise InputError(f"cannot trace from sample {since}: the search is at sample {self.t}")
        return _trace(self.block, self.used, self.t, self.heads, self.edge_src, self.store, int(node), int(since))

    def trace(self, node: int, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (t+1−since,) at samples since..t of the path ending at `node` now,
        and the edges (t−since,) between them."""
        nodes, edges = self.trace_arrivals(node, since)
        return nodes, edges[1:]


def path_terms(search: ViterbiSearch, nodes: np.ndarray, edges: np.ndarray, acc, position=None, heading=None) -> dict:
    """The accelerometer (g²), position (m) and heading (rad) costs accumulated along a
    path found by `search` (unweighted; a term counts where the search used it)."""
    T = nodes.shape[0]
    meas = np.zeros((T, search.readings.shape[1]), np.float32)
    mask = np.zeros_like(meas)
    for t in range(T):
        search._set_measurement(acc[t])
        meas[t], mask[t] = search._meas, search._mask
    present = mask.sum(axis=1) / 3.0
    pos = np.full((T, 2), np.nan) if position is None else np.asarray(position, dtype=np.float64)
    head = np.full(T, np.nan) if heading is None else np.asarray(heading, dtype=np.float64)
    p0 = pos[0] if np.all(np.isfinite(pos[0])) else np.zeros(2)
    h0 = float(head[0]) if np.isfinite(head[0]) else 0.0
    w = search.weights
    out = _path_terms(edges.astype(np.int64), search.readings, search.edge_reading, search.edge_offset,
                      search.edge_heading, search.edge_turn, meas, mask, present, pos, head, w.position != 0,
                      w.heading != 0, float(p0[0]), float(p0[1]), h0, np.cos(h0), np.sin(h0))  # fmt: skip
    return {"acc_g2": float(out[0]), "position_m": float(out[1]), "heading_rad": float(out[2])}


def viterbi_search(graph: MotionGraph, acc: np.ndarray, position=None, heading=None, weights: Weights = Weights(),
                   constraint_sets: list | None = None, rate_hz: float | None = None,
                   allowed: np.ndarray | None = None, threads: bool = True, should_stop=None) -> SearchResult:  # fmt: skip
    """Batch search. acc: (T, S, 3) m/s² in the graph's layout (NaN = missing);
    position: (T, 2) m or None; heading: (T,) rad or None; constraint_sets: see
    `compile_constraints` (times from sample index / graph rate); allowed: (N,) bool
    node mask or None; threads: see ViterbiSearch; should_stop: a callable polled
    every 32 samples — when it returns true the search raises SearchCancelled (a
    server stops work for a client that went away)."""
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
    search = ViterbiSearch(graph, weights, gamma, allowed, threads)
    pos = (lambda t: None) if position is None else (lambda t: position[t])
    head = (lambda t: None) if heading is None else (lambda t: heading[t])
    search.start(pos(0), head(0), kinds[:, 0], values[:, 0])
    for t in range(1, T):
        if should_stop is not None and t % 32 == 0 and should_stop():
            raise SearchCancelled(f"search stopped at sample {t} of {T}")
        search.step(acc[t], pos(t), head(t), kinds[:, t], values[:, t])
    search.compact()
    best = search.best_node()
    nodes, edges = search.trace(best)
    N = graph.num_nodes
    terms = path_terms(search, nodes, edges, acc, position, heading)
    return SearchResult(
        node_path=nodes, edge_path=edges, cost=float(search.cost[best]), terms=terms,
        broken=[int(v) for v in search.rank[best]],
        compression=float(N * T / max(search.peak_entries, 1)), peak_entries=int(search.peak_entries),
    )  # fmt: skip
