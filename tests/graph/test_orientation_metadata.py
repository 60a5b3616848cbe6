"""The graph's sensor-orientation metadata (`graph.edge_up`): what the simulator's
orientation output says of the same frames, the same at build and after relayout, and
graph files without it."""

import numpy as np
import pytest

from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.metadata import edge_up_vectors
from graphsvc.graph.model import EDGE_ORIGINAL, NODE_BRIDGE, NODE_INTERP
from graphsvc.motion import quat
from graphsvc.sensors.layout import PRESETS, root_sensor
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.orientation import relative_orientations, sensor_up
from graphsvc.sensors.simulate import simulate_recording
from tests.graph.test_connectivity import mixed_kb


@pytest.fixture(scope="module")
def built():
    kb = mixed_kb(5)
    g, _ = build_graph(kb, BuildOptions(layout=PRESETS["wrists-ankles"], progress=False))
    return kb, g


def test_sensor_up_is_world_up_in_the_sensor_frame():
    rng = np.random.default_rng(3)
    q = quat.normalize(rng.normal(size=(50, 4)))
    up = sensor_up(q)
    # R(q)ᵀ·ŷ from the rotation matrix, an independent route
    np.testing.assert_allclose(up, np.einsum("nij,i->nj", quat.to_matrix(q), [0.0, 1.0, 0.0]), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(up, axis=-1), 1.0, atol=1e-12)
    # a turn about the vertical leaves it alone (the cost is yaw-free)
    turned = quat.mul(quat.about_y(rng.uniform(-np.pi, np.pi, 50)), q)
    np.testing.assert_allclose(sensor_up(turned), up, atol=1e-12)


def test_edge_up_is_what_the_simulated_devices_report_of_the_same_frames(built):
    kb, g = built
    assert g.edge_up is not None and g.edge_up.shape == g.edge_acc.shape and g.edge_up.dtype == np.float16
    assert np.any(g.node_kind == NODE_BRIDGE) and np.any(g.node_kind == NODE_INTERP)
    np.testing.assert_allclose(np.linalg.norm(g.edge_up.astype(np.float64), axis=-1), 1.0, atol=2e-3)
    noise = parse_noise("none,orientations=1")  # the devices' orientation output, noise-free
    for c in (0, 3):
        motion = kb[c]
        assert g.clips[c]["name"] == motion.name
        rec = simulate_recording(motion, PRESETS["wrists-ankles"], noise, rate_hz=g.rate_hz)
        measured = sensor_up(rec.orientations)
        first, frames = g.clips[c]["first_node"], g.clips[c]["frames"]
        edges = np.flatnonzero((g.edge_kind == EDGE_ORIGINAL) & (g.edge_dst >= first) & (g.edge_dst < first + frames))
        assert edges.size == frames - 1
        np.testing.assert_allclose(g.edge_up[edges].astype(np.float64), measured[g.edge_dst[edges] - first], atol=2e-3)


def test_relayout_and_a_saved_graph_agree_with_the_build(built, tmp_path):
    _, g = built
    save_graph(g, tmp_path / "g.graph")
    loaded = load_graph(tmp_path / "g.graph")
    np.testing.assert_array_equal(loaded.edge_up, g.edge_up)
    np.testing.assert_array_equal(edge_up_vectors(loaded, PRESETS["wrists-ankles"]), g.edge_up)
    six = edge_up_vectors(loaded, PRESETS["kelly6"])  # (a root sensor: rotations relative to it)
    assert six.shape == (g.num_edges, 6, 9)


def test_a_layout_with_a_root_sensor_gets_what_its_devices_report_relative_to_the_root(built):
    kb, g = built
    layout = PRESETS["kelly6"]
    six = edge_up_vectors(g, layout).astype(np.float64)
    noise = parse_noise("none,orientations=1")
    motion = kb[1]
    rec = simulate_recording(motion, layout, noise, rate_hz=g.rate_hz)
    measured = relative_orientations(rec.orientations, root_sensor(layout))
    first, frames = g.clips[1]["first_node"], g.clips[1]["frames"]
    edges = np.flatnonzero((g.edge_kind == EDGE_ORIGINAL) & (g.edge_dst >= first) & (g.edge_dst < first + frames))
    np.testing.assert_allclose(six[edges], measured[g.edge_dst[edges] - first], atol=2e-3)


def test_graph_files_without_orientation_metadata_still_load(built, tmp_path):
    from dataclasses import replace

    _, g = built
    save_graph(replace(g, edge_up=None), tmp_path / "old.graph")
    old = load_graph(tmp_path / "old.graph")
    assert old.edge_up is None
    np.testing.assert_array_equal(old.edge_acc, g.edge_acc)
