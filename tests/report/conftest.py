"""The report tests' shared inputs: a small procedural graph on disk and a
performance's recordings."""

import pytest

from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import save_graph
from graphsvc.motion.procedural import generate_knowledge_base, generate_performance
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.markers import PRESETS as MARKERS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_marker_recording, simulate_recording

CONSTRAINTS = [[{"start_s": 0.5, "end_s": 1.5, "require": {"label": "stop"}}]]


@pytest.fixture(scope="session")
def files(tmp_path_factory):
    """A small procedural graph on disk, a performance's accelerometer recording (with a
    constraint set) and its marker recording."""
    d = tmp_path_factory.mktemp("report")
    kb = generate_knowledge_base(seed=2, minutes=0.5)
    graph, _ = build_graph(kb, BuildOptions(layout=load_layout("kelly6"), progress=False))
    save_graph(graph, d / "kb.graph")
    truth = generate_performance(seed=4)[0].slice(0, 75)
    rec = simulate_recording(truth, load_layout("kelly6"), NOISE["default"], seed=0)
    rec.constraints = CONSTRAINTS
    save_recording(rec, d / "take.rec")
    save_recording(simulate_marker_recording(truth, MARKERS["hands-feet"], NOISE["default"], seed=0), d / "markers.rec")
    return d, graph, truth
