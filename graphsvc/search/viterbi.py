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
search keeps a survivor tree — one entry per (node, sample) that some live path still
passes through, reference-counted by its children and by being a live path's head.
When a path dies its entries are freed at once, so the tree holds only the lattice
points a periodic trace-back from all nodes would keep. The compression ratio
reported is N·t over the entries alive.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from graphsvc.errors import InputError
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
    return (a + np.pi) % (2.0 * np.pi) - np.pi


# Costs closer than this are equal (g², m, rad sums: far below any real difference).
# Among equal-cost candidates (standing still reads the same at any speed) the path
# with fewer non-original edges wins, then the plainer edge (original before
# slow-down, speed-up, transition, interpolated): exact input replays its own clip.
TIE = 1e-9


@numba.njit(cache=True, nogil=True, parallel=True)
def _edge_acc_costs(edge_acc, meas_acc, out):
    """C_A of every edge (K eq. 4) in g²: one sequential pass over the metadata,
    the bulk of the arithmetic, kept apart from the scattered per-node reads.
    meas_acc (S, 3) in g; sensors with a NaN axis are left out of the mean."""
    E, S = edge_acc.shape[0], edge_acc.shape[1]
    inv_g = 1.0 / 9.81
    valid = np.empty(S, dtype=np.bool_)
    n_valid = 0
    for s in range(S):
        valid[s] = np.isfinite(meas_acc[s, 0]) and np.isfinite(meas_acc[s, 1]) and np.isfinite(meas_acc[s, 2])
        if valid[s]:
            n_valid += 1
    if n_valid == 0:
        out[:] = 0.0
        return
    scale = 1.0 / n_valid
    for e in numba.prange(E):
        acc = 0.0
        for s in range(S):
            if valid[s]:
                for k in range(3):
                    d = edge_acc[e, s, k] * inv_g - meas_acc[s, k]
                    acc += d * d
        out[e] = acc * scale


@numba.njit(cache=True, nogil=True, parallel=True)
def _step(
    incoming, edge_src, edge_kind, edge_cost_acc, edge_offset, edge_heading,
    meas_pos, meas_heading, w_acc, w_pos, w_head,
    ok, allowed,
    cost_prev, rank_prev, pos_prev, head_prev,
    cost_new, rank_new, pos_new, head_new, best_edge, term_new, term_prev,
):  # fmt: skip
    """One sample: for every node, the best incoming edge from a live path.
    edge_cost_acc (E,) C_A per edge this sample; meas_pos (2,) metres or NaN;
    meas_heading radians or NaN; ok (γ, N) constraint satisfaction of each node now;
    allowed (N,) bool: nodes the search may visit (leave-one-out masking);
    cost_prev = inf marks dead paths; term_* (N, 4): per-path accumulated acc /
    position / heading costs (for reports) and the count of non-original edges
    (the tie-break)."""
    N = cost_prev.shape[0]
    gamma = rank_prev.shape[1]
    use_pos = np.isfinite(meas_pos[0]) and np.isfinite(meas_pos[1]) and w_pos != 0.0
    use_head = np.isfinite(meas_heading) and w_head != 0.0
    carry = use_pos or use_head
    cos_prev = np.cos(head_prev)  # once per node, not once per edge
    sin_prev = np.sin(head_prev)
    for n in numba.prange(N):
        if not allowed[n]:
            best_edge[n] = -1
            cost_new[n] = np.inf
            continue
        best = -1
        best_cost = np.inf
        best_det = 0.0
        best_cp = 0.0
        best_co = 0.0
        for e in range(incoming[n], incoming[n + 1]):
            m = edge_src[e]
            base = cost_prev[m]
            if base == np.inf:
                continue
            total = base + w_acc * edge_cost_acc[e]
            cp = 0.0
            co = 0.0
            if carry:
                if use_pos:
                    ox, oz = edge_offset[e, 0], edge_offset[e, 1]
                    px = pos_prev[m, 0] + cos_prev[m] * ox + sin_prev[m] * oz
                    pz = pos_prev[m, 1] - sin_prev[m] * ox + cos_prev[m] * oz
                    cp = np.sqrt((px - meas_pos[0]) ** 2 + (pz - meas_pos[1]) ** 2)
                if use_head:
                    co = abs(_wrap(head_prev[m] + edge_heading[e] - meas_heading))
                total += w_pos * cp + w_head * co
            det = -1.0  # read only on a near-tie: one scattered read per edge, not two
            if best >= 0:
                mb = edge_src[best]
                better = False
                decided = False
                for k in range(gamma):
                    if rank_prev[m, k] != rank_prev[mb, k]:
                        better = rank_prev[m, k] < rank_prev[mb, k]
                        decided = True
                        break
                if not decided:
                    if total < best_cost - TIE:
                        better = True
                    elif total > best_cost + TIE:
                        better = False
                    else:
                        det = term_prev[m, 3] + (1.0 if edge_kind[e] != 0 else 0.0)
                        if det != best_det:
                            better = det < best_det
                        else:
                            better = edge_kind[e] < edge_kind[best]
                if not better:
                    continue
            if det < 0.0:
                det = term_prev[m, 3] + (1.0 if edge_kind[e] != 0 else 0.0)
            best = e
            best_cost = total
            best_det = det
            best_cp = cp
            best_co = co
        best_edge[n] = best
        if best < 0:
            cost_new[n] = np.inf
            continue
        m = edge_src[best]
        cost_new[n] = best_cost
        for k in range(gamma):
            rank_new[n, k] = rank_prev[m, k] + (0 if ok[k, n] else 1)
        ox, oz = edge_offset[best, 0], edge_offset[best, 1]
        pos_new[n, 0] = pos_prev[m, 0] + cos_prev[m] * ox + sin_prev[m] * oz
        pos_new[n, 1] = pos_prev[m, 1] - sin_prev[m] * ox + cos_prev[m] * oz
        head_new[n] = head_prev[m] + edge_heading[best]
        term_new[n, 0] = term_prev[m, 0] + edge_cost_acc[best]
        term_new[n, 1] = term_prev[m, 1] + best_cp
        term_new[n, 2] = term_prev[m, 2] + best_co
        term_new[n, 3] = best_det


# Survivor-tree entries are rows of one (capacity, 5) int64 array — node, edge used to
# arrive, parent entry, reference count, sample — so touching an entry is one cache line.
NODE, EDGE, PARENT, REFS, TIME = 0, 1, 2, 3, 4


@numba.njit(cache=True, nogil=True)
def _grow_tree(head, best_edge, edge_src, entries, free, n_free, t, level_count):
    """Add one survivor-tree entry per live node at sample t (parent: its
    predecessor's head entry), then release the old heads, freeing every entry no
    live path uses. level_count[τ]: entries alive at sample τ (1 = converged)."""
    N = head.shape[0]
    new_head = np.full(N, -1, dtype=np.int64)
    for n in range(N):
        e = best_edge[n]
        if e < 0:
            continue
        parent = head[edge_src[e]]
        n_free -= 1
        slot = free[n_free]
        entries[slot, NODE] = n
        entries[slot, EDGE] = e
        entries[slot, PARENT] = parent
        entries[slot, REFS] = 1  # a live head
        entries[slot, TIME] = t
        entries[parent, REFS] += 1  # its child
        new_head[n] = slot
        level_count[t] += 1
    for n in range(N):
        slot = head[n]
        while slot >= 0:  # release, cascading up while nothing refers to the entry
            entries[slot, REFS] -= 1
            if entries[slot, REFS] > 0:
                break
            free[n_free] = slot
            n_free += 1
            level_count[entries[slot, TIME]] -= 1
            slot = entries[slot, PARENT]
    head[:] = new_head
    return n_free


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

    def __init__(self, graph: MotionGraph, weights: Weights = Weights(), gamma: int = 0, allowed: np.ndarray | None = None):
        """allowed: (N,) bool, nodes the search may use (None: all); masked nodes are
        never entered, which is how leave-one-out evaluation hides a clip."""
        self.graph = graph
        self.weights = weights
        N = graph.num_nodes
        self.N = N
        self.gamma = gamma
        self.incoming = np.ascontiguousarray(graph.incoming, dtype=np.int64)
        self.edge_src = np.ascontiguousarray(graph.edge_src, dtype=np.int64)
        self.edge_kind = np.ascontiguousarray(graph.edge_kind, dtype=np.int64)
        self.edge_acc = graph.edge_acc
        self.edge_offset = np.ascontiguousarray(graph.edge_offset, dtype=np.float64)
        self.edge_heading = np.ascontiguousarray(graph.edge_heading, dtype=np.float64)
        c = graph.node_contacts
        self.contact_code = (c[:, 0].astype(np.int64) | (c[:, 1].astype(np.int64) << 1))
        self.label = np.ascontiguousarray(graph.node_label, dtype=np.int64)
        self.cost = np.zeros(N)
        self.rank = np.zeros((N, gamma), dtype=np.int64)
        self.pos = np.zeros((N, 2))
        self.head = np.zeros(N)
        self.terms = np.zeros((N, 4))
        self._scratch = (np.zeros(N), np.zeros((N, gamma), np.int64), np.zeros((N, 2)), np.zeros(N),
                         np.zeros(N, np.int64), np.zeros((N, 4)))  # fmt: skip
        self.edge_cost_acc = np.zeros(graph.num_edges)
        self.ok = np.ones((gamma, N), dtype=bool)
        if allowed is None:
            self.allowed = np.ones(N, dtype=bool)
        else:
            self.allowed = np.ascontiguousarray(allowed, dtype=bool)
            if self.allowed.shape != (N,):
                raise InputError(f"node mask must have {N} entries, got {self.allowed.shape}")
            if not self.allowed.any():
                raise InputError("the node mask leaves no node to search")
        self.level_count = np.zeros(1024, dtype=np.int64)
        self.converged_t = -1  # every sample ≤ this one has a single surviving entry
        cap = 4 * N + 16
        self._alloc(cap)
        self.t = -1
        self.peak_entries = 0

    def _alloc(self, cap):
        self.entries = np.zeros((cap, 5), np.int64)
        self.free = np.arange(cap - 1, -1, -1, dtype=np.int64)
        self.n_free = cap

    def _grow(self):
        old = len(self.entries)
        cap = 2 * old
        bigger = np.zeros((cap, 5), np.int64)
        bigger[:old] = self.entries
        self.entries = bigger
        free = np.empty(cap, np.int64)
        free[: self.n_free] = self.free[: self.n_free]
        free[self.n_free : self.n_free + (cap - old)] = np.arange(cap - 1, old - 1, -1)
        self.free = free
        self.n_free += cap - old

    @property
    def live_entries(self) -> int:
        return len(self.entries) - self.n_free

    def start(self, position=None, heading=None, kinds_t=None, values_t=None):
        """Sample 0: every node starts a path at the first measured position/heading."""
        N = self.N
        self.t = 0
        p = np.zeros(2) if position is None or not np.all(np.isfinite(position)) else np.asarray(position, float)
        h = 0.0 if heading is None or not np.isfinite(heading) else float(heading)
        self.pos[:] = p
        self.head[:] = h
        self.cost[:] = np.where(self.allowed, 0.0, np.inf)
        if self.gamma:
            _satisfied(kinds_t, values_t, self.contact_code, self.label, self.ok)
            self.rank[:] = (~self.ok).T
        live = np.nonzero(self.allowed)[0]
        slots = self.free[self.n_free - len(live) : self.n_free][::-1].copy()
        self.n_free -= len(live)
        self.entries[slots, NODE] = live
        self.entries[slots, EDGE] = -1
        self.entries[slots, PARENT] = -1
        self.entries[slots, REFS] = 1
        self.entries[slots, TIME] = 0
        self.heads = np.full(N, -1, dtype=np.int64)
        self.heads[live] = slots
        self.level_count[:] = 0
        self.level_count[0] = len(live)
        self.converged_t = 0 if len(live) == 1 else -1
        self.peak_entries = self.live_entries

    def step(self, acc, position=None, heading=None, kinds_t=None, values_t=None):
        """Advance by one sample."""
        if self.n_free < self.N:
            self._grow()
        self.t += 1
        cost, rank, pos, head, best_edge, terms = self._scratch
        meas_acc = np.ascontiguousarray(acc, dtype=np.float64) / GRAVITY
        meas_pos = np.full(2, np.nan) if position is None else np.asarray(position, dtype=np.float64)
        meas_head = np.nan if heading is None else float(heading)
        if self.gamma:
            _satisfied(kinds_t, values_t, self.contact_code, self.label, self.ok)
        w = self.weights
        if w.acc:
            _edge_acc_costs(self.edge_acc, meas_acc, self.edge_cost_acc)
        _step(self.incoming, self.edge_src, self.edge_kind, self.edge_cost_acc, self.edge_offset, self.edge_heading,
              meas_pos, meas_head, float(w.acc), float(w.position), float(w.heading), self.ok, self.allowed,
              self.cost, self.rank, self.pos, self.head,
              cost, rank, pos, head, best_edge, terms, self.terms)  # fmt: skip
        if not np.any(best_edge >= 0):
            raise InputError(f"no graph path reaches sample {self.t}: every path ran into a dead end")
        if self.t >= len(self.level_count):
            self.level_count = np.concatenate([self.level_count, np.zeros_like(self.level_count)])
        self.n_free = _grow_tree(self.heads, best_edge, self.edge_src, self.entries, self.free, self.n_free, self.t,
                                 self.level_count)  # fmt: skip
        self.peak_entries = max(self.peak_entries, self.live_entries)
        while self.converged_t < self.t and self.level_count[self.converged_t + 1] == 1:
            self.converged_t += 1
        # Swap buffers: the new state becomes the previous one.
        self._scratch = (self.cost, self.rank, self.pos, self.head, best_edge, self.terms)
        self.cost, self.rank, self.pos, self.head, self.terms = cost, rank, pos, head, terms

    @property
    def alive(self) -> np.ndarray:
        return np.isfinite(self.cost)

    def best_node(self) -> int:
        """The live node whose path ranks first: fewest broken constraints, then cost
        (within TIE counts as equal), then fewer non-original edges, then lower node id."""
        alive = np.nonzero(self.alive)[0]
        cost = np.round(self.cost[alive] / TIE) if np.all(np.abs(self.cost[alive]) < 1e6) else self.cost[alive]
        keys = [alive, self.terms[alive, 3], cost] + [self.rank[alive, k] for k in range(self.gamma - 1, -1, -1)]
        return int(alive[np.lexsort(keys)[0]])

    def trace(self, node: int, since: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Nodes (t+1−since,) at samples since..t of the path ending at `node` now,
        and the edges (t−since,) arriving at samples since+1..t. Walks only as far back
        as `since`, so a fixed-lag trace costs the lag, not the input length."""
        nodes, edges = [], []
        slot = self.heads[node]
        while slot >= 0 and self.entries[slot, TIME] >= since:
            nodes.append(self.entries[slot, NODE])
            edges.append(self.entries[slot, EDGE])
            slot = self.entries[slot, PARENT]
        return np.array(nodes[::-1], dtype=np.int64), np.array(edges[::-1][1:], dtype=np.int64)

    def arrival_edge(self, node: int, sample: int) -> int:
        """The edge by which the path ending at `node` now arrived at sample `sample`
        (−1 at sample 0)."""
        slot = self.heads[node]
        while self.entries[slot, TIME] > sample:
            slot = self.entries[slot, PARENT]
        return int(self.entries[slot, EDGE])


def viterbi_search(graph: MotionGraph, acc: np.ndarray, position=None, heading=None, weights: Weights = Weights(),
                   constraint_sets: list | None = None, rate_hz: float | None = None,
                   allowed: np.ndarray | None = None) -> SearchResult:  # fmt: skip
    """Batch search. acc: (T, S, 3) m/s² in the graph's layout (NaN = missing);
    position: (T, 2) m or None; heading: (T,) rad or None; constraint_sets: see
    `compile_constraints` (times from sample index / graph rate); allowed: (N,) bool
    node mask or None."""
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
    search = ViterbiSearch(graph, weights, gamma, allowed)
    pos = (lambda t: None) if position is None else (lambda t: position[t])
    head = (lambda t: None) if heading is None else (lambda t: heading[t])
    search.start(pos(0), head(0), kinds[:, 0], values[:, 0])
    for t in range(1, T):
        search.step(acc[t], pos(t), head(t), kinds[:, t], values[:, t])
    best = search.best_node()
    nodes, edges = search.trace(best)
    N = graph.num_nodes
    terms = {"acc_g2": float(search.terms[best, 0]), "position_m": float(search.terms[best, 1]),
             "heading_rad": float(search.terms[best, 2])}  # fmt: skip
    return SearchResult(
        node_path=nodes, edge_path=edges, cost=float(search.cost[best]), terms=terms,
        broken=[int(v) for v in search.rank[best]],
        compression=float(N * T / max(search.peak_entries, 1)), peak_entries=int(search.peak_entries),
    )  # fmt: skip
