"""Evaluation with devices worn as in the field: a calibration pose put before the
clip, the devices' mountings calibrated from it without the hidden clips, and only the
clip scored."""

from dataclasses import replace

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.evaluate import loo
from graphsvc.evaluate.run import EvalConfig, run
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.pipeline import Options
from graphsvc.sensors.layout import layout_from_dict
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.strategies.options import Weights

MOUNTED = replace(NOISE["none"], mount=30.0)
OPTIONS = Options(weights=Weights(0.5, 1, 1), smooth_s=0.0)


@pytest.fixture(scope="module")
def kb_graph():
    kb = generate_knowledge_base(seed=0, minutes=1.1)
    graph, _ = build_graph(kb, BuildOptions(progress=False))
    return kb, graph


def _setup(noise, seconds):
    return loo.EvalSetup(
        noise=noise, positions=True, options=OPTIONS, seed=7, calibrate_from_start=seconds, calibration_pose="npose"
    )


def test_the_clips_part_is_cut_out_calibrated_and_restarted_at_zero(kb_graph):
    kb, graph = kb_graph
    truth = kb[0]
    layout = layout_from_dict(graph.layout)
    rec, done = loo.calibrated_test_input(graph, truth, layout, _setup(MOUNTED, 10.0), None, [])
    assert rec.num_samples == truth.num_frames
    assert rec.timestamps_s[0] == 0.0
    assert np.allclose(np.diff(rec.timestamps_s), 1.0 / graph.rate_hz)
    assert rec.meta.get("sensor_frame") != "device"
    # Noise-free devices turned by up to 30°: the N-pose and the 8 s of motion after it
    # give the mountings back within 2° (the bound for an N-pose start; the pose
    # alone, 2 s, leaves two sensors' rotation about gravity unseen: 18° and 22° off).
    assert done["calibration_error_deg"] < 2.0
    assert done["calibration_flagged"] == []


def test_calibrated_run_scores_as_the_run_without_a_mounting(kb_graph):
    kb, graph = kb_graph
    plain = loo.evaluate_clip(
        graph, kb[0], None, loo.EvalSetup(noise=NOISE["none"], positions=True, options=OPTIONS, seed=7)
    )
    worn = loo.evaluate_clip(graph, kb[0], None, _setup(MOUNTED, 10.0))
    assert worn["frames"] == plain["frames"]
    assert abs(worn["joint_err_cm"] - plain["joint_err_cm"]) < 0.2
    assert worn["calibration_error_deg"] < 2.0


def test_the_hidden_clips_are_left_out_of_the_calibration(kb_graph, monkeypatch):
    import graphsvc.graph.calibration as calibration

    kb, graph = kb_graph
    seen = []
    real = calibration.calibrate_from_start

    def spy(rec, g, seconds, pose, hidden_clips=()):
        seen.append(list(hidden_clips))
        return real(rec, g, seconds, pose, hidden_clips=hidden_clips)

    monkeypatch.setattr(calibration, "calibrate_from_start", spy)
    loo.evaluate_clip(graph, kb[1], 1, _setup(MOUNTED, 10.0))
    assert seen == [[graph.clips[1]["name"]]]


@pytest.mark.parametrize(
    "seconds, pose, words",
    [(3.0, "npose", "seconds ≥ 4"), (float("nan"), "npose", "finite"), (10.0, "splits", "unknown calibration pose")],
)
def test_bad_calibration_arguments_are_refused_before_anything_runs(tmp_path, seconds, pose, words):
    config = EvalConfig(
        kb=(str(tmp_path / "missing"),),
        test="*.bvh",
        calibrate_from_start=seconds,
        calibration_pose=pose,
        progress=False,
    )
    with pytest.raises(InputError, match=words):
        run(config)


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--calibrate-from-start", "3"], "seconds ≥ 4"),
        (["--pose", "tpose"], "--pose goes with --calibrate-from-start"),
    ],
)
def test_the_cli_refuses_in_one_line(tmp_path, capsys, extra, words):
    from graphsvc.cli import main

    (tmp_path / "a.bvh").write_text("not read")
    code = main(["evaluate", str(tmp_path / "a.bvh"), "--test", "a.bvh", "--quiet", *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0], err
