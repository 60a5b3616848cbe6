"""`graphsvc evaluate` as a user meets it: what its JSON points at, and every argument
checked before anything is printed or searched."""

from __future__ import annotations

import json

import pytest

from graphsvc.cli import main
from tests.conftest import write_procedural_kb

UNKNOWN_BVH = (  # a skeleton no built-in joint map knows
    "HIERARCHY\nROOT Torso\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n"
    " JOINT Noggin\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n"
    "  End Site\n  {\n   OFFSET 0 10 0\n  }\n }\n}\n"
    "MOTION\nFrames: 2\nFrame Time: 0.0333333\n0 90 0 0 0 0 0 0 0\n0 90 0 0 0 0 0 0 0\n"
)


@pytest.fixture(scope="module")
def kb(tmp_path_factory):
    return write_procedural_kb(tmp_path_factory.mktemp("kb"), seed=5, minutes=0.3)


def test_a_page_without_kept_motions_leaves_a_json_that_says_so(kb, tmp_path, capsys):
    clip = sorted(p.name for p in kb.glob("*.bvh"))[0]
    argv = [
        "evaluate",
        str(kb),
        "--test",
        clip,
        "--layout",
        "kelly6",
        "--hold-out",
        "clip",
        "--quiet",
        "--strategy",
        "nearest",
        "--json",
        str(tmp_path / "E.json"),
        "--report-html",
        str(tmp_path / "E.html"),
    ]
    assert main(argv) == 0
    capsys.readouterr()
    result = json.loads((tmp_path / "E.json").read_text())
    assert "keep_motions" not in result["config"] and all("kept" not in r for r in result["clips"])
    assert (tmp_path / "E.html").stat().st_size > 0
    # `report E.json` says what to do, not that a file was moved
    assert main(["report", str(tmp_path / "E.json"), "-o", str(tmp_path / "again.html")]) == 2
    err = capsys.readouterr().err
    assert "--keep-motions" in err and "does not exist" not in err and len(err.strip().splitlines()) == 1


def test_a_test_clip_of_an_unknown_skeleton_is_refused_before_any_note(kb, tmp_path, capsys):
    graph = tmp_path / "kb.graph"
    assert main(["build", str(kb), "-o", str(graph), "--layout", "kelly6", "--quiet", "--no-bridges"]) == 0
    capsys.readouterr()
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "odd_take.bvh").write_text(UNKNOWN_BVH)
    code = main(["evaluate", str(tmp_path / "other"), "--test", "odd*", "--graph", str(graph), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("graphsvc: error: test clip odd_take: unknown skeleton"), err
    assert "note:" not in err and len(err.strip().splitlines()) == 1


def test_the_json_says_what_a_viewer_sees_of_the_output_and_of_the_truth(kb, tmp_path, capsys):
    import numpy as np

    from graphsvc.evaluate.metrics import PLAUSIBILITY, jitter_km_s3, skate_cm_s
    from graphsvc.motion.joints import CANONICAL, joint_map
    from graphsvc.motion.kinematics import motion_fk
    from graphsvc.motion.library import load_motion

    clips = sorted(p.name for p in kb.glob("*.bvh"))[:2]
    out = tmp_path / "E.json"
    assert (
        main(
            [
                "evaluate",
                str(kb),
                "--test",
                ",".join(clips),
                "--layout",
                "kelly6",
                "--hold-out",
                "clip",
                "--quiet",
                "--strategy",
                "nearest",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "jitter out/truth" in printed and "scaled cm" in printed
    e = json.loads(out.read_text())
    for row in e["clips"]:
        # the graph's skeleton is the test clip's: its bones already have the truth's
        # lengths, so the pose error on them is the joint error
        assert row["joint_err_scaled_cm"] == pytest.approx(row["joint_err_cm"], abs=1e-6)
        for key in PLAUSIBILITY:
            assert row[key] >= 0 and row[f"truth_{key}"] >= 0
        # the truth's figures, computed here from the clip itself (30 Hz, the graph's rate)
        truth = load_motion(kb / row["file"])
        table = joint_map(truth.skeleton)
        pos = motion_fk(truth)[1][:, [table[c] for c in CANONICAL]]
        assert row["truth_jitter_km_s3"] == pytest.approx(jitter_km_s3(pos, 30.0)[1], rel=1e-9)
        feet = [CANONICAL.index("l_ankle"), CANONICAL.index("r_ankle")]
        assert row["truth_skate_cm_s"] == pytest.approx(skate_cm_s(pos, 30.0, feet)[1], rel=1e-9)
    frames = np.array([r["frames"] for r in e["clips"]], dtype=float)
    for key in ("jitter_km_s3", "truth_skate_cm_s", "joint_err_scaled_cm"):  # the summary: frame-weighted means
        want = float(np.sum(frames * [r[key] for r in e["clips"]]) / frames.sum())
        assert e["mean"][key] == pytest.approx(want)


def test_pose_oracle_adds_the_floor_to_the_json_and_the_table(kb, tmp_path, capsys):
    clip = sorted(p.name for p in kb.glob("*.bvh"))[0]
    out = tmp_path / "E.json"
    assert (
        main(
            [
                "evaluate",
                str(kb),
                "--test",
                clip,
                "--layout",
                "kelly6",
                "--hold-out",
                "clip",
                "--quiet",
                "--strategy",
                "nearest",
                "--pose-oracle",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    assert "oracle cm" in capsys.readouterr().out
    e = json.loads(out.read_text())
    row = e["clips"][0]
    assert 0 < row["oracle_joint_err_cm"] <= row["joint_err_cm"]
    assert e["mean"]["oracle_joint_err_cm"] == pytest.approx(row["oracle_joint_err_cm"])


def test_a_performer_s_proportions_are_what_is_scored(kb, tmp_path, capsys):
    from graphsvc.motion.bvh import read_bvh
    from graphsvc.motion.procedural.body import standard_skeleton
    from graphsvc.motion.proportions import SEGMENTS, segment_lengths

    clip = sorted(p.name for p in kb.glob("*.bvh"))[0]
    base = [
        "evaluate",
        str(kb),
        "--test",
        clip,
        "--layout",
        "kelly6",
        "--hold-out",
        "clip",
        "--quiet",
        "--strategy",
        "nearest",
    ]
    runs = {}
    for name, extra in (("plain", []), ("same", ["--height", "1.75"]), ("tall", ["--height", "1.96"])):
        out = tmp_path / f"{name}.json"
        keep = tmp_path / f"kept_{name}"
        assert main([*base, *extra, "--json", str(out), "--keep-motions", str(keep)]) == 0, capsys.readouterr().err
        runs[name] = json.loads(out.read_text())
    capsys.readouterr()
    plain, same, tall = (runs[n]["clips"][0] for n in ("plain", "same", "tall"))
    # the knowledge base's own height (1.75 m): the same reconstruction, the same scores
    assert same["joint_err_cm"] == pytest.approx(plain["joint_err_cm"], abs=1e-6)
    assert "performer" not in runs["plain"]["config"]
    cfg = runs["tall"]["config"]["performer"]
    assert cfg["height_m"] == pytest.approx(1.96, abs=1e-4) and cfg["file"] is None
    # 12 % taller than the truth: scored on those proportions, the error grows; on the
    # truth's bone lengths (the pelvis lowered with the legs) it is the pose's, as before
    assert tall["joint_err_cm"] > plain["joint_err_cm"] + 1.0
    assert tall["joint_err_scaled_cm"] == pytest.approx(plain["joint_err_scaled_cm"], abs=1e-6)
    kb_lengths = segment_lengths(standard_skeleton())
    kept = segment_lengths(read_bvh(tmp_path / "kept_tall" / tall["kept"]["output"]).skeleton)
    for name in SEGMENTS:
        assert kept[name] == pytest.approx(1.12 * kb_lengths[name], abs=1e-6), name


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--height", "1.8", "--performer", "p.json"], "not allowed with argument"),
        (["--performer", "absent.json"], "no such file"),
        (["--performer-mapping", "guess"], "--performer-mapping applies"),
    ],
)
def test_a_bad_performer_is_refused_before_any_work(kb, tmp_path, capsys, extra, needle):
    clip = sorted(p.name for p in kb.glob("*.bvh"))[0]
    extra = [str(tmp_path / e) if e.endswith(".json") else e for e in extra]
    try:
        code = main(["evaluate", str(kb), "--test", clip, "--quiet", "--json", str(tmp_path / "E.json"), *extra])
    except SystemExit as exc:  # (argparse's refusals)
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "E.json").exists()
