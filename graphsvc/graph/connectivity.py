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

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components, dijkstra

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
    """(L, N) float: for each label B and node v, the fewest edges from v to a node of
    B (0 on B's own nodes, inf where none is reachable or v is not allowed)."""
    return label_hops(graph.edge_src, graph.edge_dst, graph.node_label, len(graph.labels), allowed)


def label_hops(
    src: np.ndarray, dst: np.ndarray, node_label: np.ndarray, num_labels: int, allowed: np.ndarray | None = None
) -> np.ndarray:
    """`label_distances` of any edge list (E,) over N = len(node_label) nodes."""
    N = node_label.shape[0]
    src, dst = np.asarray(src, dtype=np.int64), np.asarray(dst, dtype=np.int64)
    ok = np.ones(N, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    keep = ok[src] & ok[dst]
    reverse = csr_matrix((np.ones(int(keep.sum()), dtype=np.float32), (dst[keep], src[keep])), shape=(N, N))
    labels = np.asarray(node_label)
    out = np.full((num_labels, N), np.inf)
    for b in range(num_labels):
        sources = np.flatnonzero((labels == b) & ok)
        if sources.size:
            out[b] = dijkstra(reverse, directed=True, indices=sources, unweighted=True, min_only=True)
    out[:, ~ok] = np.inf
    return out


def typical_times(hops: np.ndarray, node_label: np.ndarray, rate_hz: float) -> np.ndarray:
    """(L, L) seconds: row A, column B the median over A's nodes of `label_hops`' B
    row, over the rate (inf when most of A's nodes cannot reach B; NaN for a label
    without nodes)."""
    L = hops.shape[0]
    out = np.full((L, L), np.nan)
    for a in range(L):
        nodes = node_label == a
        if nodes.any():
            out[a] = np.median(hops[:, nodes], axis=1) / rate_hz
    return out


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
    hops = label_distances(graph, ok)
    rate = float(graph.rate_hz)
    present_labels = [k for k in range(len(graph.labels)) if np.any(labels == k)]
    reach: dict = {}
    for a in present_labels:
        row = {}
        nodes_a = ok & (np.asarray(graph.node_label) == a)
        for b in present_labels:
            if a == b:
                continue
            d = hops[b, nodes_a]
            shortest, typical = float(d.min()), float(np.median(d))
            row[graph.labels[b]] = {
                "shortest_s": round(shortest / rate, 3) if np.isfinite(shortest) else None,
                "typical_s": round(typical / rate, 3) if np.isfinite(typical) else None,
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
