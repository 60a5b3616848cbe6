"""Connectivity report against a plain breadth-first search, on a procedural knowledge
base of walking, running, standing and punching."""

from collections import deque

import numpy as np
import pytest

from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.connectivity import connectivity, format_connectivity, label_distances, worst_reach
from graphsvc.motion.procedural import make_clip, standard_skeleton
from graphsvc.sensors.layout import PRESETS

KINDS = ("walk", "run", "idle", "punch")


def mixed_kb(seed: int, clips_per_kind: int = 2, seconds: float = 6.0):
    rng = np.random.default_rng(seed)
    sk = standard_skeleton()
    return [
        make_clip(kind, rng, sk, 30.0, seconds, f"{kind}_{k:02d}", seed)
        for kind in KINDS
        for k in range(clips_per_kind)
    ]


@pytest.fixture(scope="module")
def graphs():
    kb = mixed_kb(5)
    options = BuildOptions(layout=PRESETS["wrists-ankles"], progress=False)
    with_bridges, _ = build_graph(kb, options)
    without, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False, bridges=False))
    return with_bridges, without


def _bfs_hops(graph, targets: np.ndarray) -> np.ndarray:
    """Fewest edges from every node to any node of `targets`, by a plain BFS over the
    reversed edges."""
    into = [[] for _ in range(graph.num_nodes)]
    for s, d in zip(graph.edge_src.tolist(), graph.edge_dst.tolist()):
        into[d].append(s)
    hops = np.full(graph.num_nodes, np.inf)
    queue = deque(int(t) for t in targets)
    hops[targets] = 0
    while queue:
        n = queue.popleft()
        for m in into[n]:
            if hops[m] == np.inf:
                hops[m] = hops[n] + 1
                queue.append(m)
    return hops


def _bfs_reach(graph, start: int) -> np.ndarray:
    out = [[] for _ in range(graph.num_nodes)]
    for s, d in zip(graph.edge_src.tolist(), graph.edge_dst.tolist()):
        out[s].append(d)
    seen = np.zeros(graph.num_nodes, dtype=bool)
    seen[start] = True
    queue = deque([start])
    while queue:
        for m in out[queue.popleft()]:
            if not seen[m]:
                seen[m] = True
                queue.append(m)
    return seen


def test_every_ordered_label_pair_is_reachable_with_bridges(graphs):
    g, _ = graphs
    report = connectivity(g)
    assert set(report["reach"]) == set(KINDS)
    for a, row in report["reach"].items():
        assert set(row) == set(KINDS) - {a}
        for b, r in row.items():
            assert r["shortest_s"] is not None and r["typical_s"] is not None, (a, b)
    assert worst_reach(report)[0] <= 3.0
    assert report["largest_share"] >= 0.95


def test_without_bridges_actions_stay_apart(graphs):
    """The plain contact-change transitions leave some label pair unreachable — what
    the bridges are for (the baseline this module's fixture contrasts)."""
    _, plain = graphs
    report = connectivity(plain)
    assert report["largest_share"] < connectivity(graphs[0])["largest_share"]
    assert any(r["typical_s"] is None for row in report["reach"].values() for r in row.values())


@pytest.mark.parametrize("which", [0, 1])
def test_report_matches_a_plain_breadth_first_search(graphs, which):
    g = graphs[which]
    report = connectivity(g)
    hops = label_distances(g)
    for b, name in enumerate(g.labels):
        expect = _bfs_hops(g, np.flatnonzero(g.node_label == b))
        np.testing.assert_array_equal(hops[b], expect)
        for a, other in enumerate(g.labels):
            if a == b:
                continue
            d = expect[g.node_label == a]
            r = report["reach"][other][name]
            want_min = d.min() / g.rate_hz
            want_med = np.median(d) / g.rate_hz
            assert (r["shortest_s"] is None) == (not np.isfinite(want_min))
            if r["shortest_s"] is not None:
                assert r["shortest_s"] == pytest.approx(want_min, abs=1e-3)
            assert (r["typical_s"] is None) == (not np.isfinite(want_med))
            if r["typical_s"] is not None:
                assert r["typical_s"] == pytest.approx(want_med, abs=1e-3)
    # The largest component: a node of it reaches exactly the nodes that reach it back.
    rng = np.random.default_rng(0)
    members = None
    for start in rng.choice(g.num_nodes, 5, replace=False):
        forward = _bfs_reach(g, int(start))
        backward = np.isfinite(_bfs_hops(g, np.array([start])))
        component = forward & backward
        if members is None or component.sum() > members.sum():
            members = component
    assert report["largest_nodes"] == members.sum()  # (five random starts: one lies in the ≥ 95 % component)
    assert report["nodes"] == g.num_nodes
    assert report["outside_largest_nodes"] == g.num_nodes - report["largest_nodes"]


def test_report_respects_a_node_mask(graphs):
    g, _ = graphs
    allowed = np.ones(g.num_nodes, dtype=bool)
    allowed[g.node_label == g.labels.index("run")] = False
    report = connectivity(g, allowed)
    assert report["nodes"] == int(allowed.sum())
    assert "run" not in report["reach"]


def test_format_lists_the_table(graphs):
    text = format_connectivity(connectivity(graphs[0]))
    assert "largest strongly connected component" in text
    for k, name in enumerate(sorted(KINDS)):
        assert f"{k + 1:>2d} {name}" in text


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_label_hops_match_scipy_shortest_paths_on_random_graphs(seed):
    """The breadth-first search against scipy's unweighted shortest paths, and the
    label-by-label reduction against the median and minimum of the full matrix, on
    random sparse graphs with a node mask, self loops and repeated edges."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    from graphsvc.graph.connectivity import label_hops, label_reach

    rng = np.random.default_rng(seed)
    N, E, L = 400, 700, 5
    src, dst = rng.integers(0, N, E), rng.integers(0, N, E)
    src[:20] = dst[:20]
    src[20:40], dst[20:40] = src[40:60], dst[40:60]
    labels = rng.integers(0, L, N)
    labels[labels == 3] = 2  # label 3 has no node
    allowed = rng.random(N) > 0.1
    hops = label_hops(src, dst, labels, L, allowed)
    keep = allowed[src] & allowed[dst]
    reverse = csr_matrix((np.ones(int(keep.sum())), (dst[keep], src[keep])), shape=(N, N))
    for b in range(L):
        sources = np.flatnonzero((labels == b) & allowed)
        want = np.full(N, np.inf)
        if sources.size:
            want = dijkstra(reverse, directed=True, indices=sources, unweighted=True, min_only=True)
        want[~allowed] = np.inf
        np.testing.assert_array_equal(hops[b], want)
    shortest, typical = label_reach(src, dst, labels, L, allowed)
    for a in range(L):
        nodes = (labels == a) & allowed
        for b in range(L):
            if not nodes.any() or b == 3:
                assert np.isnan(shortest[a, b]) and np.isnan(typical[a, b])
                continue
            assert shortest[a, b] == hops[b, nodes].min()
            assert typical[a, b] == np.median(hops[b, nodes].astype(np.float64))
    assert np.isnan(typical[3]).all()
    assert np.isfinite(typical[0, 1]) and typical[0, 1] > 0
