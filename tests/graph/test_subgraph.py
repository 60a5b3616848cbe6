"""`graph.model.node_subgraph` (the nodes kept, renumbered, and the edges among them) and
the Viterbi warm-up that runs on such a subgraph for a large graph read from a file."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.model import NODE_ARRAYS, node_subgraph
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.layout import load_layout


@pytest.fixture(scope="module")
def graph_file(tmp_path_factory):
    kb = generate_knowledge_base(seed=3, minutes=0.3)
    g, _ = build_graph(kb, BuildOptions(layout=load_layout("wrists-ankles"), progress=False))
    path = tmp_path_factory.mktemp("subgraph") / "g.graph"
    save_graph(g, path)
    return path


def test_the_subgraph_holds_the_kept_nodes_and_every_edge_among_them(graph_file, tmp_path):
    graph = load_graph(graph_file)
    rng = np.random.default_rng(0)
    nodes = np.sort(rng.choice(graph.num_nodes, graph.num_nodes // 3, replace=False))
    sub = node_subgraph(graph, np.r_[nodes[::-1], nodes[:5]])  # (any order, repeats)
    assert sub.num_nodes == nodes.size and sub.source_path is None
    for name in NODE_ARRAYS:
        np.testing.assert_array_equal(getattr(sub, name), getattr(graph, name)[nodes])
    # every edge of the graph between two kept nodes, renumbered, in the graph's order
    new = {int(n): i for i, n in enumerate(nodes)}
    src, dst = graph.edge_src, graph.edge_dst
    expected = [e for e in range(graph.num_edges) if int(src[e]) in new and int(dst[e]) in new]
    assert sub.num_edges == len(expected) > 0
    np.testing.assert_array_equal(sub.edge_src, [new[int(src[e])] for e in expected])
    np.testing.assert_array_equal(sub.edge_dst, [new[int(dst[e])] for e in expected])
    for name in ("edge_kind", "edge_acc", "edge_offset", "edge_heading", "edge_up"):
        np.testing.assert_array_equal(getattr(sub, name), getattr(graph, name)[expected])
    np.testing.assert_array_equal(np.diff(sub.incoming), np.bincount(sub.edge_dst, minlength=sub.num_nodes))
    # its segments and bridges lie wholly among the kept nodes, renumbered with them
    for part in [*sub.segments, *sub.bridges]:
        first = int(part["first_node"])
        assert int(nodes[first + int(part["count"]) - 1]) - int(nodes[first]) == int(part["count"]) - 1
    save_graph(sub, tmp_path / "sub.graph")  # (a whole graph: the file's checks pass)
    assert load_graph(tmp_path / "sub.graph").num_edges == sub.num_edges
    with pytest.raises(ValueError, match="node ids"):
        node_subgraph(graph, [graph.num_nodes])


def test_a_large_graph_warms_up_on_a_subgraph_and_streams_the_same(graph_file, monkeypatch):
    from graphsvc.strategies import open_session
    from graphsvc.strategies.options import Options
    from graphsvc.strategies.viterbi import strategy
    from graphsvc.strategies.viterbi.options import ViterbiOptions
    from graphsvc.strategies.viterbi.tables import search_index

    graph = load_graph(graph_file)
    subgraphs = []
    real = strategy.node_subgraph
    monkeypatch.setattr(strategy, "node_subgraph", lambda g, nodes: subgraphs.append(len(nodes)) or real(g, nodes))
    half = graph.num_nodes // 2
    monkeypatch.setattr(strategy, "WARM_UP_NODES", half)
    warmed_on = []
    warm = strategy._warm_up_on
    monkeypatch.setattr(strategy, "_warm_up_on", lambda g, threads: warmed_on.append(g.num_nodes) or warm(g, threads))
    strategy.warm_up(graph, threads=True)
    assert len(subgraphs) == 1 and subgraphs[0] >= half + 1  # (the first nodes, the busiest and its sources)
    assert warmed_on and warmed_on[0] < graph.num_nodes  # (on the subgraph, saved and mapped)
    index = search_index(graph)
    assert index.warmed == {True, False}  # (a batch search does not warm up again on the graph)
    assert {"search", "float32", "beam"} <= set(index._made)  # (the graph's own tables, made at load)
    # the warm-up changes no result: a stream on the graph matches one on a fresh copy
    rng = np.random.default_rng(1)
    S = len(graph.sensor_names)
    acc = rng.normal(0.0, 2.0, (90, S, 3))
    acc[:, :, 1] += 9.81
    options = Options(strategy="viterbi", latency_s=0.5, own=ViterbiOptions(beam=10.0, live_paths=64))
    frames = []
    for g in (graph, load_graph(graph_file)):
        session = open_session(g, options, keep_motion=False)
        out = [f for t in range(90) for f in session.push(t / g.rate_hz, acc[t])] + session.flush()
        frames.append([(f.node, f.rotations.tobytes()) for f in out])
    assert frames[0] == frames[1] and len(frames[0]) == 90
