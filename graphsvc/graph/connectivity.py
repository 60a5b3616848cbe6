"""How well a motion graph connects its actions: a search can only follow what the graph connects.

A search can only follow a performance from one action to another if the graph has a
path there, and a live one only if that path is short. Three measures:

- strongly connected components (`scipy.sparse.csgraph`): the share of nodes in the
  largest one (from any of its nodes every other is reachable and back), and the
  other components, the *islands*: dead-end chains, clips nothing enters, actions
  that cannot be left;
- per ordered pair of content labels (A, B), the time from a node of A to the
  nearest node of B: every edge plays one sample, so a path of h edges lasts
  h / rate seconds. `shortest_s` is the minimum over A's nodes (whether B can be
  reached at all), `typical_s` the median over A's nodes (how long a performance
  that is doing A needs to get to B; infinite when more than half of A's nodes
  cannot reach B). One multi-source breadth-first search per label B over the
  reversed edges gives every node's distance to B at once.

Nodes outside `allowed` (a leave-one-out mask) and their edges are left out.
"""

from __future__ import annotations

import numba
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from graphsvc.graph.model import MotionGraph

ISLANDS_LISTED = 8  # the largest islands named in a report (all are counted)


def _adjacency(graph: MotionGraph, allowed: np.ndarray | None) -> csr_matrix:
    src = np.asarray(graph.edge_src, dtype=np.int64)
    dst = np.asarray(graph.edge_dst, dtype=np.int64)
    if allowed is not None:
        keep = allowed[src] & allowed[dst]
        src, dst = src[keep], dst[keep]
    N = graph.num_nodes
    return csr_matrix((np.ones(src.shape[0], dtype=np.float32), (src, dst)), shape=(N, N))


def strong_components(graph: MotionGraph, allowed: np.ndarray | None = None) -> tuple[int, np.ndarray]:
    """(number of components, (N,) component of each node); nodes outside `allowed`
    are components of their own."""
    return connected_components(_adjacency(graph, allowed), directed=True, connection="strong")


def label_distances(graph: MotionGraph, allowed: np.ndarray | None = None) -> np.ndarray:
    """(L, N) float32: for each label B and node v, the fewest edges from v to a node of
    B (0 on B's own nodes, inf where none is reachable or v is not allowed)."""
    return label_hops(graph.edge_src, graph.edge_dst, graph.node_label, len(graph.labels), allowed)


def label_hops(
    src: np.ndarray, dst: np.ndarray, node_label: np.ndarray, num_labels: int, allowed: np.ndarray | None = None
) -> np.ndarray:
    """`label_distances` of any edge list (E,) over N = len(node_label) nodes."""
    out = np.full((num_labels, np.asarray(node_label).shape[0]), np.inf, dtype=np.float32)
    for b, hops in _each_label(src, dst, node_label, num_labels, allowed):
        out[b] = hops
    return out


def label_reach(
    src: np.ndarray, dst: np.ndarray, node_label: np.ndarray, num_labels: int, allowed: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(shortest, typical), each (L, L) in edges: row A, column B the minimum and the
    median over A's allowed nodes of their fewest edges to a node of B (inf where
    unreachable; NaN for a label without allowed nodes). The same figures as reducing
    `label_hops`, label by label, without its (L, N) matrix."""
    labels = np.asarray(node_label)
    ok = np.ones(labels.shape[0], dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    nodes = np.flatnonzero(ok)
    order = nodes[np.argsort(labels[nodes], kind="stable")]
    bounds = np.searchsorted(labels[order], np.arange(num_labels + 1))
    shortest = np.full((num_labels, num_labels), np.nan)
    typical = np.full((num_labels, num_labels), np.nan)
    for b, hops in _each_label(src, dst, labels, num_labels, ok):
        grouped = hops[order]
        for a in range(num_labels):
            d = grouped[bounds[a] : bounds[a + 1]]
            if d.size:
                shortest[a, b], typical[a, b] = float(d.min()), float(np.median(d))
    return shortest, typical


def _each_label(src, dst, node_label, num_labels: int, allowed):
    """(b, (N,) float32 hops to label b) for every label with an allowed node, others
    skipped: one multi-source breadth-first search a label over the reversed edges
    (compressed rows of each node's predecessors), O(N + E) each."""
    labels = np.asarray(node_label)
    N = labels.shape[0]
    src, dst = np.asarray(src, dtype=np.int64), np.asarray(dst, dtype=np.int64)
    ok = np.ones(N, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    keep = ok[src] & ok[dst]
    src, dst = src[keep], dst[keep]
    order = np.argsort(dst, kind="stable")
    predecessors = src[order].astype(np.int32)
    indptr = np.zeros(N + 1, dtype=np.int64)
    np.cumsum(np.bincount(dst, minlength=N), out=indptr[1:])
    del src, dst, order, keep
    hops = np.empty(N, dtype=np.int32)
    queue = np.empty(N, dtype=np.int32)
    for b in range(num_labels):
        sources = np.flatnonzero((labels == b) & ok).astype(np.int32)
        if not sources.size:
            continue
        _multi_source_bfs(indptr, predecessors, sources, hops, queue)
        out = hops.astype(np.float32)
        out[hops < 0] = np.inf
        yield b, out


@numba.njit(cache=True, nogil=True)
def _multi_source_bfs(indptr, neighbours, sources, hops, queue):  # pragma: no cover - compiled
    """hops[v]: fewest edges from any source to v along `neighbours` (CSR), −1 where
    none reaches; `queue` is scratch of N entries."""
    hops[:] = -1
    tail = 0
    for s in sources:
        if hops[s] < 0:
            hops[s] = 0
            queue[tail] = s
            tail += 1
    head = 0
    while head < tail:
        v = queue[head]
        head += 1
        h = hops[v] + 1
        for k in range(indptr[v], indptr[v + 1]):
            u = neighbours[k]
            if hops[u] < 0:
                hops[u] = h
                queue[tail] = u
                tail += 1


def connectivity(graph: MotionGraph, allowed: np.ndarray | None = None) -> dict:
    """JSON-ready connectivity report (module docstring): nodes counted, components,
    largest_share, islands (the largest few: nodes and nodes per label), and reach:
    {A: {B: {"shortest_s", "typical_s"}}} for every ordered pair of labels present,
    None where B cannot be reached."""
    ok = np.ones(graph.num_nodes, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    count, component = strong_components(graph, ok)
    component = component[ok]
    sizes = np.bincount(component, minlength=count)
    largest = int(np.argmax(sizes)) if sizes.size else 0
    labels = np.asarray(graph.node_label)[ok]
    order = [int(c) for c in np.argsort(-sizes, kind="stable") if c != largest and sizes[c] > 0]
    islands = []
    for c in order[:ISLANDS_LISTED]:
        present = np.bincount(labels[component == c], minlength=len(graph.labels))
        islands.append(
            {"nodes": int(sizes[c]), "labels": {graph.labels[k]: int(n) for k, n in enumerate(present) if n}}
        )
    total = int(ok.sum())
    rate = float(graph.rate_hz)
    shortest, typical = label_reach(graph.edge_src, graph.edge_dst, graph.node_label, len(graph.labels), ok)
    present_labels = [k for k in range(len(graph.labels)) if np.any(labels == k)]
    reach: dict = {}
    for a in present_labels:
        row = {}
        for b in present_labels:
            if a == b:
                continue
            low, mid = shortest[a, b], typical[a, b]
            row[graph.labels[b]] = {
                "shortest_s": round(float(low) / rate, 3) if np.isfinite(low) else None,
                "typical_s": round(float(mid) / rate, 3) if np.isfinite(mid) else None,
            }
        reach[graph.labels[a]] = row
    return {
        "nodes": total,
        "components": int(np.count_nonzero(sizes)),
        "largest_nodes": int(sizes[largest]) if sizes.size else 0,
        "largest_share": round(float(sizes[largest]) / total, 4) if total else 0.0,
        "outside_largest_nodes": int(total - (sizes[largest] if sizes.size else 0)),
        "islands": islands,
        "reach": reach,
    }


def worst_reach(report: dict) -> tuple[float, str, str] | None:
    """The slowest typical time over all ordered label pairs, (seconds, A, B); inf
    when some pair is unreachable for most of A's nodes; None with fewer than 2 labels."""
    worst = None
    for a, row in report["reach"].items():
        for b, r in row.items():
            t = np.inf if r["typical_s"] is None else r["typical_s"]
            if worst is None or t > worst[0]:
                worst = (t, a, b)
    return worst


def format_connectivity(report: dict) -> str:
    """A few lines for `graphsvc info` and `build`: the largest component, the islands
    and a label × label table of typical times (s; '-' where unreachable)."""
    lines = [
        f"connectivity: largest strongly connected component {100 * report['largest_share']:.1f} % of "
        f"{report['nodes']:,} nodes; {report['components'] - 1:,} other components "
        f"({report['outside_largest_nodes']:,} nodes)"
    ]
    for isl in report["islands"][:3]:
        names = ", ".join(f"{k} {v:,}" for k, v in sorted(isl["labels"].items(), key=lambda kv: -kv[1])[:3])
        lines.append(f"  island of {isl['nodes']:,} nodes ({names})")
    labels = list(report["reach"])
    if len(labels) >= 2:
        worst = worst_reach(report)
        where = "unreachable" if not np.isfinite(worst[0]) else f"{worst[0]:.2f} s"
        lines.append(
            f"reach from a typical node of each label (row) to the nearest of another (column), s; "
            f"slowest {worst[1]} → {worst[2]}: {where}"
        )
        width = max(len(lab) for lab in labels)
        lines.append(" " * (width + 4) + "".join(f"{k + 1:>6d}" for k in range(len(labels))))
        for i, a in enumerate(labels):
            cells = []
            for b in labels:
                if a == b:
                    cells.append(f"{'·':>6s}")
                    continue
                t = report["reach"][a][b]["typical_s"]
                cells.append(f"{'-':>6s}" if t is None else f"{t:6.2f}")
            lines.append(f"{i + 1:>2d} {a:<{width}s}  " + "".join(cells))
    return "\n".join(lines)
