"""`evaluate.run` as a library call: the summary it returns is the JSON `--json` writes,
the lines `graphsvc evaluate` prints are formatted from it, notes reach the caller,
and a bad argument is refused before anything is built or written."""

from __future__ import annotations

import json

import pytest

from graphsvc.cli import main
from graphsvc.errors import InputError
from graphsvc.evaluate.run import EvalConfig, run, summary_lines
from graphsvc.strategies.options import Options
from tests.conftest import write_procedural_kb


@pytest.fixture(scope="module")
def kb(tmp_path_factory):
    return write_procedural_kb(tmp_path_factory.mktemp("kb"), seed=5, minutes=0.3)


@pytest.fixture(scope="module")
def graph_file(kb, tmp_path_factory):
    path = tmp_path_factory.mktemp("graph") / "kb.graph"
    assert main(["build", str(kb), "-o", str(path), "--layout", "kelly6", "--quiet", "--no-bridges"]) == 0
    return path


def test_the_summary_is_the_json_and_the_lines_are_the_commands(kb, graph_file, tmp_path, capsys):
    clip = sorted(p.name for p in kb.glob("*.bvh"))[0]
    config = EvalConfig(
        kb=(str(kb),),
        test=clip,
        graph=str(graph_file),
        hold_out="clip",
        options=Options(strategy="nearest"),
        json=str(tmp_path / "E.json"),
        progress=False,
    )
    notes = []
    summary = run(config, note=notes.append)
    assert summary == json.loads((tmp_path / "E.json").read_text()) and notes == []
    assert summary["config"]["kb"] == [str(kb)] and summary["config"]["graph"] == str(graph_file)
    assert all("kept" not in c for c in summary["clips"])
    lines = summary_lines(summary, config)
    assert lines[0].startswith("clip ") and lines[1].startswith("leave-one-out (hold-out clip) on ")
    assert lines[1].endswith(f"; wrote {tmp_path / 'E.json'}") and "(kelly6)" in lines[1]

    # the command prints the same lines (the timings aside) and writes the same JSON
    argv = [
        "evaluate",
        str(kb),
        "--test",
        clip,
        "--graph",
        str(graph_file),
        "--hold-out",
        "clip",
        "--strategy",
        "nearest",
        "--json",
        str(tmp_path / "C.json"),
        "--quiet",
    ]
    capsys.readouterr()
    assert main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    again = json.loads((tmp_path / "C.json").read_text())
    timing = ("build_s", "evaluate_s", "json")
    assert {k: v for k, v in again["config"].items() if k not in timing} == {
        k: v for k, v in summary["config"].items() if k not in timing
    }
    assert [c["joint_err_cm"] for c in again["clips"]] == [c["joint_err_cm"] for c in summary["clips"]]
    assert out[0].split() == lines[0].splitlines()[0].split()
    assert out[-1].split(" on ")[1].split(";")[0] == lines[1].split(" on ")[1].split(";")[0]


def test_a_test_clip_not_in_the_graph_is_a_note(kb, graph_file, tmp_path):
    other = tmp_path / "other"
    other.mkdir()
    write_procedural_kb(other, seed=9, minutes=0.1)
    clip = sorted(p.name for p in other.glob("*.bvh"))[0]
    notes = []
    run(
        EvalConfig(
            kb=(str(other),), test=clip, graph=str(graph_file), options=Options(strategy="nearest"), progress=False
        ),
        note=notes.append,
    )
    assert len(notes) == 1 and "are evaluated with nothing hidden" in notes[0]


def test_arguments_are_checked_before_anything_is_written(kb, tmp_path):
    page = str(tmp_path / "E.html")
    with pytest.raises(ValueError, match="write_page"):
        run(EvalConfig(kb=(str(kb),), test="*", report_html=page))
    with pytest.raises(InputError, match="--mixed needs at least 2"):
        run(EvalConfig(kb=(str(kb),), test="*", mixed=1, keep_motions=str(tmp_path / "keep")))
    with pytest.raises(InputError, match="matches none"):
        run(EvalConfig(kb=(str(kb),), test="nothing*", json=str(tmp_path / "E.json")))
    assert sorted(p.name for p in tmp_path.iterdir()) == []
