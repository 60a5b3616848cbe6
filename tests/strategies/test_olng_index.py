"""The OLNG index (graphsvc/strategies/olng/index.py) on a small procedural graph."""

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.strategies.olng.index import OlngIndex, build_arrays


@pytest.fixture(scope="module")
def graph():
    g, _ = build_graph(generate_knowledge_base(seed=5, minutes=0.4), BuildOptions(interp=False, progress=False))
    return g


def test_frames_are_original_nodes_in_runs_of_consecutive_frames(graph):
    a = build_arrays(graph)
    nodes, run = a["nodes"], a["run_of"]
    assert (graph.node_kind[nodes] == 0).all() and np.all(np.diff(nodes) > 0)
    same = run[1:] == run[:-1]
    # Within a run: the same clip, one frame apart; a clip's first frame has no reading.
    assert (graph.node_clip[nodes[1:]][same] == graph.node_clip[nodes[:-1]][same]).all()
    np.testing.assert_array_equal(graph.node_frame[nodes[1:]][same] - graph.node_frame[nodes[:-1]][same], 1.0)
    assert run[-1] + 1 == len(graph.clips)  # (one run a clip here: no frame left out)
    stored = graph.edge_acc[a["edges"]].astype(np.float64)
    np.testing.assert_allclose(a["readings"], stored.reshape(nodes.size, -1) / GRAVITY, rtol=1e-6)


def test_query_is_the_nearest_by_brute_force_and_drops_hidden_frames(graph):
    a = build_arrays(graph)
    index = OlngIndex(graph, a)
    rng = np.random.default_rng(0)
    reading = a["readings"][17] + rng.normal(0, 0.05, a["readings"].shape[1])
    got = index.query(reading, 12)
    d = np.linalg.norm(a["readings"].astype(np.float64) - reading, axis=1)
    np.testing.assert_array_equal(got.frames, np.argsort(d, kind="stable")[:12])
    np.testing.assert_allclose(got.distances, np.sort(d)[:12], rtol=1e-6)
    assert got.dropped == 0
    # Hide the clip of the nearest frame: the same tree, its frames passed over.
    clip = graph.node_clip[a["nodes"][got.frames[0]]]
    allowed = graph.node_clip != clip
    hidden = index.with_allowed(allowed)
    assert hidden.tree is index.tree
    h = hidden.query(reading, 12)
    ok = allowed[a["nodes"]]
    expect = [p for p in np.argsort(d, kind="stable") if ok[p]][:12]
    np.testing.assert_array_equal(h.frames, expect)
    # dropped: the hidden frames nearer than the last one kept
    by_distance = np.argsort(d, kind="stable")
    last = list(by_distance).index(expect[-1])
    assert h.dropped == int(np.sum(~ok[by_distance[: last + 1]])) > 0


def test_bad_queries_are_refused(graph):
    index = OlngIndex(graph, build_arrays(graph))
    width = index.readings.shape[1]
    with pytest.raises(InputError, match="NaN"):
        index.query(np.full(width, np.nan), 4)
    with pytest.raises(InputError, match="values"):
        index.query(np.zeros(width + 1), 4)
    with pytest.raises(InputError, match="K must be"):
        index.query(np.zeros(width), index.frames + 1)


def test_the_arrays_are_cached_beside_the_graph_file_and_memory_mapped(graph, tmp_path):
    from graphsvc.graph.file import load_graph, save_graph
    from graphsvc.strategies.index import index_path
    from graphsvc.strategies.olng.index import load_index

    path = tmp_path / "g.graph"
    save_graph(graph, path)
    loaded = load_graph(path)
    first = load_index(loaded)
    cache = index_path(path, "olng")
    assert cache.is_file()
    stamp = cache.stat().st_mtime_ns
    again = load_index(load_graph(path))
    assert cache.stat().st_mtime_ns == stamp  # read, not rebuilt
    assert not again.readings.flags.writeable and not again.readings.flags.owndata  # (a view of the mapped file)
    np.testing.assert_array_equal(again.readings, first.readings)
    np.testing.assert_array_equal(again.run_of, build_arrays(graph)["run_of"])
