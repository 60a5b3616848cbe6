"""Outputs never overwrite inputs: every command refuses, with one line and exit 2
before it reads or writes anything, an output path that names one of its inputs or
another output, a suffix it would not write, and an empty path."""

from __future__ import annotations

import pytest

from graphsvc.cli import main
from graphsvc.errors import InputError
from graphsvc.fileio import check_outputs
from graphsvc.motion.bvh import write_bvh
from graphsvc.motion.library import load_motion
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording
from tests.conftest import still_motion, write_gliding_clip


@pytest.fixture
def files(tmp_path):
    clip = write_gliding_clip(tmp_path)
    rec = tmp_path / "take.rec"
    save_recording(simulate_recording(load_motion(clip), load_layout("kelly6"), parse_noise("none"), seed=0), rec)
    graph = tmp_path / "g.graph"
    graph.write_bytes(b"not read: the outputs are checked first")
    return {"clip": clip, "rec": rec, "graph": graph, "dir": tmp_path}


def _main(argv) -> int:
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:  # (argparse's own refusals)
        return exc.code


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _refused(argv, capsys, folder, needle: str) -> str:
    before = _snapshot(folder)
    code = _main(argv)
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("graphsvc: error: "), err
    assert needle in lines[0], lines[0]
    assert _snapshot(folder) == before, "a refused command changed a file"
    return lines[0]


@pytest.mark.parametrize(
    "case", ["-o input", "--report input", "-o equal to --report", "-o graph", "-o x.txt", "--report x.bvh", "-o empty"]
)
def test_synthesize_refuses_outputs_that_would_lose_data(files, capsys, case):
    g, rec, d = files["graph"], files["rec"], files["dir"]
    argv, needle = {
        "-o input": (["synthesize", g, rec, "-o", rec], "would overwrite the recording"),
        "--report input": (
            ["synthesize", g, rec, "-o", d / "out.bvh", "--report", rec],
            "would overwrite the recording",
        ),
        "-o equal to --report": (
            ["synthesize", g, rec, "-o", d / "x.bvh", "--report", d / "x.bvh"],
            "name the same file",
        ),
        "-o graph": (["synthesize", g, rec, "-o", g], "would overwrite the graph"),
        "-o x.txt": (["synthesize", g, rec, "-o", d / "x.txt"], "writes .bvh, .glb or .gltf, not .txt"),
        "--report x.bvh": (["synthesize", g, rec, "-o", d / "y.bvh", "--report", d / "y.BVH"], "writes .json"),
        "-o empty": (["synthesize", g, rec, "-o", ""], "empty path"),
    }[case]
    _refused(argv, capsys, d, needle)


def test_an_output_that_is_an_input_under_another_name_is_refused(files, capsys):
    d = files["dir"]
    (d / "sub").mkdir()
    link = d / "sub" / "same.rec"
    link.symlink_to(files["rec"])
    hard = d / "hard.rec"
    hard.hardlink_to(files["rec"])
    for alias in (link, hard, d / "sub" / ".." / "take.rec"):
        _refused(
            ["synthesize", files["graph"], files["rec"], "-o", d / "a.bvh", "--report", alias],
            capsys,
            d,
            "would overwrite the recording",
        )
    with pytest.raises(InputError, match="would overwrite the recording"):
        check_outputs([("-o", link, (".bvh",))], [("the recording", files["rec"])])


def test_two_outputs_naming_one_file_through_dot_segments(tmp_path):
    with pytest.raises(InputError, match="name the same file"):
        check_outputs([("--json", tmp_path / "e.json", None), ("--report-html", tmp_path / "." / "e.json", None)])
    check_outputs([("--json", tmp_path / "e.json", (".json",)), ("--report-html", tmp_path / "e.html", (".html",))])


@pytest.mark.parametrize(
    "case",
    [
        "simulate -o clip",
        "simulate -o txt",
        "mapping -o clip",
        "calibrate -o rec",
        "report -o result",
        "relayout -o graph",
        "build -o kb file",
        "evaluate json = html",
        "evaluate --json kb file",
    ],
)
def test_other_commands_refuse_outputs_over_inputs(files, capsys, case):
    c, rec, g, d = files["clip"], files["rec"], files["graph"], files["dir"]
    result = d / "r.json"
    result.write_text("{}")
    argv, needle = {
        "simulate -o clip": (["simulate", c, "--layout", "kelly6", "-o", c], "would overwrite the clip"),
        "simulate -o txt": (["simulate", c, "--layout", "kelly6", "-o", d / "a.txt"], "not .txt"),
        "mapping -o clip": (["mapping", c, "-o", c], "would overwrite the clip"),
        "calibrate -o rec": (["calibrate", rec, "--pose", "npose", "-o", rec], "would overwrite the recording"),
        "report -o result": (["report", result, "-o", d / "R.JSON"], ".html"),
        "relayout -o graph": (["relayout", g, "--layout", "kelly6", "-o", g], "would overwrite the graph"),
        "build -o kb file": (["build", c, "-o", c], "would overwrite a knowledge-base file"),
        "evaluate json = html": (
            ["evaluate", d, "--test", "*", "--json", d / "e.json", "--report-html", d / "e.json"],
            "name the same file",
        ),
        "evaluate --json kb file": (
            ["evaluate", c, "--test", "*", "--json", result, "--graph", result],
            "would overwrite the graph",
        ),
    }[case]
    _refused(argv, capsys, d, needle)


@pytest.mark.parametrize(
    "argv",
    [
        ["inspect", ""],
        ["inspect", " "],
        ["simulate", "", "--layout", "kelly6", "-o", "x.rec"],
        ["build", "", "-o", "g"],
        ["info", ""],
        ["synthesize", "", "x.rec", "-o", "y.bvh"],
        ["report", "", "-o", "r.html"],
        ["mapping", ""],
        ["demo", "-o", ""],
        ["evaluate", "kb", "--test", "*", "--json", ""],
    ],
)
def test_an_empty_path_is_refused_wherever_it_is_given(argv, capsys, tmp_path, monkeypatch):
    # beside a demo's output, which an empty path once found as "the current folder"
    demo = tmp_path / "graphsvc-demo"
    demo.mkdir()
    write_bvh(demo / "walk_demo_001.bvh", still_motion(3), scale=100.0)
    monkeypatch.chdir(tmp_path)
    code = _main(argv)
    err = capsys.readouterr().err
    assert code == 2 and "empty path" in err and len(err.strip().splitlines()) == 1, err


def test_the_library_refuses_an_empty_path():
    from graphsvc.describe import describe_paths
    from graphsvc.motion.library import find_motion_files

    for call in (lambda: describe_paths([""]), lambda: find_motion_files([""])):
        with pytest.raises(InputError, match="empty path"):
            call()


def test_synthesize_files_checks_its_outputs_before_reading(files):
    from graphsvc.pipeline import synthesize_files

    rec = files["rec"]
    before = rec.read_bytes()
    for output, report in (
        (rec, None),
        (files["dir"] / "a.bvh", rec),
        (files["dir"] / "a.bvh", files["dir"] / "a.bvh"),
    ):
        with pytest.raises(InputError):  # (the graph object is never touched: None would fail on use)
            synthesize_files(None, files["graph"], rec, output, report_path=report)
    assert rec.read_bytes() == before and not (files["dir"] / "a.bvh").exists()


def test_the_working_directory_is_empty_at_every_test_start(tmp_path):
    from pathlib import Path

    assert list(Path.cwd().iterdir()) == [] and Path.cwd() != tmp_path
