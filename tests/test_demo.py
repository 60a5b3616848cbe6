import numpy as np

from graphsvc.demo import format_demo_summary, run_demo
from graphsvc.motion.library import load_motion
from graphsvc.motion.procedural import CONTENT_LABELS
from graphsvc.sensors.recording import import_csv, load_recording


def test_demo_writes_readable_outputs_deterministically(tmp_path):
    first = run_demo(tmp_path / "a", seed=0, minutes=0.6)
    second = run_demo(tmp_path / "b", seed=0, minutes=0.6)
    a, b = tmp_path / "a", tmp_path / "b"
    names = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file())
    assert {"performance.bvh", "performance.rec", "performance.csv", "sensors.png"} <= set(names)
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
    assert first["timings"].keys() == second["timings"].keys()
