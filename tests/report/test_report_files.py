"""`graphsvc report` on what the other commands write: a synthesize report of every
registered strategy, an evaluation with kept motions (`evaluate --keep-motions`,
`--report-html`), a batch folder; and its errors."""

import base64
import json
import shutil

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.motion.joints import CANONICAL
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.library import load_motion
from graphsvc.pipeline import Options, Weights, synthesize_files
from graphsvc.report.load import load_document
from graphsvc.sensors.markers import PRESETS as MARKERS
from graphsvc.strategies import available, get
from tests.conftest import write_procedural_kb


def _positions(fig, T):
    root = np.frombuffer(base64.b64decode(fig["root_mm"]), "<i4").reshape(T, 3)
    rel = np.frombuffer(base64.b64decode(fig["rel_mm"]), "<i2").reshape(T, -1, 3)
    return (root[:, None] + rel) / 1000.0


# (multilinear needs clips named <content>_<style>_<take>, which the procedural knowledge
# base's are not: tests/strategies/test_multilinear.py makes its page)
@pytest.mark.parametrize(
    "strategy", [n for n in available() if type(get(n)).__module__.startswith("graphsvc.") and n != "multilinear"]
)
def test_a_synthesize_report_of_every_strategy_becomes_a_page(files, strategy, capsys):
    d, graph, truth = files
    rec = d / ("markers.rec" if strategy == "ssg" else "take.rec")
    options = Options(strategy=strategy, weights=Weights(0.5, 1, 1))
    synthesize_files(graph, d / "kb.graph", rec, d / f"{strategy}.bvh", options, report_path=d / f"{strategy}.json")
    report = json.loads((d / f"{strategy}.json").read_text())
    assert report["files"]["graph"] == str((d / "kb.graph").resolve())
    assert ("node_path" in report) != ("sources" in report)  # (graph strategies walk nodes; the others blend)

    doc = load_document(d / f"{strategy}.json")
    (view,) = doc["clips"]
    out = load_motion(d / f"{strategy}.bvh")
    T = out.num_frames
    assert view["frames"] == T and view["figures"][0]["name"] == "reconstruction"
    np.testing.assert_allclose(_positions(view["figures"][0], T), motion_fk(out)[1], atol=0.0006)
    segments = view["timeline"]["segments"]
    assert sum(s["frames"] for s in segments) == T and segments[0]["start"] == 0
    assert {s["clip"] for s in segments} <= {c["name"] for c in graph.clips}
    assert (view["timeline"]["neighbours"] is not None) == (strategy in ("olng", "ssg", "piecewise"))
    if strategy == "ssg":
        assert view["sensors"] is None and view["markers"]["names"] == [m.name for m in MARKERS["hands-feet"].markers]
    else:
        assert view["sensors"]["names"] == list(graph.sensor_names) and view["markers"] is None
        virtual = np.frombuffer(base64.b64decode(view["sensors"]["virtual"][0]), "<i2").reshape(T, 3)
        assert (virtual[1:] != -32768).any()  # (the path's readings are there)
    if strategy == "viterbi":  # the constraint set, marked frame by frame over its interval
        (c,) = view["constraints"]
        assert c["first_frame"] == 15 and len(c["met"]) == 30
        labels = [s["label"] for s in segments for _ in range(s["frames"])]
        assert c["met"] == "".join("1" if lab == "stop" else "0" for lab in labels[15:45])

    # With its truth beside it, and through the command line.
    from graphsvc.motion.bvh import write_bvh

    write_bvh(d / "truth.bvh", truth, scale=100.0)
    assert (
        main(
            ["report", str(d / f"{strategy}.json"), "-o", str(d / f"{strategy}.html"), "--truth", str(d / "truth.bvh")]
        )
        == 0
    )
    assert "wrote" in capsys.readouterr().out
    page = (d / f"{strategy}.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and len(page) < 3_000_000


def test_a_page_says_what_a_viewer_sees_of_the_output_and_of_its_truth(files):
    from graphsvc.evaluate.metrics import motion_plausibility
    from graphsvc.pipeline import Options, synthesize_files
    from graphsvc.report.load import synthesize_view

    d, graph, truth = files
    result = synthesize_files(
        graph, d / "kb.graph", d / "take.rec", d / "seen.bvh", Options(strategy="nearest"), report_path=d / "seen.json"
    )
    view = synthesize_view(json.loads((d / "seen.json").read_text()), d, truth=truth)
    out, true = motion_plausibility(load_motion(d / "seen.bvh")), motion_plausibility(truth)
    assert view["info"]["jitter_km_s3"] == pytest.approx(out["jitter_km_s3"], abs=1e-4)
    assert view["info"]["truth_skate_cm_s"] == pytest.approx(true["skate_cm_s"], abs=1e-4)
    assert result.motion.num_frames == view["frames"]


def test_report_refuses_what_it_cannot_show(files, tmp_path, capsys):
    d, _, _ = files
    (tmp_path / "other.json").write_text('{"a": 1}')
    (tmp_path / "broken.json").write_text('{"a": ')
    moved = json.loads((d / "viterbi.json").read_text()) if (d / "viterbi.json").exists() else {"files": {}}
    moved["files"] = {"output": str(tmp_path / "gone.bvh")}
    (tmp_path / "moved.json").write_text(json.dumps(moved))
    (tmp_path / "empty").mkdir()
    for argv, message in [
        ([str(tmp_path / "none.json")], "does not exist"),
        ([str(tmp_path / "other.json")], "not a synthesize report"),
        ([str(tmp_path / "broken.json")], "not valid JSON"),
        ([str(tmp_path / "moved.json")], "gone.bvh does not exist"),
        ([str(tmp_path / "empty")], "no item reports"),
    ]:
        assert main(["report", *argv, "-o", str(tmp_path / "r.html")]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and "\n" not in err, err
    (tmp_path / "eval.json").write_text('{"clips": [], "mean": {}}')
    assert (
        main(
            ["report", str(tmp_path / "eval.json"), "-o", str(tmp_path / "r.html"), "--truth", str(tmp_path / "t.bvh")]
        )
        == 2
    )
    assert "--truth applies to a synthesize report" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists()
    assert main(["report", str(tmp_path / "other.json"), "-o", str(tmp_path / "no" / "r.html")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_a_batch_folder_shows_each_item(files, tmp_path):
    d, _, _ = files
    for name in ("viterbi", "olng"):
        if not (d / f"{name}.json").exists():
            pytest.skip("needs the synthesize test's reports")
        shutil.copy(d / f"{name}.json", tmp_path / f"{name}.json")
    (tmp_path / "summary.json").write_text('{"totals": {}}')
    doc = load_document(tmp_path)
    assert [v["name"] for v in doc["clips"]] == ["olng", "viterbi"]
    assert doc["table"]["rows"][0][:2] == ["olng", "olng"] and doc["table"]["clip"] == [0, 1]


def test_evaluate_keeps_motions_and_writes_the_page(tmp_path, capsys):
    (tmp_path / "kb").mkdir()
    kb = write_procedural_kb(tmp_path / "kb", seed=5, minutes=0.4)
    clips = sorted(p.name for p in kb.glob("*.bvh"))[:2]
    argv = [
        "evaluate",
        str(kb),
        "--test",
        ",".join(clips),
        "--layout",
        "kelly6",
        "--hold-out",
        "clip",
        "--quiet",
        "--json",
        str(tmp_path / "eval.json"),
        "--keep-motions",
        str(tmp_path / "kept"),
        "--report-html",
        str(tmp_path / "eval.html"),
    ]
    assert main(argv) == 0
    capsys.readouterr()
    result = json.loads((tmp_path / "eval.json").read_text())
    assert result["config"]["keep_motions"] == str((tmp_path / "kept").resolve())
    rows = result["clips"]
    assert len(rows) == 2 and all(set(r["kept"]) == {"output", "truth", "recording", "view"} for r in rows)
    for r in rows:
        truth = load_motion(tmp_path / "kept" / r["kept"]["truth"])
        assert truth.num_frames == r["frames"]
    doc = load_document(tmp_path / "eval.json")
    assert [v["name"] for v in doc["clips"]] == [r["name"] for r in rows]
    assert doc["table"]["columns"][:5] == ["clip", "label", "frames", "joint_err_cm", "joint_err_scaled_cm"]
    for row, r in zip(doc["table"]["rows"], rows):
        assert row[4] == pytest.approx(r["joint_err_scaled_cm"], abs=1e-4)
    for v, r in zip(doc["clips"], rows):
        assert [f["name"] for f in v["figures"]] == ["reconstruction", "truth"]
        # the page's errors are the evaluation's own per-frame errors
        assert abs(np.mean(v["errors"]["joint_err_cm"]) - r["joint_err_cm"]) < 0.01
    assert main(["report", str(tmp_path / "eval.json"), "-o", str(tmp_path / "again.html")]) == 0
    assert (tmp_path / "again.html").read_bytes() == (tmp_path / "eval.html").read_bytes()
    # without the kept motions there is nothing to show
    del result["config"]["keep_motions"]
    for r in result["clips"]:
        del r["kept"]
    (tmp_path / "bare.json").write_text(json.dumps(result))
    assert main(["report", str(tmp_path / "bare.json"), "-o", str(tmp_path / "x.html")]) == 2
    assert "--keep-motions" in capsys.readouterr().err


def test_a_truth_on_an_unknown_skeleton_takes_a_joint_map(files, tmp_path, capsys):
    """A truth whose joints graphsvc does not know: its error charts are left out with
    one note saying why; with --mapping they are there, and equal to those of the same
    motion on the known skeleton."""
    from dataclasses import replace

    from graphsvc.motion.bvh import write_bvh

    d, graph, truth = files
    synthesize_files(
        graph,
        d / "kb.graph",
        d / "take.rec",
        tmp_path / "out.bvh",
        Options(weights=Weights(0.5, 1, 1)),
        report_path=tmp_path / "out.json",
    )
    sk = truth.skeleton
    renamed = replace(truth, skeleton=replace(sk, names=tuple(f"Bone{i:02d}" for i in range(len(sk.names)))))
    write_bvh(tmp_path / "odd.bvh", renamed, scale=100.0)
    write_bvh(tmp_path / "known.bvh", truth, scale=100.0)
    mapping = tmp_path / "odd.json"
    mapping.write_text(json.dumps({n: f"Bone{i:02d}" for i, n in enumerate(sk.names) if n in CANONICAL}))

    assert (
        main(
            ["report", str(tmp_path / "out.json"), "-o", str(tmp_path / "a.html"), "--truth", str(tmp_path / "odd.bvh")]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith("note: out: the error charts are left out")
    assert "--mapping" in err
    notes = []
    without = load_document(tmp_path / "out.json", truth=tmp_path / "odd.bvh", notes=notes)
    assert without["clips"][0]["errors"] is None and len(notes) == 1

    assert (
        main(
            [
                "report",
                str(tmp_path / "out.json"),
                "-o",
                str(tmp_path / "b.html"),
                "--truth",
                str(tmp_path / "odd.bvh"),
                "--mapping",
                str(mapping),
            ]
        )
        == 0
    )
    assert capsys.readouterr().err == ""
    mapped = load_document(tmp_path / "out.json", truth=tmp_path / "odd.bvh", truth_mapping=str(mapping))
    known = load_document(tmp_path / "out.json", truth=tmp_path / "known.bvh")
    errors = mapped["clips"][0]["errors"]
    assert errors is not None and errors == known["clips"][0]["errors"]
    assert len(errors["joint_err_cm"]) == mapped["clips"][0]["frames"]

    assert main(["report", str(tmp_path / "out.json"), "-o", str(tmp_path / "c.html"), "--mapping", str(mapping)]) == 2
    assert "give --truth too" in capsys.readouterr().err
