"""Crash safety: a writer killed with SIGKILL (GRAPHSVC_CRASH_AT, `fileio._crash_point`)
at the worst moments — its temporary file just made, or written and synced but not
yet renamed — leaves the output absent (or, when it existed, as it was), never
partial; rerunning completes and removes what the killed run left. One test per
writer: build, relayout, simulate, synthesize (a BVH and its report), batch, and the
server's batch store."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import write_procedural_kb

ROOT = Path(__file__).resolve().parents[1]


def graphsvc(*args, crash: str | None = None, timeout: float = 180) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.pop("GRAPHSVC_CRASH_AT", None)
    if crash:
        env["GRAPHSVC_CRASH_AT"] = crash
    return subprocess.run(
        [sys.executable, "-m", "graphsvc.cli", *map(str, args)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def killed(proc: subprocess.CompletedProcess) -> None:
    assert proc.returncode == -signal.SIGKILL, proc.stderr


def ok(proc: subprocess.CompletedProcess) -> None:
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def kb(tmp_path_factory) -> Path:
    return write_procedural_kb(tmp_path_factory.mktemp("kb"), seed=0, minutes=0.2)


@pytest.fixture(scope="module")
def small_graph(kb, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("graph") / "small.graph"
    ok(graphsvc("build", kb, "-o", out, "--layout", "kelly6", "--quiet"))
    return out


def test_main_runs_as_a_module():
    # (the subprocesses below run `python -m graphsvc.cli`)
    proc = graphsvc("--version")
    assert proc.returncode == 0 and proc.stdout.strip()


@pytest.mark.parametrize("point", ["open", "rename"])
def test_build_killed_writing_leaves_no_graph_and_a_rerun_completes(kb, tmp_path, point):
    from graphsvc.graph.file import load_graph

    out = tmp_path / "g.graph"
    killed(graphsvc("build", kb, "-o", out, "--quiet", crash=f"{point}:g.graph"))
    assert not out.exists() and len(temporaries(tmp_path)) == 1
    ok(graphsvc("build", kb, "-o", out, "--quiet"))
    assert load_graph(out).num_nodes > 0 and temporaries(tmp_path) == []


def test_relayout_killed_over_an_existing_graph_leaves_it_as_it_was(small_graph, tmp_path):
    from graphsvc.graph.file import load_graph

    out = tmp_path / "relaid.graph"
    out.write_bytes(small_graph.read_bytes())
    before = out.read_bytes()
    killed(graphsvc("relayout", small_graph, "--layout", "wrists-ankles", "-o", out, crash="rename:relaid.graph"))
    assert out.read_bytes() == before and len(temporaries(tmp_path)) == 1
    ok(graphsvc("relayout", small_graph, "--layout", "wrists-ankles", "-o", out))
    assert load_graph(out).layout["name"] == "wrists-ankles" and temporaries(tmp_path) == []


@pytest.mark.parametrize("suffix", [".rec", ".csv"])
def test_simulate_killed_writing_leaves_no_recording_and_a_rerun_completes(kb, tmp_path, suffix):
    from graphsvc.sensors.files import read_recording

    clip = sorted(kb.glob("*.bvh"))[0]
    out = tmp_path / f"sim{suffix}"
    killed(graphsvc("simulate", clip, "--layout", "kelly6", "-o", out, crash=f"rename:sim{suffix}"))
    assert not out.exists() and len(temporaries(tmp_path)) == 1
    ok(graphsvc("simulate", clip, "--layout", "kelly6", "-o", out))
    assert read_recording(out).num_samples > 0 and temporaries(tmp_path) == []


@pytest.mark.parametrize("point", ["open:out.json", "rename:out.json", "open:out.bvh", "rename:out.bvh"])
def test_synthesize_killed_anywhere_never_leaves_a_bvh_without_its_report(small_graph, kb, tmp_path, point):
    clip = sorted(kb.glob("*.bvh"))[0]
    rec = tmp_path / "in.rec"
    ok(graphsvc("simulate", clip, "--layout", "kelly6", "-o", rec))
    args = (
        "synthesize",
        small_graph,
        rec,
        "-o",
        tmp_path / "out.bvh",
        "--report",
        tmp_path / "out.json",
        "--strategy",
        "nearest",
    )
    killed(graphsvc(*args, crash=point))
    bvh, report = (tmp_path / "out.bvh").exists(), (tmp_path / "out.json").exists()
    assert not bvh and report == (point == "rename:out.bvh")  # the report lands first, the BVH last
    ok(graphsvc(*args))
    assert (tmp_path / "out.bvh").exists() and (tmp_path / "out.json").exists() and temporaries(tmp_path) == []


def test_batch_killed_writing_its_summary_reruns_to_completion(small_graph, kb, tmp_path):
    import json

    from graphsvc.sensors.files import read_recording

    clip = sorted(kb.glob("*.bvh"))[0]
    ok(graphsvc("simulate", clip, "--layout", "kelly6", "-o", tmp_path / "in.rec"))
    manifest = tmp_path / "m.csv"
    manifest.write_text("recording,graph,strategy,output\nin.rec,small,nearest,a\nin.rec,small,viterbi,b\n")
    out = tmp_path / "out"
    args = ("batch", manifest, "--out", out, "--workers", "1", "--graph", f"small={small_graph}", "--quiet")
    killed(graphsvc(*args, crash="rename:summary.json"))
    left = temporaries(out)
    assert not (out / "summary.json").exists() and len(left) == 1 and left[0].startswith(".summary.json.")
    assert {p.name for p in out.glob("*.bvh")} == {"a.bvh", "b.bvh"}  # each item whole before the crash
    done = {p.name: p.stat().st_mtime_ns for p in out.glob("*.bvh")}
    ok(graphsvc(*args))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["totals"]["done"] == 2 and summary["totals"]["skipped"] == 2  # nothing recomputed
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.bvh")} == done
    assert temporaries(out) == [] and read_recording(tmp_path / "in.rec").num_samples > 0


_SUBMIT = """
import sys
from graphsvc.batch.service import BatchManager
BatchManager(sys.argv[1], {{"small": sys.argv[2]}}).submit({text!r})
"""


def test_server_killed_making_a_batch_leaves_none_and_its_next_start_cleans_up(small_graph, tmp_path):
    from graphsvc.batch.service import BatchManager

    root = tmp_path / "batches"
    root.mkdir()
    text = "recording,graph,strategy,output\nin.rec,small,nearest,a\n"
    env = dict(
        os.environ,
        GRAPHSVC_CRASH_AT="rename:manifest.*",
        PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
    )
    for _ in range(2):
        proc = subprocess.run(
            [sys.executable, "-c", _SUBMIT.format(text=text), str(root), str(small_graph)],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        killed(proc)
    # No batch folder; the second start removed the first one's leftovers, its own remain.
    assert len(list(root.iterdir())) == 1 and temporaries(root) == [p.name for p in root.iterdir()]
    manager = BatchManager(root, {"small": str(small_graph)})  # a restarted server
    assert list(root.iterdir()) == [] and manager.list() == []
