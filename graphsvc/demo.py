"""`graphsvc demo`: the whole pipeline on the embedded procedural knowledge base.

Generates a knowledge base and a held-out performance (different seed, never in
the knowledge base), simulates the performance's sensors with the default
noise, builds the knowledge base's motion graph, reconstructs the performance from
its recording and scores it (the metrics of docs/evaluation.md). Writes BVH files (knowledge base,
performance, reconstruction, both side by side), the recording (native and CSV), a
PNG of the sensor streams and a PNG of the per-frame errors.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np

from graphsvc import precompile
from graphsvc.errors import GraphsvcError
from graphsvc.evaluate.metrics import truth_errors
from graphsvc.evaluate.report import plot_errors
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion import signals
from graphsvc.motion.bvh import write_bvh
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base, generate_performance
from graphsvc.motion.skeleton import Motion, Skeleton
from graphsvc.pipeline import Options, reconstruct
from graphsvc.report.gather import clip_view
from graphsvc.report.html import write_html
from graphsvc.sensors.layout import load_layout
from graphsvc.sensors.noise import PRESETS
from graphsvc.sensors.plot import plot_recording
from graphsvc.sensors.recording import export_csv, save_recording
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.options import Weights
from graphsvc.strategies.sources import path_readings, timeline_from_nodes
from graphsvc.strategies.viterbi.batch import warm_up_search
from graphsvc.synthesis.path import warm_up_synthesis

BVH_UNITS_PER_M = 100.0  # centimetres, what most BVH viewers expect
SIDE_BY_SIDE_M = 1.5  # x distance between the two figures of side_by_side.bvh


def side_by_side(left: Motion, right: Motion, dx_m: float = SIDE_BY_SIDE_M) -> Motion:
    """Both motions in one skeleton, for viewers that open one file at a time: a
    still root "world" (position channels only, at the origin) carrying `left`'s
    joints prefixed "true_" and `right`'s prefixed "reconstructed_", the latter moved
    `dx_m` metres along +X. Needs equal frame counts and rates; each keeps its
    skeleton's bone offsets and channels."""
    if left.num_frames != right.num_frames or left.rate_hz != right.rate_hz:
        raise GraphsvcError("side by side needs two motions with the same frames and rate")
    F = left.num_frames
    names, parents, offsets, channels, end_site = (
        ["world"],
        [-1],
        [np.zeros(3)],
        [("Xposition", "Yposition", "Zposition")],
        [False],
    )
    rot = [np.tile([1.0, 0.0, 0.0, 0.0], (F, 1, 1))]
    trans = [np.zeros((F, 1, 3))]
    for prefix, m, dx in (("true_", left, 0.0), ("reconstructed_", right, dx_m)):
        sk = m.skeleton
        base = len(names)
        names += [prefix + n for n in sk.names]
        parents += [0 if p < 0 else base + int(p) for p in sk.parents]
        offsets += list(sk.offsets)
        channels += list(sk.channels)
        end_site += list(sk.end_site)
        t = m.translations.copy()
        t[:, 0, 0] += dx  # the root's translation places the whole figure
        rot.append(m.rotations)
        trans.append(t)
    skeleton = Skeleton(tuple(names), np.array(parents), np.array(offsets), tuple(channels), np.array(end_site))
    return Motion(
        skeleton,
        np.concatenate(rot, axis=1),
        np.concatenate(trans, axis=1),
        left.rate_hz,
        name="side_by_side",
        source="graphsvc demo",
    )


KNOWLEDGE_BASES = ("procedural", "pybullet")
PYBULLET_RATE_HZ = 30.0  # the graph's rate on pybullet's clips (they come at 16 to 60 Hz)
PYBULLET_HELD_OUT = "turn_left_1"  # its twin turn_left_0 stays in the knowledge base


def pybullet_knowledge_base(held_out: str = PYBULLET_HELD_OUT) -> tuple[list[Motion], Motion, np.ndarray]:
    """pybullet's sample clips but `held_out` (a name `graphsvc samples` writes), and
    that clip at PYBULLET_RATE_HZ with its per-frame labels: leave one clip out."""
    from graphsvc.motion.resample import resample
    from graphsvc.samples import load_samples

    clips = load_samples()
    names = [c.name for c in clips]
    if held_out not in names:
        raise GraphsvcError(f"no sample clip named {held_out!r} to hold out (choose from {', '.join(names)})")
    held = resample(clips[names.index(held_out)], PYBULLET_RATE_HZ)
    return [c for c in clips if c.name != held_out], held, np.full(held.num_frames, held.labels[0])


def run_demo(
    out_dir: Path,
    seed: int = 0,
    layout_name: str = "kelly6",
    minutes: float = 3.0,
    kb_name: str = "procedural",
    held_out: str = PYBULLET_HELD_OUT,
) -> dict:
    """Run the demo into `out_dir` (created if missing; its parent must exist).
    kb_name: "procedural" (generated by seed, `minutes` long, and a held-out
    performance of another seed) or "pybullet" (pybullet's sample clips but
    `held_out`, which is reconstructed). Returns a summary dict of what was generated,
    written and how long it took."""
    out_dir = Path(out_dir)
    if not out_dir.parent.is_dir():
        raise GraphsvcError(f"output folder {out_dir.parent} does not exist")
    if kb_name not in KNOWLEDGE_BASES:
        raise GraphsvcError(f"unknown knowledge base {kb_name!r} (choose from {', '.join(KNOWLEDGE_BASES)})")
    layout = load_layout(layout_name)  # (an unknown layout refused before anything is written)
    timings = {}
    t0 = time.perf_counter()
    frame_labels: dict = {}  # (each clip's phases: a stop clip walks first, a stroke clip stands between strokes)
    if kb_name == "pybullet":  # (pybullet missing or an unknown clip refused before anything is written)
        kb, performance, performance_labels = pybullet_knowledge_base(held_out)
    (out_dir / "kb").mkdir(parents=True, exist_ok=True)
    # numba's threaded search kernels compile in another process meanwhile (`precompile`).
    ahead = precompile.start()
    if kb_name == "procedural":
        kb = generate_knowledge_base(seed=seed, minutes=minutes, frame_labels=frame_labels)
        performance, performance_labels = generate_performance(seed=seed + 1)
    timings["generate_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    kb_files = ["kb/*.bvh"]
    if kb_name == "pybullet":
        from graphsvc.samples import LICENCE_FILE, write_samples

        write_samples(out_dir / "kb", kb)
        kb_files.append(f"kb/{LICENCE_FILE}")
    else:
        for clip in kb:
            write_bvh(out_dir / "kb" / f"{clip.name}.bvh", clip, scale=BVH_UNITS_PER_M)
    write_bvh(out_dir / "performance.bvh", performance, scale=BVH_UNITS_PER_M)
    timings["write_bvh_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
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

    t0 = time.perf_counter()
    graph, _ = build_graph(kb, BuildOptions(rate_hz=performance.rate_hz, layout=layout, progress=False), frame_labels)
    timings["build_graph_s"] = time.perf_counter() - t0
    # numba's first compilation (a fresh install) is listed apart from the reconstruction:
    # the serial search and synthesis kernels here, the threaded ones from the process
    # started above (waited for), then whatever the reconstruction still had to warm.
    t0 = time.perf_counter()
    warm_up_search(graph, threads=False)
    warm_up_synthesis(graph)
    precompile.wait(ahead)
    warm_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    # Kelly et al.'s weights with global data (their Table 3); a stream the recording lacks gets none.
    weights = Weights(0.5, 1.0 if rec.ground_position is not None else 0.0, 1.0 if rec.heading is not None else 0.0)
    result = reconstruct(graph, rec, Options(weights=weights))
    timings["search_warm_up_s"] = warm_s + result.report["timings_s"]["warm_up"]
    timings["reconstruct_s"] = time.perf_counter() - t0 - result.report["timings_s"]["warm_up"]
    t0 = time.perf_counter()
    write_bvh(out_dir / "reconstruction.bvh", result.motion, scale=BVH_UNITS_PER_M)
    write_bvh(out_dir / "side_by_side.bvh", side_by_side(performance, result.motion), scale=BVH_UNITS_PER_M)
    pred_labels = np.asarray(graph.labels)[graph.node_label[result.node_path]]
    scores = truth_errors(result.motion, performance, pred_labels, performance_labels)
    plot_errors(
        out_dir / "error.png",
        graph.rate_hz,
        scores["per_frame"],
        pred_labels,
        performance_labels,
        title=f"reconstruction of the held-out performance ({layout.name}, default noise)",
    )
    timings["write_reconstruction_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    write_html(
        out_dir / "report.html", demo_document(graph, result, rec, performance, scores, pred_labels, layout.name)
    )
    timings["write_report_s"] = time.perf_counter() - t0
    report = result.report

    kb_frames = sum(c.num_frames for c in kb)
    rates = sorted({c.rate_hz for c in kb})
    label_seconds = Counter()
    for c in kb:
        label_seconds[c.labels[0]] += c.duration_s
    segments = [str(performance_labels[0])]
    for label in performance_labels[1:]:
        if label != segments[-1]:
            segments.append(str(label))
    return {
        "out_dir": str(out_dir),
        "kb_name": kb_name,
        "kb_clips": len(kb),
        "kb_frames": kb_frames,
        "kb_minutes": sum(c.duration_s for c in kb) / 60.0,
        "kb_seconds_by_label": dict(sorted(label_seconds.items())),
        "performance_frames": performance.num_frames,
        "performance_seconds": performance.duration_s,
        "performance_segments": segments,
        "contact_fraction": contacts.mean(axis=0).tolist(),
        "layout": layout.name,
        "sensors": list(rec.sensor_names),
        "samples": rec.num_samples,
        "files": kb_files
        + [
            "performance.bvh",
            "performance.rec",
            "performance.csv",
            "sensors.png",
            "reconstruction.bvh",
            "side_by_side.bvh",
            "error.png",
            "report.html",
        ],
        "graph": {"nodes": graph.num_nodes, "edges": graph.num_edges},
        "weights": [weights.acc, weights.position, weights.heading],
        "metrics": {k: scores[k] for k in ("joint_err_cm", "root_err_cm", "heading_err_deg", "label_acc")},
        "samples_per_s": float(report["samples_per_s"]),
        "path_labels": [run["label"] for run in report["labels"]],
        "timings": {k: round(v, 3) for k, v in timings.items()},
        "rate_hz": kb[0].rate_hz,
        "kb_rates_hz": rates,
        "joints": kb[0].skeleton.num_joints_excluding_end_sites,
        "accel_range_g": float(np.nanmax(np.abs(rec.accelerations)) / 9.81),
    }


def demo_document(graph, result, rec, performance: Motion, scores: dict, pred_labels, layout_name: str) -> dict:
    """The demo's report page: the reconstruction beside the held-out performance."""
    m = scores
    info = {
        "strategy": "viterbi",
        "layout": layout_name,
        "joint error": f"{m['joint_err_cm']:.1f} cm",
        "root error": f"{m['root_err_cm']:.1f} cm",
        "labels right": f"{100 * m['label_acc']:.0f} %",
    }
    view = clip_view(
        "held-out performance",
        result.motion,
        timeline_from_nodes(graph, result.node_path),
        rec,
        performance,
        scores["per_frame"],
        labels=list(pred_labels),
        info=info,
        virtual=path_readings(graph, result.node_path),
    )
    return {"title": "graphsvc demo: reconstruction of a held-out performance", "clips": [view], "table": None}


def format_demo_summary(s: dict) -> str:
    digits = 1 if s.get("kb_name") == "pybullet" else 0  # (pybullet's clips last a second or two)
    labels = ", ".join(f"{k} {v:.{digits}f} s" for k, v in s["kb_seconds_by_label"].items())
    m = s["metrics"]
    return "\n".join(
        [
            f"knowledge base: {s['kb_clips']} {s.get('kb_name', 'procedural')} clips, {s['kb_frames']:,} frames "
            f"({s['kb_minutes']:.1f} min) at {'/'.join(f'{r:g}' for r in s.get('kb_rates_hz', [s['rate_hz']]))} Hz, "
            f"{s['joints']} joints",
            f"  by label: {labels}",
            f"held-out performance: {s['performance_seconds']:.1f} s: {' → '.join(s['performance_segments'])}",
            f"  feet in contact: left {100 * s['contact_fraction'][0]:.0f} %, right {100 * s['contact_fraction'][1]:.0f} % of frames",
            f"sensors: {s['layout']} ({', '.join(s['sensors'])}), {s['samples']} samples, "
            f"default noise, peak |a| {s['accel_range_g']:.1f} g",
            f"motion graph: {s['graph']['nodes']:,} nodes, {s['graph']['edges']:,} edges",
            (
                f"reconstruction (weights {','.join(f'{w:g}' for w in s['weights'])}): joint error "
                f"{m['joint_err_cm']:.1f} cm, root error {m['root_err_cm']:.1f} cm, heading error "
                f"{m['heading_err_deg']:.1f}°, label right {100 * m['label_acc']:.0f} % of frames"
            ),
            f"  path: {' → '.join(s['path_labels'][:14])}" + (" …" if len(s["path_labels"]) > 14 else ""),
            f"wrote {s['out_dir']}/: {', '.join(s['files'])}",
            # (the one line that depends on the machine: the rest is the same everywhere)
            "times: "
            + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in s["timings"].items())
            + f"; search {s['samples_per_s']:,.0f} samples/s",
        ]
    )
