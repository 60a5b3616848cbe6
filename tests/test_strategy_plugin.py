"""A strategy installed as its own package reaches every way in, with no other edit.

The example package (examples/strategy-plugin: `graphsvc_meanpose`, the knowledge
base's mean pose) is installed into a folder of its own as pip would (the package and
a dist-info whose entry_points.txt is the example's own pyproject declaration), put on
the path, and found by the registry through the `graphsvc.strategies` entry-point
group. Then `synthesize` (in this process and as a command of its own), `evaluate`,
`batch` (Dask worker processes), the gRPC unary and streaming calls (live-worker
processes) and the report all take `--strategy meanpose` and its own option."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import graphsvc.strategies as registry
from graphsvc.batch.manifest import _ItemParser
from graphsvc.cli import build_parser, main
from tests.conftest import write_procedural_kb

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "strategy-plugin"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The example package installed into a site folder of its own, on the path (this
    process's and, through PYTHONPATH, every child's), the registry emptied so that it
    loads again; everything as it was afterwards."""
    site = tmp_path_factory.mktemp("site")
    shutil.copytree(EXAMPLE / "graphsvc_meanpose", site / "graphsvc_meanpose")
    project = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]
    info = site / f"graphsvc_meanpose-{project['version']}.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    points = project["entry-points"]["graphsvc.strategies"]
    (info / "entry_points.txt").write_text(
        "[graphsvc.strategies]\n" + "".join(f"{k} = {v}\n" for k, v in points.items())
    )
    saved = (list(sys.path), os.environ.get("PYTHONPATH"), dict(registry._REGISTRY), registry._loaded)
    sys.path.insert(0, str(site))
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(site), saved[1]) if p)
    registry._REGISTRY.clear()
    registry._loaded = False
    _ItemParser._parser = None  # (a batch's flag parser, made once a process, as it was before the install)
    yield site
    sys.path[:] = saved[0]
    if saved[1] is None:
        os.environ.pop("PYTHONPATH", None)
    else:
        os.environ["PYTHONPATH"] = saved[1]
    registry._REGISTRY.clear()
    registry._REGISTRY.update(saved[2])
    registry._loaded = saved[3]
    _ItemParser._parser = None
    sys.modules.pop("graphsvc_meanpose", None)


@pytest.fixture(scope="module")
def files(installed, tmp_path_factory):
    """A procedural knowledge base, its kelly6 graph and a held-out clip's recording."""
    from graphsvc.motion.procedural import generate_performance
    from graphsvc.sensors.layout import load_layout
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.recording import save_recording
    from graphsvc.sensors.simulate import simulate_recording

    d = tmp_path_factory.mktemp("plugin")
    (d / "kb").mkdir()
    kb = write_procedural_kb(d / "kb", seed=0, minutes=0.5)
    assert main(["build", str(kb), "-o", str(d / "kb.graph"), "--layout", "kelly6", "--quiet", "--no-bridges"]) == 0
    motion = generate_performance(seed=5)[0].slice(0, 90)
    save_recording(simulate_recording(motion, load_layout("kelly6"), parse_noise("default"), seed=1), d / "take.rec")
    return {"dir": d, "kb": kb, "graph": d / "kb.graph", "rec": d / "take.rec"}


def test_the_installed_strategy_is_registered_with_its_flags(installed, capsys):
    from graphsvc_meanpose import MeanPoseOptions

    assert registry.available()[:4] == ("viterbi", "nearest", "olng", "ssg") and "meanpose" in registry.available()
    s = registry.get("meanpose")
    assert s.options_class is MeanPoseOptions and type(s).__module__ == "graphsvc_meanpose"
    with pytest.raises(SystemExit):
        build_parser().parse_args(["synthesize", "--help"])
    text = capsys.readouterr().out
    assert "--meanpose-label LABEL" in text and "meanpose" in text.split("--strategy")[1]


def test_synthesize_in_process_and_as_a_command_then_the_report(files, capsys):
    d = files["dir"]
    out, report = d / "mean.bvh", d / "mean.json"
    argv = [
        "synthesize",
        str(files["graph"]),
        str(files["rec"]),
        "-o",
        str(out),
        "--strategy",
        "meanpose",
        "--meanpose-label",
        "idle",
        "--report",
        str(report),
    ]
    assert main(argv) == 0, capsys.readouterr().err
    r = json.loads(report.read_text())
    assert r["strategy"] == "meanpose" and r["options"]["label"] == "idle" and r["meanpose"]["label"] == "idle"
    assert "accelerations" in r["ignored_inputs"]  # (a floor: it reads no sensor)
    # the same bytes from a process of its own, which finds the strategy by itself
    again = d / "again.bvh"
    proc = subprocess.run(
        [sys.executable, "-m", "graphsvc.cli", *argv[:4], str(again), *argv[5:9]],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert again.read_bytes() == out.read_bytes()
    assert main(["report", str(report), "-o", str(d / "mean.html")]) == 0
    assert (d / "mean.html").stat().st_size > 100_000
    # a bad value of its own option: one line, exit 2
    capsys.readouterr()
    assert main([*argv[:4], str(d / "x.bvh"), "--strategy", "meanpose", "--meanpose-label", "swim"]) == 2
    err = capsys.readouterr().err
    assert "meanpose label 'swim'" in err and len(err.strip().splitlines()) == 1


def test_evaluate_hides_the_test_clip_from_the_mean(files, capsys):
    from graphsvc_meanpose import STRATEGY, mean_pose_node

    from graphsvc.evaluate.loo import held_out_mask
    from graphsvc.graph.file import load_graph

    graph = load_graph(files["graph"])
    whole = graph.clips[int(graph.node_clip[mean_pose_node(graph, None, None)])]["name"]
    clip = f"{whole}.bvh"  # the clip the mean pose comes from when nothing is hidden
    out = files["dir"] / "e.json"
    assert (
        main(
            [
                "evaluate",
                str(files["kb"]),
                "--test",
                clip,
                "--graph",
                str(files["graph"]),
                "--strategy",
                "meanpose",
                "--hold-out",
                "clip",
                "--quiet",
                "--json",
                str(out),
            ]
        )
        == 0
    ), capsys.readouterr().err
    e = json.loads(out.read_text())
    assert e["config"]["options"]["strategy"] == "meanpose" and len(e["clips"]) == 1
    assert np.isfinite(e["clips"][0]["joint_err_cm"])
    k = [c["name"] for c in graph.clips].index(whole)
    hidden = STRATEGY.allowed_mask(graph, k)
    np.testing.assert_array_equal(hidden, held_out_mask(graph, k))
    assert graph.node_clip[mean_pose_node(graph, hidden, None)] != k  # the hidden clip's frames are not in the mean


def test_batch_runs_it_on_dask_workers(files, capsys):
    from graphsvc.fileio import file_sha256

    d = files["dir"]
    manifest = d / "m.csv"
    manifest.write_text(
        "recording,graph,strategy,output,options\n"
        f'{files["rec"]},{files["graph"]},meanpose,p1,"{{""meanpose-label"": ""idle""}}"\n'
    )
    out = d / "batch"
    assert main(["batch", str(manifest), "--out", str(out), "--workers", "1", "--quiet"]) == 0, capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["totals"]["done"] == 1
    assert (
        main(
            [
                "synthesize",
                str(files["graph"]),
                str(files["rec"]),
                "-o",
                str(d / "ref.bvh"),
                "--strategy",
                "meanpose",
                "--meanpose-label",
                "idle",
            ]
        )
        == 0
    )
    assert file_sha256(out / "p1.bvh") == file_sha256(d / "ref.bvh")


def test_the_service_takes_it_unary_and_streaming_in_live_workers(files):
    from graphsvc_meanpose import MeanPoseOptions

    from graphsvc.pipeline import Options, reconstruct
    from graphsvc.sensors.files import read_recording
    from graphsvc.service import client as C
    from graphsvc.service import convert
    from graphsvc.service.graphs import load_graphs
    from graphsvc.service.server import ServerConfig, start_server

    graphs = load_graphs([f"kb={files['graph']}"])
    running = start_server(graphs, ServerConfig(host="127.0.0.1", port=0, live_workers=1))
    try:
        rec = read_recording(files["rec"])
        options = Options(strategy="meanpose", own=MeanPoseOptions(label="idle"))
        msg = convert.options_to_proto(options)
        assert msg.strategy_name == "meanpose" and msg.strategy == 0  # (no enum value: by name only)
        want = reconstruct(graphs["kb"].graph, rec, options)
        with C.connect(f"127.0.0.1:{running.port}") as conn:
            got = C.synthesize(conn, "kb", rec, msg)
            assert got.report["strategy"] == "meanpose" and got.report["options"]["label"] == "idle"
            np.testing.assert_allclose(got.motion.rotations, want.motion.rotations, atol=1e-6)
            result = C.stream_recording(conn, "kb", rec, msg, speed=1000.0)
        assert len(result.frames) == rec.num_samples and result.started.lag_frames == 0
        assert running.servicer.live_workers.pids()  # (the session ran in a worker process)
    finally:
        running.stop(0)
