"""`graphsvc calibrate` and `--calibration` end to end: a calibration take → CAL.json →
a match take synthesized as if its sensors had no mounting; bad files refused."""

from __future__ import annotations

import json

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import save_graph
from graphsvc.motion.bvh import read_bvh
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import parse_noise
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording
from tests.sensors.test_calibration import npose_take

LAYOUT = load_layout("wrists-ankles")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A graph of a procedural knowledge base; a calibration take and a match take
    simulated with one seed (one mounting), and the match take without a mounting."""
    d = tmp_path_factory.mktemp("calibrate")
    kb = generate_knowledge_base(seed=3, minutes=1.0)
    graph, _ = build_graph(kb, BuildOptions(layout=LAYOUT, progress=False))
    save_graph(graph, d / "g.graph")
    stop = next(m for m in kb if m.name.startswith("stop"))
    run = next(m for m in kb if m.name.startswith("run"))
    mounted = parse_noise("none,mount=60")
    save_recording(simulate_recording(npose_take(stop), LAYOUT, mounted, seed=9), d / "take.rec")
    save_recording(simulate_recording(run, LAYOUT, mounted, seed=9), d / "match.rec")
    save_recording(simulate_recording(run, LAYOUT, parse_noise("none"), seed=9), d / "free.rec")
    return d


def run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def test_calibrate_then_synthesize_matches_the_mount_free_recording(files, capsys):
    d = files
    cal = d / "cal.json"
    code, out, err = run(
        ["calibrate", str(d / "take.rec"), "--graph", str(d / "g.graph"), "--pose", "npose", "-o", str(cal)], capsys
    )
    assert code == 0, err
    assert out.startswith(f"wrote {cal}: 4 sensors, pose npose") and "l_wrist: mounting" in out
    doc = json.loads(cal.read_text())
    assert doc["format"] == "graphsvc-calibration" and doc["source"] == str(d / "take.rec")
    for name, path in (("calibrated", d / "match.rec"), ("free", d / "free.rec")):
        extra = ["--calibration", str(cal)] if name == "calibrated" else []
        code, _, err = run(["synthesize", str(d / "g.graph"), str(path), "-o", str(d / f"{name}.bvh"), *extra], capsys)
        assert code == 0, err
        assert "note:" not in err
    a, b = (motion_fk(read_bvh(d / f"{n}.bvh"))[1] for n in ("calibrated", "free"))
    assert np.mean(np.linalg.norm(a - b, axis=-1)) < 0.01  # m: the same motion within 1 cm on average
    # Uncalibrated, a device-frame recording is used with a note saying so.
    code, _, err = run(["synthesize", str(d / "g.graph"), str(d / "match.rec"), "-o", str(d / "raw.bvh")], capsys)
    assert code == 0 and "--calibration" in err


def test_calibrate_with_a_span_and_without_a_graph(files, capsys):
    d = files
    code, _, err = run(["calibrate", str(d / "take.rec"), "--pose", "npose", "-o", str(d / "x.json")], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "rotation about gravity" in err
    assert not (d / "x.json").exists()
    code, _, err = run(
        [
            "calibrate",
            str(d / "take.rec"),
            "--graph",
            str(d / "g.graph"),
            "--pose",
            "npose",
            "--from",
            "1.7",
            "--to",
            "2.2",
            "-o",
            str(d / "x.json"),
        ],
        capsys,
    )
    assert code == 2 and ("no still stretch" in err or "needs at least" in err), err
    code, _, err = run(
        [
            "calibrate",
            str(d / "take.rec"),
            "--graph",
            str(d / "g.graph"),
            "--pose",
            "npose",
            "--from",
            "3",
            "--to",
            "1",
            "-o",
            str(d / "x.json"),
        ],
        capsys,
    )
    assert code == 2 and "--from" in err


@pytest.mark.parametrize(
    "content, needle",
    [
        ("{", "not valid JSON"),
        (
            json.dumps(
                {
                    "format": "graphsvc-calibration",
                    "version": 1,
                    "sensors": {"l_wrist": {"rotation_wxyz": [2, 0, 0, 0]}},
                }
            ),
            "unit quaternion",
        ),
        (
            json.dumps(
                {
                    "format": "graphsvc-calibration",
                    "version": 1,
                    "sensors": {"l_wrist": {"rotation_wxyz": [1, 0, 0, 0]}},
                }
            ),
            "not the recording's",
        ),
        (json.dumps({"version": 1}), "not a graphsvc calibration"),
    ],
)
def test_bad_calibration_files_one_line_exit_2(files, capsys, content, needle):
    d = files
    bad = d / "bad.json"
    bad.write_text(content)
    out = d / "never.bvh"
    code, _, err = run(
        ["synthesize", str(d / "g.graph"), str(d / "match.rec"), "-o", str(out), "--calibration", str(bad)], capsys
    )
    assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not out.exists()


def test_a_layout_frame_recording_is_not_calibrated(files, capsys):
    d = files
    cal = d / "ident.json"
    cal.write_text(
        json.dumps(
            {
                "format": "graphsvc-calibration",
                "version": 1,
                "sensors": {n: {"rotation_wxyz": [1, 0, 0, 0]} for n in LAYOUT.sensor_names},
            }
        )
    )
    code, _, err = run(
        ["synthesize", str(d / "g.graph"), str(d / "free.rec"), "-o", str(d / "n.bvh"), "--calibration", str(cal)],
        capsys,
    )
    assert code == 2 and "already in the layout" in err


def test_rest_times_count_from_the_recordings_first_sample(files, capsys):
    """With --from the rest still reads in the recording's own seconds: it starts where
    the span does (the pose is held from the first sample) and ends where the whole
    take's rest ends."""
    d = files
    ends = []
    for extra in ([], ["--from", "0.5"]):
        cal = d / f"rest{len(extra)}.json"
        code, out, err = run(
            [
                "calibrate",
                str(d / "take.rec"),
                "--graph",
                str(d / "g.graph"),
                "--pose",
                "npose",
                *extra,
                "-o",
                str(cal),
            ],
            capsys,
        )
        assert code == 0, err
        a, b = json.loads(cal.read_text())["rest_s"]
        assert f"rest {a:.2f}–{b:.2f} s" in out
        ends.append((a, b))
    (a0, b0), (a1, b1) = ends
    assert a0 == 0.0 and a1 == pytest.approx(0.5, abs=1e-6)
    assert b1 == pytest.approx(b0, abs=0.05) and b0 > 1.4


def test_a_short_noisy_stand_after_other_motion_is_found(files, capsys, tmp_path):
    """2.5 s of running, then a natural stance held 1.3 s (and eased into a punch) from
    noisy devices (σ = 0.9 m/s² a axis: an RMS deviation of 1.56 m/s² at rest): with
    `--from 2.5` the whole held stance is the rest, each window judged by its own
    noise (a fixed bound of 1.5 m/s² refused it, or took a pause 7 s later)."""
    from dataclasses import replace

    from graphsvc.motion.calibration_pose import with_calibration_pose

    kb = generate_knowledge_base(seed=3, minutes=1.0)
    clip = lambda name: next(m for m in kb if m.name.startswith(name))  # noqa: E731
    noise = parse_noise("real,sigma=0.9,mount=30")
    before = simulate_recording(clip("run"), LAYOUT, noise, seed=0)
    take = simulate_recording(with_calibration_pose(clip("punch"), "stand", 1.8), LAYOUT, noise, seed=0)
    n = int(round(2.5 * before.rate_hz))
    cat = lambda a, b: np.concatenate([a[:n], b])  # noqa: E731
    rec = replace(
        take,
        timestamps_s=np.arange(n + take.timestamps_s.size) / take.rate_hz,
        accelerations=cat(before.accelerations, take.accelerations),
        orientations=cat(before.orientations, take.orientations),
        ground_position=cat(before.ground_position, take.ground_position),
        heading=cat(before.heading, take.heading),
    )
    save_recording(rec, tmp_path / "stand.rec")
    cal = tmp_path / "stand.json"
    code, out, err = run(
        [
            "calibrate",
            str(tmp_path / "stand.rec"),
            "--graph",
            str(files / "g.graph"),
            "--pose",
            "stand",
            "--from",
            "2.5",
            "-o",
            str(cal),
        ],
        capsys,
    )
    assert code == 0, err
    a, b = json.loads(cal.read_text())["rest_s"]
    assert a == pytest.approx(2.5, abs=1e-6) and b >= 2.5 + 1.3 - 0.05, (a, b)


def test_an_untrustworthy_calibration_exits_2_unless_forced(files, capsys, tmp_path):
    from graphsvc.sensors.files import read_recording
    from tests.sensors.test_calibration import _wobbled

    save_recording(_wobbled(read_recording(files / "take.rec"), 1), tmp_path / "wobbly.rec")
    cal = tmp_path / "cal.json"
    argv = [
        "calibrate",
        str(tmp_path / "wobbly.rec"),
        "--graph",
        str(files / "g.graph"),
        "--pose",
        "npose",
        "-o",
        str(cal),
    ]
    code, out, err = run(argv, capsys)
    assert code == 2 and not cal.exists() and out == ""
    assert err.strip().splitlines() == [
        "graphsvc: error: calibration not to be trusted: r_wrist (moved during the pose) (--force writes it anyway)"
    ]
    code, out, err = run(argv + ["--force"], capsys)
    assert code == 0 and json.loads(cal.read_text())["problems"] == ["r_wrist (moved during the pose)"]
    assert err.strip().splitlines() == [
        "graphsvc: warning: calibration not to be trusted: r_wrist (moved during the pose)"
    ]
    assert "  r_wrist: mounting" in out and "residual" in out


def test_calibrate_from_start_is_calibrate_then_synthesize(files, capsys):
    """`synthesize --calibrate-from-start 5 --pose npose` on the calibration take gives
    the same BVH, byte for byte, as `calibrate --to 5` and `synthesize --calibration`
    (the calibrating seconds reconstructed too)."""
    d = files
    take, g = str(d / "take.rec"), str(d / "g.graph")
    code, _, err = run(
        ["calibrate", take, "--graph", g, "--pose", "npose", "--to", "5", "-o", str(d / "c5.json")], capsys
    )
    assert code == 0, err
    code, _, err = run(["synthesize", g, take, "--calibration", str(d / "c5.json"), "-o", str(d / "two.bvh")], capsys)
    assert code == 0, err
    code, out, err = run(
        [
            "synthesize",
            g,
            take,
            "--calibrate-from-start",
            "5",
            "--pose",
            "npose",
            "-o",
            str(d / "one.bvh"),
            "--report",
            str(d / "one.json"),
        ],
        capsys,
    )
    assert code == 0, err
    # One note: the calibration's mountings and residuals, as `calibrate` prints them.
    doc = json.loads((d / "c5.json").read_text())
    angles = {n: 2 * np.degrees(np.arccos(min(1.0, abs(s["rotation_wxyz"][0])))) for n, s in doc["sensors"].items()}
    assert err.strip().splitlines() == [
        f"note: calibrated from its first 5 s (npose, rest {doc['rest_s'][0]:.2f}–{doc['rest_s'][1]:.2f} s): "
        + ", ".join(
            f"{n} {angles[n]:.1f}° (residual {doc['sensors'][n]['residual_deg']:.1f}°)" for n in LAYOUT.sensor_names
        )
    ]
    assert (d / "one.bvh").read_bytes() == (d / "two.bvh").read_bytes()
    assert json.loads((d / "one.json").read_text())["files"]["read"]["calibrate_from_start"] == {
        "seconds": 5.0,
        "pose": "npose",
    }


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["--calibrate-from-start", "5", "--pose", "npose", "--calibration", "CAL"], "two ways to calibrate"),
        (["--calibrate-from-start", "5"], "needs --pose"),
        (["--pose", "tpose"], "--pose goes with --calibrate-from-start"),
        (["--calibrate-from-start", "1", "--pose", "npose"], "calibration needs at least 2 s"),
    ],
)
def test_calibrate_from_start_refusals_one_line_exit_2(files, capsys, extra, needle):
    d = files
    cal = d / "ident.json"
    cal.write_text(
        json.dumps(
            {
                "format": "graphsvc-calibration",
                "version": 1,
                "sensors": {n: {"rotation_wxyz": [1, 0, 0, 0]} for n in LAYOUT.sensor_names},
            }
        )
    )
    out = d / "never.bvh"
    extra = [str(cal) if a == "CAL" else a for a in extra]
    code, _, err = run(["synthesize", str(d / "g.graph"), str(d / "take.rec"), "-o", str(out), *extra], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and needle in err, err
    assert not out.exists()


def test_calibrate_from_start_takes_positive_seconds(files, capsys):
    with pytest.raises(SystemExit) as info:
        main(
            [
                "synthesize",
                str(files / "g.graph"),
                str(files / "take.rec"),
                "-o",
                str(files / "never.bvh"),
                "--calibrate-from-start",
                "0",
                "--pose",
                "npose",
            ]
        )
    err = capsys.readouterr().err
    assert info.value.code == 2 and "--calibrate-from-start" in err and "> 0" in err
