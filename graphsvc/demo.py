"""`graphsvc demo`: the whole pipeline on the embedded procedural knowledge base.

Generates a knowledge base and a held-out performance (different seed, never in
the knowledge base), simulates the performance's sensors with SPEC §2's default
noise, and writes BVH files, the recording (native and CSV) and a PNG of the sensor
streams. Later stages (graph, search) extend this to a reconstruction.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np

from graphsvc.errors import GraphsvcError
from graphsvc.motion import signals
from graphsvc.motion.bvh import write_bvh
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base, generate_performance
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import PRESETS
from graphsvc.sensors.plot import plot_recording
from graphsvc.sensors.recording import export_csv, save_recording
from graphsvc.sensors.simulate import simulate_recording

BVH_UNITS_PER_M = 100.0  # centimetres, what most BVH viewers expect


def run_demo(out_dir: Path, seed: int = 0, layout_name: str = "kelly6", minutes: float = 3.0) -> dict:
    """Run the demo into `out_dir` (created if missing; its parent must exist).
    Returns a summary dict of what was generated, written and how long it took."""
    out_dir = Path(out_dir)
    if not out_dir.parent.is_dir():
        raise GraphsvcError(f"output folder {out_dir.parent} does not exist")
    (out_dir / "kb").mkdir(parents=True, exist_ok=True)
    timings = {}
    t0 = time.perf_counter()
    kb = generate_knowledge_base(seed=seed, minutes=minutes)
    performance, performance_labels = generate_performance(seed=seed + 1)
    timings["generate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    for clip in kb:
        write_bvh(out_dir / "kb" / f"{clip.name}.bvh", clip, scale=BVH_UNITS_PER_M)
    write_bvh(out_dir / "performance.bvh", performance, scale=BVH_UNITS_PER_M)
    timings["write_bvh_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    layout = load_layout(layout_name)
    rec = simulate_recording(performance, layout, PRESETS["default"], seed=seed)
    save_recording(rec, out_dir / "performance.rec")
    export_csv(rec, out_dir / "performance.csv")
    timings["simulate_s"] = time.perf_counter() - t0

    _, world_pos = motion_fk(performance)
    contacts = signals.foot_contacts(world_pos, joint_map(performance.skeleton), performance.rate_hz)
    t0 = time.perf_counter()
    plot_recording(
        rec, out_dir / "sensors.png", title=f"held-out performance, {layout.name}, default noise", contacts=contacts
    )
    timings["plot_s"] = time.perf_counter() - t0

    kb_frames = sum(c.num_frames for c in kb)
    label_seconds = Counter()
    for c in kb:
        label_seconds[c.labels[0]] += c.duration_s
    segments = [str(performance_labels[0])]
    for label in performance_labels[1:]:
        if label != segments[-1]:
            segments.append(str(label))
    return {
        "out_dir": str(out_dir),
        "kb_clips": len(kb),
        "kb_frames": kb_frames,
        "kb_minutes": kb_frames / kb[0].rate_hz / 60.0,
        "kb_seconds_by_label": dict(sorted(label_seconds.items())),
        "performance_frames": performance.num_frames,
        "performance_seconds": performance.duration_s,
        "performance_segments": segments,
        "contact_fraction": contacts.mean(axis=0).tolist(),
        "layout": layout.name,
        "sensors": list(rec.sensor_names),
        "samples": rec.num_samples,
        "files": ["kb/*.bvh", "performance.bvh", "performance.rec", "performance.csv", "sensors.png"],
        "timings": {k: round(v, 3) for k, v in timings.items()},
        "rate_hz": kb[0].rate_hz,
        "joints": kb[0].skeleton.num_joints,
        "accel_range_g": float(np.nanmax(np.abs(rec.accelerations)) / 9.81),
    }


def format_demo_summary(s: dict) -> str:
    labels = ", ".join(f"{k} {v:.0f} s" for k, v in s["kb_seconds_by_label"].items())
    return "\n".join(
        [
            f"knowledge base: {s['kb_clips']} procedural clips, {s['kb_frames']:,} frames "
            f"({s['kb_minutes']:.1f} min) at {s['rate_hz']:g} Hz, {s['joints']} joints",
            f"  by label: {labels}",
            f"held-out performance: {s['performance_seconds']:.1f} s: {' → '.join(s['performance_segments'])}",
            f"  feet in contact: left {100 * s['contact_fraction'][0]:.0f} %, right {100 * s['contact_fraction'][1]:.0f} % of frames",
            f"sensors: {s['layout']} ({', '.join(s['sensors'])}), {s['samples']} samples, "
            f"default noise, peak |a| {s['accel_range_g']:.1f} g",
            f"wrote {s['out_dir']}/: {', '.join(s['files'])}",
            "times: " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in s["timings"].items()),
        ]
    )
