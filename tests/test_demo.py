import numpy as np

from graphsvc.demo import format_demo_summary, run_demo
from graphsvc.motion.library import load_motion
from graphsvc.motion.procedural import CONTENT_LABELS
from graphsvc.sensors.recording import import_csv, load_recording


def test_demo_writes_readable_outputs_deterministically(tmp_path, demo_run):
    first, a = demo_run
    second = run_demo(tmp_path / "b", seed=0, minutes=0.6)
    b = tmp_path / "b"
    names = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file())
    assert {
        "performance.bvh",
        "performance.rec",
        "performance.csv",
        "sensors.png",
        "reconstruction.bvh",
        "side_by_side.bvh",
        "error.png",
        "report.html",
    } <= set(names)
    assert len([n for n in names if n.startswith("kb/")]) == first["kb_clips"]
    for n in names:  # same seed, same bytes, plot included
        assert (a / n).read_bytes() == (b / n).read_bytes(), n

    perf = load_motion(a / "performance.bvh")
    rec = load_recording(a / "performance.rec")
    assert rec.num_samples == perf.num_frames == first["samples"]
    assert rec.num_sensors == 6 and rec.ground_position is not None
    csv = import_csv(a / "performance.csv")
    np.testing.assert_allclose(csv.accelerations, rec.accelerations, rtol=1e-6, equal_nan=True)
    kb_labels = {load_motion(p).labels[0] for p in (a / "kb").glob("*.bvh")}
    assert kb_labels == set(first["kb_seconds_by_label"]) <= set(CONTENT_LABELS)  # file names keep labels
    assert "held-out performance" in format_demo_summary(first)

    # The reconstruction: same skeleton and length as the performance, scored.
    recon = load_motion(a / "reconstruction.bvh")
    assert recon.num_frames == perf.num_frames and recon.skeleton.names == perf.skeleton.names
    np.testing.assert_allclose(recon.skeleton.offsets, perf.skeleton.offsets, atol=1e-6)
    assert (a / "error.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    metrics = first["metrics"]
    assert set(metrics) == {"joint_err_cm", "root_err_cm", "heading_err_deg", "label_acc"}
    assert all(np.isfinite(v) and v >= 0 for v in metrics.values()) and 0 <= metrics["label_acc"] <= 1
    assert metrics["joint_err_cm"] < 40 and first["samples_per_s"] > 0
    text = format_demo_summary(first)
    assert "joint error" in text and "samples/s" in text and "reconstruction.bvh" in text
    assert first["timings"].keys() == second["timings"].keys()


def test_side_by_side_holds_both_figures_apart():
    from graphsvc.demo import side_by_side
    from graphsvc.motion.kinematics import motion_fk
    from graphsvc.motion.procedural import generate_knowledge_base

    a, b = generate_knowledge_base(seed=0, minutes=0.2)[:2]
    n = min(a.num_frames, b.num_frames)
    a = a.copy(rotations=a.rotations[:n], translations=a.translations[:n])
    b = b.copy(rotations=b.rotations[:n], translations=b.translations[:n])
    both = side_by_side(a, b, 1.5)
    J = a.skeleton.num_joints
    _, world = motion_fk(both)
    _, wa = motion_fk(a)
    _, wb = motion_fk(b)
    np.testing.assert_allclose(world[:, 1 : J + 1], wa, atol=1e-9)
    np.testing.assert_allclose(world[:, J + 1 :], wb + [1.5, 0.0, 0.0], atol=1e-9)


def test_the_threaded_kernels_compile_ahead_in_a_process_that_exits_cleanly():
    # (With the suite's kernels already in numba's cache the process only loads them.)
    from graphsvc import precompile

    process = precompile.start()
    assert process is not None
    precompile.wait(process, timeout_s=300)
    assert process.returncode == 0
    precompile.wait(None)  # (nothing started: nothing to wait for)
