"""The strategy registry and the interface every strategy shares: lookup by name,
inputs checked against what a strategy needs, the shared report."""

import numpy as np
import pytest

from graphsvc.errors import InputError, StrategyNotImplementedError
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion.procedural import generate_knowledge_base, generate_performance
from graphsvc.pipeline import Options, open_session, reconstruct
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies import available, get, names
from graphsvc.strategies.base import INPUTS, Strategy
from graphsvc.strategies.live import LiveSession
from graphsvc.strategies.nearest import NearestSession
from graphsvc.strategies.viterbi import ViterbiSession


@pytest.fixture(scope="module")
def graph():
    g, _ = build_graph(
        generate_knowledge_base(seed=2, minutes=0.5), BuildOptions(layout=PRESETS["kelly6"], progress=False)
    )
    return g


@pytest.fixture(scope="module")
def rec():
    motion = generate_performance(seed=4)[0].slice(0, 90)
    return simulate_recording(motion, PRESETS["kelly6"], NOISE["none"], seed=0)


def test_names_and_lookup(monkeypatch):
    assert available()[:4] == ("viterbi", "nearest", "olng", "ssg")
    assert set(names()) >= {"viterbi", "nearest", "olng", "ssg"}
    for name in available():
        s = get(name)
        assert isinstance(s, Strategy) and s.name == name and s.summary
        assert s.needs <= s.uses <= set(INPUTS)
        assert issubclass(s.session_class, LiveSession)
    import graphsvc.strategies as registry

    monkeypatch.setattr(registry, "PLANNED", ("hosvd",))  # a strategy specified but not built
    assert names()[-1] == "hosvd"
    with pytest.raises(StrategyNotImplementedError, match="not implemented"):
        get("hosvd")
    with pytest.raises(InputError, match="unknown strategy 'elbow'"):
        get("elbow")


def test_live_session_opens_the_strategys_session(graph, rec, monkeypatch):
    from graphsvc.strategies.ssg import SsgSession

    assert type(open_session(graph, Options(), rec.sensor_names)) is ViterbiSession
    assert type(open_session(graph, Options(strategy="nearest"), rec.sensor_names)) is NearestSession
    with pytest.raises(InputError, match="needs the names of the markers"):
        open_session(graph, Options(strategy="ssg"), rec.sensor_names)
    with pytest.raises(InputError, match="needs a marker set"):
        open_session(graph, Options(strategy="ssg"), marker_names=("l_hand",))
    from graphsvc.strategies.ssg.options import SsgOptions

    ssg = open_session(graph, Options(strategy="ssg", ssg=SsgOptions(markers="hands-feet")), marker_names=("l_hand",))
    assert type(ssg) is SsgSession
    import graphsvc.strategies as registry

    monkeypatch.setattr(registry, "PLANNED", ("hosvd",))
    with pytest.raises(StrategyNotImplementedError):
        open_session(graph, Options(strategy="hosvd"), rec.sensor_names)


@pytest.mark.parametrize("strategy", ["viterbi", "nearest", "olng"])
def test_a_missing_input_is_named(graph, rec, strategy):
    from dataclasses import replace

    bare = replace(
        rec,
        accelerations=None,
        orientations=np.tile([1.0, 0, 0, 0], (rec.num_samples, rec.num_sensors, 1)).astype(np.float32),
    )
    with pytest.raises(InputError, match=f"strategy '{strategy}' needs accelerations, and the recording has none"):
        reconstruct(graph, bare, Options(strategy=strategy))


def test_inputs_and_options_a_strategy_cannot_use_are_reported(graph, rec):
    constraints = ([{"start_s": 0.0, "end_s": 1.0, "require": {"contact": "both"}}],)
    r = reconstruct(graph, rec, Options(strategy="nearest", constraints=constraints, beam=5.0))
    assert r.report["ignored_inputs"] == ["constraints"]
    assert r.report["ignored_options"] == ["beam"]
    assert r.report["constraint_sets"] == 0
    pulled = reconstruct(graph, rec, Options(strategy="nearest", track_pull_s=0.0))  # (no path to pull)
    assert pulled.report["ignored_options"] == ["track_pull_s"]
    v = reconstruct(graph, rec, Options(constraints=constraints))
    assert "ignored_inputs" not in v.report and v.report["constraint_sets"] == 1


@pytest.mark.parametrize("strategy", ["viterbi", "nearest"])
def test_every_strategy_reports_the_same_fields(graph, rec, strategy):
    r = reconstruct(graph, rec, Options(strategy=strategy))
    rep = r.report
    for key in (
        "strategy",
        "options",
        "graph",
        "samples",
        "labels",
        "node_path",
        "timings_s",
        "samples_per_s",
        "terms",
        "cost",
    ):
        assert key in rep, key
    assert rep["strategy"] == strategy
    assert {"warm_up", "prepare", "search", "synthesis"} <= set(rep["timings_s"])
    assert sum(run["frames"] for run in rep["labels"]) == rep["samples"] == r.motion.num_frames
    # Provenance: one source a frame for graph nodes, its label the node's.
    p = r.provenance
    assert p.clip.shape == (r.motion.num_frames, 1) and np.allclose(p.weight, 1.0)
    np.testing.assert_array_equal(p.clip[:, 0], graph.node_clip[r.node_path])
    assert list(p.label) == [graph.labels[k] for k in graph.node_label[r.node_path]]
    assert p.sources(0) == [(int(graph.node_clip[r.node_path[0]]), float(graph.node_frame[r.node_path[0]]), 1.0)]
