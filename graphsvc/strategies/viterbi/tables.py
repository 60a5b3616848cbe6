"""The motion graph's arrays in the Viterbi search's layouts: a search index.

`SearchIndex` holds, for one graph, what the search reads: the compact edge arrays
and the distinct readings (`search_tables`), the slot-major tables of the float64
passes (`slot_tables`, made for constrained searches), those of the float32 pass
(`float32_tables`) and a beam step's successors and row-major readings
(`beam_tables`), each made on first use. `search_index(graph)` is the index of a graph
in this process (made once, dropped with the graph; `graph.derived`); the Viterbi
strategy prepares it at load. A graph read from a file has its tables written beside
it once (`strategies.index.cached_arrays`: `GRAPH.viterbi-search.index` and the like,
keyed by the graph's checksum) and memory-mapped on every later load, so a server's
processes share one copy of their pages: on a 9.3M-node graph the tables are 2.3 GB
and took about two minutes to make and write; on a 263k-node one, 70 MB and 0.4 s.
"""

from __future__ import annotations

import threading
import weakref

import numpy as np

from graphsvc.errors import InputError
from graphsvc.graph.derived import derived
from graphsvc.graph.model import MotionGraph, incoming_offsets
from graphsvc.graph.rows import distinct_rows
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.index import cached_arrays

# The tables' layout version in their cache files beside a graph: raise it when a
# table's contents or layout change, so older caches are made again.
TABLES_VERSION = 1
BEAM_KEYS = ("out_start", "out_dst", "readings")


def _make_search_tables(graph: MotionGraph, oriented: bool = False) -> dict:
    """The graph's arrays in the search's layout (`SearchIndex.tables`). Each node's shared reading is the distinct reading most of its incoming edges
    read (the first-met among equals; on built graphs the node's own frame: 79–86 % of
    the edges read their destination's), and those edges are its shared ones. Nodes
    are laid out (node_pos (N,) uint32 each node's position) in SELECT_CHUNKS chunks
    of consecutive ids (`_chunks`), within a chunk by descending count of
    shared edges, then id. The readings, transposed (3S, R) float32 in g: column p the
    shared reading of the node at layout position p (zeros for a node without
    incoming edges), then the readings only other edges read (distinct, in order of
    first use), so the float32 pass reads its shared edges' C_A in layout order, not
    scattered; edge_reading (E,) int32 each edge's column; edge_shared (E,) bool.
    Compact edge arrays. oriented: each reading is followed by the edge's sensor "up"
    vectors (`graph.edge_up`), a reading (6S,) — the orientation term rides in the C_A
    kernels as 3S more axes (`costs`)."""
    N, E = graph.num_nodes, graph.num_edges
    flat = np.ascontiguousarray(graph.edge_acc, dtype=np.float32).reshape(E, -1)
    D = flat.shape[1]
    if oriented:
        flat = np.concatenate([flat, np.asarray(graph.edge_up, dtype=np.float32).reshape(E, -1)], axis=1)
    first_edge, distinct = distinct_rows(flat)
    in_g = flat[first_edge]
    in_g[:, :D] = (in_g[:, :D].astype(np.float64) / GRAVITY).astype(np.float32)
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
        "edge_turn": np.ascontiguousarray(
            np.stack(
                [np.cos(graph.edge_heading.astype(np.float64)), np.sin(graph.edge_heading.astype(np.float64))], axis=-1
            )
        ),
    }
    return tables


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


def _make_slot_tables(graph: MotionGraph, tables: dict) -> dict:
    """For the float64 passes (constrained searches; `SearchIndex.slots`): the per-edge arrays the edge and select passes read, permuted into
    slot-major order within chunks of nodes: chunk c's edges, first every node's first
    incoming edge, then every second one, … Within a chunk nodes are laid out by
    descending in-degree (then id), so slot j holds the chunk's first count_j layout
    positions in order. chunk_nodes (C+1,) node bounds; chunk_slots (C, D+1) where
    chunk c's slot j lies; slot_dst (E,) each entry's node; slot_edge (E,) graph edge
    id."""
    N, E = graph.num_nodes, graph.num_edges
    degree = np.diff(tables["incoming"]).astype(np.int64)
    dst, slot = _arrivals(graph, tables["incoming"])
    D = int(slot.max()) + 1 if E else 1
    chunk_nodes, node_chunk = _chunks(N)
    node_pos = _layout(node_chunk, degree)
    order, chunk_slots = _slot_major(dst, slot, node_chunk, node_pos, D)
    return {
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


def _make_float32_tables(graph: MotionGraph, tables: dict) -> dict:
    """For the float32 pass (`dense._approx_select_py`; `SearchIndex.float32`), in
    `search_tables`' node layout. Shared edges in slot-major order within chunks
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
    return {
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


def _make_beam_tables(graph: MotionGraph, tables: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a beam step reads besides `search_tables` (`SearchIndex.beam`): each node's successors, out_start
    (N+1,) int64 and out_dst (E,) int32 (node m's at out_dst[out_start[m]:out_start[m+1]],
    in edge order), and the readings row by row, (R, 3S) float32 in g (the transpose of
    readings_t: a step computes C_A reading by reading; 25 MB on the 268k-node kelly6
    graph, plus 4 MB of successors)."""
    src = np.asarray(graph.edge_src, dtype=np.int64)
    order = np.argsort(src, kind="stable")
    out_start = incoming_offsets(src, graph.num_nodes)  # (the same offsets, by source)
    readings = np.ascontiguousarray(tables["readings_t"].T)
    return out_start, np.ascontiguousarray(graph.edge_dst[order], dtype=np.int32), readings


class SearchIndex:
    """One graph's tables in the search's layouts (module docstring), each made on
    first use and then shared by every search on the graph, from any thread. Holds the
    graph weakly: the index lives as long as the graph does.

    warmed: the thread modes (True: threaded kernels) `batch.warm_up_search` has run
    for on this graph in this process."""

    def __init__(self, graph: MotionGraph, oriented: bool = False):
        self._graph = weakref.ref(graph)
        self.oriented = bool(oriented)
        self._lock = threading.RLock()
        self._made: dict[str, object] = {}
        self.warmed: set[bool] = set()

    @property
    def graph(self) -> MotionGraph:
        graph = self._graph()
        if graph is None:
            raise RuntimeError("the graph of this search index is gone")
        return graph

    def _table(self, name: str, make) -> dict:
        """Table `name` (a dict of arrays): made by make() on first use in this
        process, or mapped from the graph's cache file (module docstring)."""
        with self._lock:
            if name not in self._made:
                key = f"viterbi-{name}" + ("-oriented" if self.oriented else "")
                self._made[name] = {
                    k: _read_only(a) for k, a in cached_arrays(self.graph, key, TABLES_VERSION, make).items()
                }
            return self._made[name]

    @property
    def tables(self) -> dict:
        """Compact edge arrays and the distinct readings (`_make_search_tables`)."""
        return self._table("search", lambda: _make_search_tables(self.graph, self.oriented))

    @property
    def slots(self) -> dict:
        """The float64 passes' slot-major tables (`_make_slot_tables`)."""
        return self._table("slots", lambda: _make_slot_tables(self.graph, self.tables))

    @property
    def float32(self) -> dict:
        """The float32 pass's tables (`_make_float32_tables`)."""
        return self._table("float32", lambda: _make_float32_tables(self.graph, self.tables))

    @property
    def beam(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A beam step's successors and row-major readings (`_make_beam_tables`)."""
        beam = self._table("beam", lambda: dict(zip(BEAM_KEYS, _make_beam_tables(self.graph, self.tables))))
        return tuple(beam[k] for k in BEAM_KEYS)


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of a table: mapped from a cache file they are read-only anyway,
    and numba compiles a kernel once for each argument type, so tables made in memory
    (a graph built, never saved) are read-only too and share the mapped ones' kernels
    (one compilation on a fresh install, not two). Nothing writes into a table."""
    if not a.flags.writeable:
        return a
    view = a.view()
    view.flags.writeable = False
    return view


def search_index(graph: MotionGraph, oriented: bool = False) -> SearchIndex:
    """The graph's search index in this process (`graph.derived`: made on first use,
    dropped with the graph; a copy of the graph gets its own). oriented: the index
    whose readings carry the edges' sensor "up" vectors too (searches that weigh
    measured orientations; the graph must have them, `graph.edge_up`)."""
    if oriented:
        if graph.edge_up is None:
            raise InputError("the graph has no sensor orientation metadata (rebuild it or run `graphsvc relayout`)")
        return derived(graph, "viterbi.search_index.oriented", lambda: SearchIndex(graph, True))
    return derived(graph, "viterbi.search_index", lambda: SearchIndex(graph))


def search_tables(graph: MotionGraph) -> dict:
    """`SearchIndex.tables` of the graph's index."""
    return search_index(graph).tables


def slot_tables(graph: MotionGraph) -> dict:
    """`SearchIndex.slots` of the graph's index."""
    return search_index(graph).slots


def float32_tables(graph: MotionGraph) -> dict:
    """`SearchIndex.float32` of the graph's index."""
    return search_index(graph).float32


def beam_tables(graph: MotionGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`SearchIndex.beam` of the graph's index."""
    return search_index(graph).beam
