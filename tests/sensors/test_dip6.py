"""The dip6 layout (DIP-IMU's six sensors) end to end on a small procedural knowledge
base: a graph builds with it, its edges carry orientations relative to the pelvis
sensor, and a noise-free recording of a knowledge-base clip comes back as itself."""

from dataclasses import replace

import numpy as np
import pytest

from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.pipeline import Options, reconstruct
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.orientation import RELATIVE_WIDTH, relative_orientations
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.inputs import graph_cue
from graphsvc.strategies.options import Weights


@pytest.fixture(scope="module")
def kb():
    return generate_knowledge_base(seed=2, minutes=0.4)


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb, BuildOptions(layout=PRESETS["dip6"], progress=False))
    return g


def test_a_dip6_graph_carries_orientations_relative_to_the_pelvis(graph, kb):
    assert graph.sensor_names == PRESETS["dip6"].sensor_names
    assert graph.edge_up is not None and graph.edge_up.shape == (graph.num_edges, 6, RELATIVE_WIDTH)
    # A clip's orientations, simulated without noise, give the cue its graph nodes carry:
    # the graph's edges into clip 1's nodes hold what the recording's orientations make.
    clip = graph.clips[1]
    noise = replace(NOISE["none"], orientations=1.0)
    rec = simulate_recording(kb[1], PRESETS["dip6"], noise, seed=0)
    cue = graph_cue(graph, rec.orientations)
    np.testing.assert_allclose(cue, relative_orientations(rec.orientations.astype(np.float64), 5), atol=1e-12)
    first, count = int(clip["first_node"]), int(clip["frames"])
    dst = np.asarray(graph.edge_dst)
    for node in (first + 5, first + count // 2):
        e = int(np.flatnonzero(dst == node)[0])
        np.testing.assert_allclose(graph.edge_up[e].astype(np.float64), cue[node - first], atol=2e-3)


def test_a_noise_free_dip6_clip_comes_back_as_itself(graph, kb):
    noise = replace(NOISE["none"], orientations=1.0)
    rec = simulate_recording(kb[1], PRESETS["dip6"], noise, seed=0)
    r = reconstruct(graph, rec, Options(weights=Weights(0.5, 1, 1, 1)))
    first = graph.clips[1]["first_node"]
    np.testing.assert_array_equal(r.node_path, first + np.arange(rec.num_samples))
