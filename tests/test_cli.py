"""The CLI end to end: real files in, exit codes and one-line errors out."""

import json
import subprocess
import sys

import numpy as np
import pytest

from graphsvc.cli import main
from tests.conftest import write_gliding_clip, write_procedural_kb


@pytest.fixture
def clip(tmp_path):
    return write_gliding_clip(tmp_path)


def run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_simulate_then_inspect_recording(tmp_path, clip, capsys):
    rec = tmp_path / "walk.rec"
    code, out, _ = run(
        ["simulate", str(clip), "--layout", "kelly6", "--noise", "default", "--seed", "2", "-o", str(rec)], capsys
    )
    assert code == 0 and "40 samples of 6 sensors" in out
    code, out, _ = run(["inspect", str(rec), "--json"], capsys)
    info = json.loads(out)["recordings"][0]
    assert code == 0 and info["samples"] == 40 and len(info["sensors"]) == 6
    assert "ground_position.x" in info["channels"]


def test_inspect_motion_folder_totals(tmp_path, clip, capsys):
    code, out, _ = run(["inspect", str(tmp_path), "--json"], capsys)
    info = json.loads(out)
    assert code == 0
    assert info["totals"] == {"clips": 1, "frames": 40, "duration_s": pytest.approx(40 / 30), "rates_hz": [30.0]}
    assert info["clips"][0]["labels"][0] == "walk_demo"  # take number dropped
    code, out, _ = run(["inspect", str(clip)], capsys)
    assert "total: 1 clips, 40 frames at 30 Hz" in out


def test_inspect_and_mapping_count_joints_not_end_sites(tmp_path, capsys):
    (tmp_path / "two.bvh").write_text(  # a root, one joint, two End Sites: 2 joints
        "HIERARCHY\nROOT hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
        " JOINT spine\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n"
        "  End Site\n  {\n   OFFSET 0 10 0\n  }\n }\n End Site\n {\n  OFFSET 0 -10 0\n }\n}\n"
        "MOTION\nFrames: 2\nFrame Time: 0.0333333\n0 90 0 0 0 0 0 0 0\n0 90 0 0 0 0 0 0 0\n"
    )
    code, out, _ = run(["inspect", str(tmp_path / "two.bvh"), "--json"], capsys)
    assert code == 0 and json.loads(out)["clips"][0]["joints"] == 2
    _, _, err = run(["mapping", str(tmp_path / "two.bvh")], capsys)  # (exit 2: no canonical joints found)
    assert err.startswith("2 joints;"), err


def test_simulate_csv_output(tmp_path, clip, capsys):
    out_csv = tmp_path / "walk.csv"
    code, _, _ = run(["simulate", str(clip), "--layout", "right-wrist", "-o", str(out_csv)], capsys)
    assert code == 0
    lines = out_csv.read_text().splitlines()
    assert lines[0].startswith("#") and sum(not line.startswith("#") for line in lines) == 41
    code, out, _ = run(["inspect", str(out_csv)], capsys)
    assert code == 0 and "40 samples of 1 sensors (r_wrist)" in out


@pytest.mark.parametrize(
    "argv_tail, needle",
    [
        (["inspect", "{tmp}/missing.bvh"], "missing.bvh: no such file"),
        (["inspect", "{tmp}/notes.txt"], "unknown format"),
        (["simulate", "{clip}", "--layout", "elbows", "-o", "{tmp}/x.rec"], "unknown layout"),
        (["simulate", "{clip}", "--layout", "kelly6", "--noise", "loud", "-o", "{tmp}/x.rec"], "noise preset"),
        (["simulate", "{clip}", "--layout", "kelly6", "-o", "{tmp}/no/such/dir/x.rec"], "does not exist"),
        (["simulate", "{bad}", "--layout", "kelly6", "-o", "{tmp}/x.rec"], "{bad}"),
        (["simulate", "{clip}", "--layout", "kelly6"], "required"),
        (["simulate", "{clip}", "--layout", "kelly6", "-o", "{tmp}/s.txt"], ".rec (binary) or .csv"),
        (["inspect", "{tmp}/empty"], "no motion files or recordings found"),
        (["synthesize", "{tmp}/g.graph", "{tmp}/x.rec", "-o", "{tmp}/o.bvh", "--weights", "-1,1,1"], "≥ 0"),
        (["synthesize", "{tmp}/g.graph", "{tmp}/x.rec", "-o", "{tmp}/o.bvh", "--weights", "0,0,0"], "all 0"),
    ],
)
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, clip, capsys, argv_tail, needle):
    (tmp_path / "notes.txt").write_text("hello")
    (tmp_path / "empty").mkdir()
    bad = tmp_path / "broken.bvh"
    bad.write_text(clip.read_text().replace("MOTION", "MOTON"))
    subs = {"{tmp}": str(tmp_path), "{clip}": str(clip), "{bad}": str(bad)}
    argv = [a for a in argv_tail]
    for k, v in subs.items():
        argv = [a.replace(k, v) for a in argv]
        needle = needle.replace(k, v)
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(SystemExit) if "required" in needle else _noop():
        code, out, err = run(argv, capsys)
        assert code == 2
        assert len(err.strip().splitlines()) == 1 and needle.lower() in err.lower()
        assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


class _noop:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_console_script_exit_code_and_no_traceback(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "graphsvc.cli", "inspect", str(tmp_path / "nope.bvh")], capture_output=True, text=True
    )
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


# ---------------------------------------------------------------- evaluate


@pytest.fixture(scope="module")
def procedural_kb(tmp_path_factory):
    """Five procedural clips (stop, forehand, idle, overhead, backhand) as BVH files."""
    return write_procedural_kb(tmp_path_factory.mktemp("kb"), seed=0, minutes=0.5)


def test_evaluate_writes_json_and_prints_a_table(tmp_path, procedural_kb, capsys):
    out_json = tmp_path / "eval.json"
    code, out, err = run(
        [
            "evaluate",
            str(procedural_kb),
            "--test",
            "idle_*.bvh",
            "--layout",
            "kelly6",
            "--weights",
            "0.5,1,1",
            "--json",
            str(out_json),
            "--quiet",
        ],
        capsys,
    )
    assert code == 0, err
    result = json.loads(out_json.read_text())
    assert {"clips", "mean"} <= set(result)
    assert [c["file"] for c in result["clips"]] == ["idle_01.bvh"]
    for row in (result["clips"][0], result["mean"]):
        for key in ("joint_err_cm", "root_err_cm", "heading_err_deg", "samples_per_s"):
            assert isinstance(row[key], float) and np.isfinite(row[key]), key
        # idle_01 is the knowledge base's only idle clip: held out, no node carries its
        # label, so label accuracy does not apply (null; n/a in the table).
        assert row["label_acc"] is None
    assert result["clips"][0]["hidden_nodes"] > 0 and result["mean"]["clips"] == 1
    assert result["config"]["positions"] is True  # the default noise has a tracker
    lines = out.splitlines()
    assert lines[0].split()[:2] == ["clip", "frames"]
    assert any(line.startswith("idle_01.bvh") and "n/a" in line for line in lines)
    assert any(line.startswith("mean of 1 clips") for line in lines)
    assert "leave-one-out" in lines[-1]


def test_evaluate_with_a_prebuilt_graph_matches_the_clips(tmp_path, procedural_kb, capsys):
    graph = tmp_path / "kb.graph"
    assert run(["build", str(procedural_kb), "-o", str(graph), "--quiet", "--layout", "kelly6"], capsys)[0] == 0
    code, _, err = run(
        ["evaluate", str(procedural_kb), "--test", "idle_01.bvh", "--graph", str(graph), "--noise", "none", "--quiet"],
        capsys,
    )
    assert code == 0, err
    assert "note:" not in err  # matched by content hash, so the clip is hidden
    code, _, err = run(
        ["evaluate", str(procedural_kb), "--test", "idle_01.bvh", "--graph", str(graph), "--layout", "wrists-ankles"],
        capsys,
    )
    assert code == 2 and "kelly6" in err


def test_evaluate_hold_out_protocols(tmp_path, procedural_kb, capsys):
    out_json = tmp_path / "eval.json"
    rows = {}
    for protocol in ("clip", "content"):
        code, out, err = run(
            [
                "evaluate",
                str(procedural_kb),
                "--test",
                "*_01.bvh",
                "--noise",
                "none",
                "--hold-out",
                protocol,
                "--json",
                str(out_json),
                "--quiet",
            ],
            capsys,
        )
        assert code == 0, err
        result = json.loads(out_json.read_text())
        assert result["config"]["hold_out"] == protocol and f"(hold-out {protocol})" in out.splitlines()[-1]
        rows[protocol] = {r["file"]: r for r in result["clips"]}
    # Each procedural clip is the only one of its label: content hides the same clip, and
    # neither scores a label (no searchable node carries it); the groups are reported apart.
    for name, r in rows["content"].items():
        assert r["label_acc"] is None and rows["clip"][name]["label_acc"] is None
        assert r["hidden_nodes"] == rows["clip"][name]["hidden_nodes"]
    assert set(result["groups"]) == {"locomotion", "gestures"}
    assert "locomotion (1 clips)" in out


def test_evaluate_mixed_joins_the_test_clips(tmp_path, procedural_kb, capsys):
    out_json = tmp_path / "mixed.json"
    code, out, err = run(
        [
            "evaluate",
            str(procedural_kb),
            "--test",
            "*.bvh",
            "--mixed",
            "2",
            "--noise",
            "none",
            "--json",
            str(out_json),
            "--quiet",
        ],
        capsys,
    )
    assert code == 0, err
    result = json.loads(out_json.read_text())
    rows = result["clips"]
    assert len(rows) == 2 and [r["file"] for r in rows] == ["mixed_01", "mixed_02"]  # five clips: two pairs
    for r in rows:
        parts = r["joined"].split(" + ")
        assert len(parts) == 2 and parts[0].split("_")[0] != parts[1].split("_")[0]
        assert r["hidden_nodes"] > 0 and r["label"] == "mixed"
    assert result["config"]["mixed"] == 2
    assert "2 joined performances of 2 actions" in out.splitlines()[-1]


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--test", "*_009.bvh"], "matches none"),
        (["--test", "idle_*.bvh", "--mixed", "2"], "--mixed 2"),
        (["--test", "*.bvh", "--mixed", "1"], "at least 2"),
        (["--test", "*.bvh", "--layout", "elbows"], "unknown layout"),
        (["--test", "*.bvh", "--weights", "1,x,1"], "weights"),
        (["--test", "*.bvh", "--weights", "1,1"], "weights"),
        (["--test", "*.bvh", "--noise", "loud"], "noise preset"),
        (["--test", "*.bvh", "--strategy", "ssg"], "give the set to simulate, --markers"),
        (
            ["--test", "*.bvh", "--strategy", "ssg", "--markers", "hands-feet", "--keep", "l_ear"],
            "defines no marker l_ear",
        ),
        (["--test", "*.bvh", "--strategy", "ssg", "--markers", "hands-feet", "--gap-fraction", "1.5"], "gap fraction"),
        (["--test", "*.bvh", "--flicker", "0.1"], "apply to a strategy that reads optical markers"),
        (["--test", "*.bvh", "--beam", "0"], "beam"),
        (["--test", "*.bvh", "--beam", "nan"], "beam"),
        (["--test", "*.bvh", "--json", "{tmp}/no/such/dir/x.json"], "does not exist"),
        (["--test", "idle_*.bvh", "--hold-out", "actor"], "hides every clip"),  # (one procedural performer)
        (["--test", "idle_*.bvh", "--hold-out", "actor", "--actors", "{tmp}/none.json"], "actor map: "),
    ],
)
def test_evaluate_bad_input_one_line_exit_2(tmp_path, procedural_kb, capsys, extra, needle):
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = ["evaluate", str(procedural_kb)] + [a.replace("{tmp}", str(tmp_path)) for a in extra]
    code, _, err = run(argv, capsys)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and needle in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_the_path_summary_never_prints_a_run_as_zero_seconds():
    from graphsvc.cli.reconstruction import _seconds

    assert _seconds(1 / 30) == "0.03 s" and _seconds(2 / 30) == "0.07 s" and _seconds(0.1) == "0.1 s"
    assert _seconds(3 / 30) == "0.1 s" and _seconds(12.04) == "12.0 s"
