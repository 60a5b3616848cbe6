"""The batch Viterbi search: a whole recording in one search, with its constraint
sets compiled, per-term costs summed along the path, and the warm-up that compiles the
kernels before a first client waits for them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from graphsvc.errors import InputError, SearchCancelled
from graphsvc.graph.model import MotionGraph
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.costs import _path_terms
from graphsvc.strategies.viterbi.search import ViterbiSearch
from graphsvc.strategies.viterbi.tables import search_index

REQ_NONE, REQ_CONTACT, REQ_LABEL = 0, 1, 2
CONTACT_CODES = {"none": 0, "left": 1, "right": 2, "both": 3}  # bit 0 left, bit 1 right


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


def compile_constraints(
    graph: MotionGraph, constraint_sets: list, times_s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
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
                    raise InputError(
                        f"constraint set {k}: unknown label {req['label']!r} (graph labels: {', '.join(graph.labels)})"
                    )
                kind, value = REQ_LABEL, graph.labels.index(req["label"])
            else:
                raise InputError(f"constraint set {k}: 'require' needs 'contact' or 'label'")
            span = (times_s >= start) & (times_s <= end)
            kinds[k, span] = kind
            values[k, span] = value
    return kinds, values


def path_terms(
    search: ViterbiSearch,
    nodes: np.ndarray,
    edges: np.ndarray,
    acc,
    position=None,
    heading=None,
    measured=None,
    up=None,
) -> dict:
    """The accelerometer (g²), position (m) and heading (rad) costs accumulated along a
    path found by `search` (unweighted; a term counts where the search used it), and
    in an oriented search the orientation cost (chord²), with the search's arithmetic
    (`costs._path_terms`). measured: `search.measurements(acc, up)`, when the caller
    has it already."""
    T = nodes.shape[0]
    if search.oriented:  # (each term alone: C_A by the accelerations' own mask, C_R by unit masks on the up axes)
        meas, mask, _ = search.measurements(acc[:T], None if up is None else up[:T]) if measured is None else measured
        _, a_mask, a_present = search.acc_measurements(acc[:T])
        D = a_mask.shape[1]
        r_mask = np.zeros_like(mask)
        r_mask[:, D:] = mask[:, D:] != 0
        terms = _terms(
            search,
            edges,
            meas,
            np.concatenate([a_mask, np.zeros_like(mask[:, D:])], axis=1),
            a_present,
            position,
            heading,
            T,
        )
        r_present = r_mask.sum(axis=1) / search.graph.edge_up.shape[-1]
        terms["orientation_chord2"] = _terms(search, edges, meas, r_mask, r_present, None, None, T)["acc_g2"]
        return terms
    meas, mask, present = search.measurements(acc[:T]) if measured is None else measured
    return _terms(search, edges, meas, mask, present, position, heading, T)


def _terms(search, edges, meas, mask, present, position, heading, T) -> dict:
    pos = np.full((T, 2), np.nan) if position is None else np.asarray(position, dtype=np.float64)
    head = np.full(T, np.nan) if heading is None else np.asarray(heading, dtype=np.float64)
    p0, h0 = search.start_placement
    w = search.weights
    out = _path_terms(
        edges.astype(np.int64),
        search.readings_t,
        search.edge_reading,
        search.edge_offset,
        search.edge_heading,
        search.edge_turn,
        meas,
        mask,
        present,
        pos,
        head,
        w.position != 0,
        w.heading != 0,
        float(p0[0]),
        float(p0[1]),
        h0,
        np.cos(h0),
        np.sin(h0),
        search.pull_alpha,
    )
    return {"acc_g2": float(out[0]), "position_m": float(out[1]), "heading_rad": float(out[2])}


def orientation_counts(graph: MotionGraph, weights: Weights, up=None) -> bool:
    """Whether the orientation term can count: W_R > 0, some measured orientation cue
    (T, S, W) finite, and the graph has orientation metadata (`graph.edge_up`)."""
    return bool(
        up is not None
        and weights.orientation > 0
        and graph.edge_up is not None
        and np.isfinite(np.asarray(up)).all(axis=-1).any()
    )


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
    samples) or first meets constraints. threads=True warms the serial kernels too: a
    search that may use the threads runs serial steps where they are faster
    (`strategies.threads.StepTimer`)."""
    warmed = search_index(graph).warmed
    for mode in (True, False) if threads else (False,):
        if mode not in warmed:  # (a mode warmed already, e.g. the serial one by a caller, is not run again)
            _warm_up(graph, mode)
            warmed.add(mode)


def _warm_up(graph: MotionGraph, threads: bool) -> None:
    rng = np.random.default_rng(0)
    T = 16
    acc = rng.normal(0.0, 9.81, (T, len(graph.sensor_names), 3))
    position = np.cumsum(rng.normal(0.0, 0.02, (T, 2)), axis=0)
    free = np.zeros(1, np.int64)
    placed, unplaced = Weights(0.5, 1, 1), Weights(1, 0, 0)
    for window, gamma, weights, beam in (
        (None, 0, placed, None),
        (2, 0, placed, None),
        (None, 0, unplaced, None),
        (None, 1, placed, None),
        (2, 0, placed, 1e-6),
    ):
        search = ViterbiSearch(graph, weights, gamma, threads=threads, window=window, ring=(4, 2), beam=beam)
        search.start(position[0], 0.0, free[:gamma], free[:gamma])
        for t in range(1, T):
            search.step(acc[t], position[t], 0.0, free[:gamma], free[:gamma])
        search.trace(search.best_node(), since=search.t - 1)
    for weights, pos, head in ((placed, position, np.zeros(T)), (unplaced, None, None)):  # batch C_A, path terms
        viterbi_search(graph, acc, pos, head, weights, threads=threads)


def warm_up_search_once(graph: MotionGraph, threads: bool = True) -> float:
    """`warm_up_search` unless it has run for this graph and thread mode in this
    process (a server warms up at load). Returns the seconds it took, 0.0 if it had run."""
    if bool(threads) in search_index(graph).warmed:
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


def viterbi_search(
    graph: MotionGraph,
    acc: np.ndarray,
    position=None,
    heading=None,
    weights: Weights = Weights(),
    constraint_sets: list | None = None,
    rate_hz: float | None = None,
    allowed: np.ndarray | None = None,
    threads: bool = True,
    should_stop=None,
    beam: float | None = None,
    start: tuple | None = None,
    pull_s: float | None = None,
    up: np.ndarray | None = None,
) -> SearchResult:
    """Batch search. acc: (T, S, 3) m/s² in the graph's layout (NaN = missing);
    position: (T, 2) m or None; heading: (T,) rad or None; constraint_sets: see
    `compile_constraints` (times from sample index / graph rate); allowed: (N,) bool
    node mask or None; threads: see ViterbiSearch; should_stop: a callable polled
    every READING_BATCH (16) samples — when it returns true the search raises SearchCancelled (a
    server stops work for a client that went away); beam: see ViterbiSearch. start:
    (ground position (2,) m or None, heading rad or None), where every path starts
    (`strategies.base.start_placement`); None: at the first measured position and
    heading (see `ViterbiSearch.start`). pull_s: see ViterbiSearch. up: (T, S, W)
    the sensors' measured orientation cue (`sensors.orientation.orientation_cue` of the
    recording's orientations, of the graph's width; NaN = missing), weighed by W_R where the graph has orientation
    metadata (`orientation_counts`); None: no orientation term."""
    acc = np.asarray(acc)
    T = acc.shape[0]
    if T == 0:
        raise InputError("the input has no samples")
    if acc.ndim != 3 or acc.shape[1:] != (len(graph.sensor_names), 3):
        raise InputError(
            f"accelerations must be (samples, {len(graph.sensor_names)}, 3) for the graph's layout, got {acc.shape}"
        )
    constraint_sets = constraint_sets or []
    gamma = len(constraint_sets)
    times = np.arange(T) / (rate_hz or graph.rate_hz)
    kinds, values = compile_constraints(graph, constraint_sets, times)
    oriented = orientation_counts(graph, weights, up)
    search = ViterbiSearch(
        graph,
        weights,
        gamma,
        allowed,
        threads,
        needs_placement(weights, position, heading),
        ring=batch_ring(T),
        beam=beam,
        pull_s=pull_s,
        oriented=oriented,
    )
    up = up if oriented else None
    pos = (lambda t: None) if position is None else (lambda t: position[t])
    head = (lambda t: None) if heading is None else (lambda t: heading[t])
    if start is None:
        search.start(pos(0), head(0), kinds[:, 0], values[:, 0])
    else:
        search.start(start[0], start[1], kinds[:, 0], values[:, 0])
    measured = search.measurements(acc, up)  # once: the C_A batches and the path's terms share it
    for t0 in range(1, T, READING_BATCH):
        if should_stop is not None and should_stop():
            raise SearchCancelled(f"search stopped at sample {t0} of {T}")
        block = slice(t0, t0 + READING_BATCH)
        # (a beam search's sparse steps compute only the readings they read)
        costs = None if search.narrow else search.reading_costs(acc[block], tuple(m[block] for m in measured))
        for t in range(t0, min(T, t0 + READING_BATCH)):
            search.step(
                acc[t],
                pos(t),
                head(t),
                kinds[:, t],
                values[:, t],
                None if costs is None else costs[t - t0],
                None if up is None else up[t],
            )
    best = search.best_node()
    nodes, edges = search.trace(best)
    terms = path_terms(search, nodes, edges, acc, position, heading, measured, up)
    return SearchResult(
        node_path=nodes,
        edge_path=edges,
        cost=float(search.cost[best]),
        terms=terms,
        broken=[int(v) for v in search.rank[best]],
        compression=float(search.compression),
        peak_entries=int(search.peak_entries),
    )
