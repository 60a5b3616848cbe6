"""Fixtures of the batch tests: a small graph built once from the procedural knowledge
base, recordings of the held-out performance (accelerometers and tracker; optical
markers), and one real two-worker LocalCluster the tests share (no mocks of Dask)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def batch_files(tmp_path_factory) -> Path:
    """A folder with small.graph, perf0..perf3.rec (3 to 6 s of the performance,
    default noise, ground position and heading) and markers.rec (hands-feet)."""
    from graphsvc.graph.build import BuildOptions, build_graph
    from graphsvc.graph.file import save_graph
    from graphsvc.motion.procedural import generate_knowledge_base, generate_performance
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.recording import save_recording
    from graphsvc.sensors.simulate import MarkerPattern, simulate_marker_recording, simulate_recording

    folder = tmp_path_factory.mktemp("batch-inputs")
    layout = load_layout("kelly6")
    graph, _ = build_graph(generate_knowledge_base(seed=0, minutes=0.5), BuildOptions(layout=layout))
    save_graph(graph, folder / "small.graph")
    motion = generate_performance(seed=1)[0]
    for k in range(4):
        clip = motion.slice(30 * k, 30 * k + 90 + 30 * k)
        save_recording(simulate_recording(clip, layout, parse_noise("default"), seed=k), folder / f"perf{k}.rec")
    markers = simulate_marker_recording(
        motion.slice(30, 120),
        "hands-feet",
        parse_noise("none"),
        seed=0,
        pattern=MarkerPattern(gaps=((10, 20),), flicker=0.1),
    )
    save_recording(markers, folder / "markers.rec")
    return folder


@pytest.fixture(scope="session")
def cluster():
    """Two single-threaded local workers, as `graphsvc batch --workers 2` starts them."""
    from graphsvc.batch.run import local_cluster

    c = local_cluster(2)
    yield c
    c.close()


@pytest.fixture(scope="session")
def client(cluster):
    from distributed import Client

    c = Client(cluster, set_as_default=False)
    yield c
    c.close()


def write_manifest(path: Path, rows: list[dict]) -> Path:
    """rows as a CSV manifest (options as JSON text), or JSON for a .json path."""
    if path.suffix == ".json":
        path.write_text(json.dumps(rows))
        return path
    columns = ["recording", "graph", "strategy", "output", "weights", "constraints", "format", "options"]
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        for r in rows:
            w.writerow([json.dumps(r[c]) if c == "options" and c in r else r.get(c, "") for c in columns])
    return path
