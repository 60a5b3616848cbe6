"""Leave-one-clip-out evaluation: what `graphsvc evaluate` runs.

The graph is built once from the whole knowledge base. For each test clip, every
node that carries any of its data is hidden by the strategy's mask
(`Strategy.allowed_mask`; for the graph strategies `graph.holdout.held_out_mask`); the
clip's sensors are simulated, the recording is reconstructed
through `graphsvc.pipeline.reconstruct(..., allowed=mask)` and compared with the clip
itself (`evaluate_clip`). `run_leave_one_out` does this for many clips, optionally in
worker processes that memory-map one graph file.

What a test clip hides is in `graph.holdout`.
Edges touching a hidden node are unusable because the search never enters a hidden
node. The graph's other structure was built with the clip present (the transition
cap keeps each frame's 8 closest transitions, some of which may have pointed into
the hidden clip), so a frame may have fewer usable transitions than in a graph built
without it; rebuilding per clip would cost a full build each.
"""

from __future__ import annotations

import fnmatch
import hashlib
import math
import multiprocessing
import os
import resource
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import numba
import numpy as np

from graphsvc.errors import InputError
from graphsvc.evaluate import oracle
from graphsvc.evaluate.keep import keep_clip, kept_name
from graphsvc.evaluate.metrics import evaluate_frames, plausibility, summarize
from graphsvc.evaluate.protocols import activity
from graphsvc.fileio import StrPath
from graphsvc.graph.build import content_digest
from graphsvc.graph.file import load_graph, save_graph
from graphsvc.graph.holdout import held_out_mask, is_augmented, performance_clips, performance_key  # noqa: F401
from graphsvc.graph.model import MotionGraph
from graphsvc.motion import quat, signals
from graphsvc.motion.joints import CANONICAL, JointMapping, common_joints, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.resample import resample
from graphsvc.motion.skeleton import Motion
from graphsvc.pipeline import Options, put_on_performer, reconstruct
from graphsvc.sensors.layout import Layout, layout_from_dict
from graphsvc.sensors.noise import NoiseModel
from graphsvc.sensors.recording import Recording
from graphsvc.sensors.simulate import MarkerPattern
from graphsvc.strategies import get as get_strategy
from graphsvc.strategies.sources import path_readings, source_readings, timeline_from_nodes, timeline_from_sources


def clip_file_name(source: str, name: str) -> str:
    """What `--test GLOB` is matched against: the source file's name (`walk_001.bvh`),
    or the clip name for clips without a file (procedural ones)."""
    src = str(source or "")
    return Path(src).name if src and ":" not in Path(src).name and Path(src).suffix else str(name)


def select_clips(names: list[str], pattern: str) -> list[int]:
    """Indices of `names` (file names) matching the fnmatch `pattern` — or any of
    several, comma-separated — in order. Case-sensitive, so the selection does not
    depend on the platform."""
    patterns = [p for p in pattern.split(",") if p]
    return [k for k, n in enumerate(names) if any(fnmatch.fnmatchcase(n, p) for p in patterns)]


def match_graph_clips(graph: MotionGraph, motions: list[Motion]) -> list[int | None]:
    """The graph clip index of each motion (None when the graph lacks it): by content
    hash (`sha256` in graph.clips) and name, else by resolved source path and name —
    the hash survives moving the knowledge base, the path a re-export."""
    by_hash: dict[tuple, int] = {}
    by_path: dict[tuple, int] = {}
    for k, c in enumerate(graph.clips):
        by_hash.setdefault((c.get("sha256"), c["name"]), k)
        by_path.setdefault((_resolved(c.get("source")), c["name"]), k)
    out: list[int | None] = []
    for m in motions:
        found = by_hash.get((content_digest(m), m.name))
        out.append(found if found is not None else by_path.get((_resolved(m.source), m.name)))
    return out


def _resolved(source) -> str:
    try:
        return str(Path(source).resolve()) if source else ""
    except (OSError, ValueError):
        return str(source)


def clip_seed(seed: int, name: str) -> int:
    """The noise seed of one test clip: a hash of the run's seed and the clip name,
    so a clip's noise does not depend on which other clips are tested or on --jobs."""
    digest = hashlib.sha256(f"{int(seed)}/{name}".encode()).digest()
    return int.from_bytes(digest[:8], "little")


# ---------------------------------------------------------------- one clip


@dataclass(frozen=True)
class EvalSetup:
    """What every test clip's evaluation shares.

    noise: the sensor/tracker noise model. positions: whether the simulated
    recording keeps the overhead tracker's ground positions (else they are dropped;
    heading follows `noise.heading`, where "none" drops it). options: decoding
    options of `pipeline.reconstruct`. seed: the run's seed (`clip_seed`). protocol:
    the hold-out protocol the hidden clips were chosen by (`evaluate.protocols`)."""

    noise: NoiseModel
    positions: bool
    options: Options
    seed: int = 0
    protocol: str = "clip"  # (`protocols`: what hides the clip list given; "content": label accuracy not applicable)
    # Optical markers instead of accelerometers, for a strategy that reads markers: how
    # they are lost (`sensors.simulate.MarkerPattern`); the rest of what is simulated
    # is the strategy's (`Strategy.simulate_input`).
    pattern: MarkerPattern = MarkerPattern()
    # The test clips' joint map when their skeleton is not the graph's family (a file, a
    # dict or "guess"; None: the graph's).
    mapping: JointMapping = None
    # A folder to keep each clip's reconstruction, truth, input and timeline in, for
    # `graphsvc report` (`report.load.keep_clip`); None: kept nowhere.
    keep_dir: str | None = None
    # Score the pose-oracle floor too (`evaluate.oracle`): per frame the usable node
    # closest in pose to the truth, as `oracle_joint_err_cm`.
    pose_oracle: bool = False
    # Devices worn as in the field: CALIBRATION_POSE_S of `calibration_pose` put before
    # each clip, the devices calibrated from the recording's first this many seconds
    # (the pose and the motion after it) and the clip's part reconstructed
    # (`calibrated_test_input`); None: the recording is read as simulated.
    calibrate_from_start: float | None = None
    calibration_pose: str = "npose"
    # A performer's segment lengths every reconstruction is put on before it is scored
    # (`pipeline.put_on_performer`); None: the graph skeleton's.
    performer: dict | None = None


def reads_markers(setup: EvalSetup) -> bool:
    """Whether the test inputs are optical markers (the strategy needs them)."""
    return "markers" in get_strategy(setup.options.strategy).needs


def inputs_description(setup: EvalSetup) -> str:
    """Which streams the recordings carry, e.g. "accelerometers + positions (σ 0.1 m) + heading (noisy)"."""
    own = get_strategy(setup.options.strategy).describe_input(setup.options, setup.noise, setup.pattern)
    if own:
        return own
    parts = ["accelerometers"]
    if setup.noise.orientations:
        parts.append(f"orientations (σ {setup.noise.orient_sigma:g}°, yaw drift {setup.noise.yaw_drift:g}°/√s)")
    if setup.positions:
        parts.append(f"positions (σ {setup.noise.position:g} m)")
    if setup.options.heading_from_track:
        parts.append("heading (from the track, Kelly et al.'s rule)")
    elif setup.noise.heading != "none":
        parts.append(f"heading ({setup.noise.heading})")
    return " + ".join(parts)


def simulate_test_input(motion: Motion, layout: Layout, setup: EvalSetup, rate_hz: float, mapping=None) -> Recording:
    """The simulated input of a test clip (already at `rate_hz`): what its strategy
    reads (`Strategy.simulate_input`: by default the layout's accelerometers; markers
    lost to `setup.pattern` for one that reads markers), noise seeded by `clip_seed`;
    positions dropped unless `setup.positions`."""
    strategy = get_strategy(setup.options.strategy)
    rec = strategy.simulate_input(
        motion, layout, setup.options, setup.noise, clip_seed(setup.seed, motion.name), rate_hz, mapping, setup.pattern
    )
    if not setup.positions:
        rec = replace(rec, ground_position=None)
    return rec


# How long the pose put before a test clip is held (the issue of devices worn as in the
# field: a wearer stands in it for about two seconds before moving).
CALIBRATION_POSE_S = 2.0


def calibrated_test_input(
    graph: MotionGraph, truth: Motion, layout: Layout, setup: EvalSetup, mapping, hidden: list[str]
) -> tuple[Recording, dict]:
    """The simulated input of a test clip (at the graph's rate) worn as devices are
    worn: CALIBRATION_POSE_S of `setup.calibration_pose` put before the clip
    (`motion.calibration_pose.with_calibration_pose`), the devices simulated over both
    (their mountings, noise and drift running on), calibrated from the recording's first
    `setup.calibrate_from_start` seconds — the pose fixes each sensor's tilt, the motion
    after it the rotation about gravity — against the graph's readings without the
    `hidden` clips (a calibration against a hidden clip's own readings would be a leak;
    `graph.calibration.calibrate_from_start`), and the calibrated stream from the clip's
    first frame on, its clock restarted at 0.

    Returns the recording and what the calibration did: `calibration_error_deg`, the mean
    over sensors of the angle between each estimated mounting and the simulated one
    (`sensors.device_model.mounting`), `calibration_residual_deg` (the mean of the
    calibration's residuals) and `calibration_flagged` (its quality check's line naming
    the sensors not to be trusted, or nothing; the evaluation goes on with the
    calibration, as `--force` would)."""
    from graphsvc.errors import CalibrationQualityError
    from graphsvc.graph.calibration import calibrate_from_start
    from graphsvc.motion.calibration_pose import with_calibration_pose
    from graphsvc.sensors.calibration import apply_calibration, calibration_rotations, check_calibration
    from graphsvc.sensors.device_model import mounting

    if setup.calibrate_from_start is None:
        raise InputError("a calibrated test input needs the setup's calibrate_from_start seconds")
    seconds = float(setup.calibrate_from_start)
    posed = with_calibration_pose(truth, setup.calibration_pose, CALIBRATION_POSE_S, mapping)
    full = simulate_test_input(posed, layout, setup, float(graph.rate_hz), mapping)
    # (devices strapped on straight still read in their own frames: calibrated all the same)
    full = replace(full, meta={**full.meta, "sensor_frame": "device"})
    flagged: list[str] = []
    try:
        cal = calibrate_from_start(full, graph, seconds, setup.calibration_pose, hidden_clips=hidden)
    except CalibrationQualityError as exc:
        cal, flagged = exc.calibration, [str(exc)]
    cal = check_calibration(cal, "the calibration from the start")
    full = apply_calibration(full, cal)
    cut = posed.num_frames - truth.num_frames
    pick = lambda a: None if a is None else a[cut:]  # noqa: E731
    rec = replace(
        full,
        timestamps_s=full.timestamps_s[cut:] - full.timestamps_s[cut],
        accelerations=pick(full.accelerations),
        orientations=pick(full.orientations),
        ground_position=pick(full.ground_position),
        heading=pick(full.heading),
    )
    names = tuple(full.sensor_names)
    estimated = calibration_rotations(cal, names)
    true = mounting(clip_seed(setup.seed, truth.name), names, setup.noise.mount)
    dots = np.abs(np.sum(estimated * true, axis=-1)).clip(0.0, 1.0)
    residuals = [s.get("residual_deg") for s in cal["sensors"].values() if s.get("residual_deg") is not None]
    return rec, {
        "calibration_error_deg": float(np.degrees(2.0 * np.arccos(dots)).mean()),
        "calibration_residual_deg": float(np.mean(residuals)) if residuals else None,
        "calibration_flagged": flagged,
    }


def _global_signals(world_pos: np.ndarray, table: dict, names=CANONICAL) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, P, 3) the canonical joints `names` (default all 19), (T, 2) ground position,
    (T,) heading."""
    canon = world_pos[:, [table[c] for c in names]]
    return canon, signals.ground_position(world_pos, table["pelvis"]), signals.heading(world_pos, table)


def place_start(pos, ground, heading, true_ground0, true_heading0, fix_position: bool, fix_heading: bool):
    """Move a whole predicted motion rigidly so its first frame starts where the truth
    does, for what the recording could not tell: without positions a reconstruction
    starts at the origin, and without positions and heading facing +Z
    (`strategies.base.start_placement`); the metrics should measure drift, not where
    the world origin happens to be. A reconstruction whose track was searched against
    measured positions is never moved: its start heading came from the track.

    pos (T, P, 3), ground (T, 2) m, heading (T,) rad → moved copies. Turns about the
    first frame's ground position by the heading difference (fix_heading), then
    shifts onto the true first ground position (fix_position)."""
    d = float(true_heading0 - heading[0]) if fix_heading else 0.0
    shift = (np.asarray(true_ground0, float) - ground[0]) if fix_position else np.zeros(2)
    c, s = math.cos(d), math.sin(d)
    g0 = ground[0].copy()
    x, z = pos[..., 0] - g0[0], pos[..., 2] - g0[1]
    pos = pos.copy()
    # R_y(d) maps (x, z) to (cos d·x + sin d·z, −sin d·x + cos d·z) (metrics.py convention).
    pos[..., 0] = c * x + s * z + g0[0] + shift[0]
    pos[..., 2] = -s * x + c * z + g0[1] + shift[1]
    gx, gz = ground[:, 0] - g0[0], ground[:, 1] - g0[1]
    ground = np.stack([c * gx + s * gz + g0[0] + shift[0], -s * gx + c * gz + g0[1] + shift[1]], axis=-1)
    return pos, ground, heading + d


def offered_labels(graph: MotionGraph, allowed: np.ndarray) -> set[str]:
    """The content labels the nodes a search may use carry (allowed: (N,) bool)."""
    used = np.unique(np.asarray(graph.node_label)[np.asarray(allowed, dtype=bool)])
    return {str(graph.labels[k]) for k in used if 0 <= k < len(graph.labels)}


def scored_labels(true_label, offered: set[str]):
    """What label accuracy is scored against: the test clip's label, or its (T,)
    per-frame labels with None where the graph offers that label nowhere; None (label
    accuracy not applicable, not 0) when no frame's label is offered."""
    if isinstance(true_label, (str, bytes, int, np.integer, np.str_)):
        return true_label if str(true_label) in offered else None
    kept = [w if w is not None and str(w) in offered else None for w in true_label]
    return kept if any(w is not None for w in kept) else None


_oracle_nodes: dict = {}


def evaluate_clip(graph: MotionGraph, motion: Motion, clip_index, setup: EvalSetup, true_labels=None) -> dict:
    """Reconstruct one test clip with its performance hidden and score it.

    motion: the test clip as loaded (any rate; resampled to the graph's), or a joined
    performance (`mixed.join_clips`) with its (F,) per-frame `true_labels` at the
    graph rate. clip_index: its index in graph.clips, a list of them (a joined
    performance's clips), or None (not in the graph, nothing to hide). Returns
    `evaluate_frames`'s dict (name, frames, the four metrics and the joint error on the
    truth's bone lengths, per_frame arrays) plus
    file, label, samples_per_s, search_s, hidden_nodes, in_graph, start_placed, and
    `node_path` / `pred_labels` ((T,) arrays, for plots; not in the JSON)."""
    mapping = graph.params.get("mapping")
    test_mapping = setup.mapping if setup.mapping is not None else mapping  # (the test clip's skeleton)
    rate = float(graph.rate_hz)
    truth = resample(motion, rate)
    layout = layout_from_dict(graph.layout)
    in_graph = clip_index is not None and np.size(clip_index) > 0
    calibrated: dict = {}
    if setup.calibrate_from_start:
        hidden = [graph.clips[int(k)]["name"] for k in np.atleast_1d(clip_index)] if in_graph else []
        rec, calibrated = calibrated_test_input(graph, truth, layout, setup, test_mapping, hidden)
    else:
        rec = simulate_test_input(truth, layout, setup, rate, test_mapping)
    strategy = get_strategy(setup.options.strategy)
    allowed = strategy.allowed_mask(graph, clip_index) if in_graph else np.ones(graph.num_nodes, dtype=bool)
    result = reconstruct(graph, rec, setup.options, allowed=allowed)
    if setup.performer is not None:
        result = put_on_performer(graph, result, setup.performer)

    true_table, pred_table = joint_map(truth.skeleton, test_mapping), joint_map(graph.skeleton, mapping)
    compared = common_joints(true_table, pred_table)  # (what both skeletons have)
    true_canon, true_ground, true_heading = _global_signals(motion_fk(truth)[1], true_table, compared)
    pred_canon, pred_ground, pred_heading = _global_signals(motion_fk(result.motion)[1], pred_table, compared)
    markers = rec.marker_positions is not None  # (markers place a reconstruction in the world themselves)
    fix_position = rec.ground_position is None and not markers
    fix_heading = (
        rec.heading is None and rec.ground_position is None and not markers
    )  # (positions: the track placed it)
    if fix_position or fix_heading:
        pred_canon, pred_ground, pred_heading = place_start(
            pred_canon, pred_ground, pred_heading, true_ground[0], true_heading[0], fix_position, fix_heading
        )
    if result.provenance is not None:
        pred_labels = np.asarray(result.provenance.label, dtype=object)
    else:
        pred_labels = np.asarray(graph.labels, dtype=object)[np.asarray(graph.node_label)[result.node_path]]
    true_label = motion.labels[0] if motion.labels else motion.name
    scored = scored_labels(true_label if true_labels is None else true_labels, offered_labels(graph, allowed))
    row = evaluate_frames(
        pred_canon,
        true_canon,
        pred_ground,
        pred_heading,
        true_ground,
        true_heading,
        pred_labels=pred_labels,
        true_label=scored,
        name=motion.name,
        joints=compared,
    )
    # What a viewer sees, of the output and of the truth (each over its own frames).
    feet = [compared.index(f) for f in ("l_ankle", "r_ankle")]
    seen, seen_per_frame = plausibility(pred_canon, rate, feet)
    truth_seen, _ = plausibility(true_canon, rate, feet)
    row.update(seen)
    row.update({f"truth_{k}": v for k, v in truth_seen.items()})
    row.update(calibrated)
    row["per_frame"].update(seen_per_frame)
    if setup.pose_oracle:
        names = tuple(compared)
        key = (id(graph), names)
        if _oracle_nodes.get("key") != key:  # (one graph a worker: its nodes' poses once)
            _oracle_nodes.update(key=key, local=oracle.node_local_positions(graph, list(names)))
        floor, _ = oracle.pose_oracle(
            _oracle_nodes["local"], allowed, oracle.local_positions(true_canon, true_ground, true_heading)
        )
        row["oracle_joint_err_cm"] = float(floor.mean())
        row["per_frame"]["oracle_joint_err_cm"] = floor
    if setup.protocol == "content":
        row["label_acc"] = None  # (its label is hidden: no frame can carry it)
    if setup.keep_dir:
        row["kept"] = _keep(
            graph,
            Path(setup.keep_dir),
            motion,
            truth,
            rec,
            result,
            pred_labels,
            row["per_frame"],
            (fix_position, fix_heading),
            (true_ground[0], true_heading[0], pred_ground, pred_heading),
        )
    report = result.report
    row.update(
        {
            "file": clip_file_name(motion.source, motion.name),
            "label": str(true_label),
            "samples": int(report["samples"]),
            "samples_per_s": float(report["samples_per_s"]),
            "search_s": float(report["timings_s"]["search"]),
            "hidden_nodes": int(np.count_nonzero(~allowed)),
            "hidden_clips": int(np.size(clip_index)) if in_graph else 0,
            "activity": activity(true_label) if true_labels is None else "mixed",
            "in_graph": in_graph,
            **({"joined": motion.source} if true_labels is not None else {}),
            "start_placed": [k for k, v in (("position", fix_position), ("heading", fix_heading)) if v],
            **(
                {"missing_joints": sorted(true_table.missing | pred_table.missing)}
                if true_table.missing or pred_table.missing
                else {}
            ),
            "node_path": np.asarray(result.node_path if result.node_path is not None else [], dtype=np.int64),
            "pred_labels": pred_labels,
        }
    )
    return row


def placed_motion(motion: Motion, d: float, g0, shift) -> Motion:
    """`place_start`'s rigid move applied to a motion's root: turned by d rad about +Y
    around ground point g0 (x, z), then shifted by `shift` (x, z)."""
    rot, trans = motion.rotations.copy(), motion.translations.copy()
    rot[:, 0] = quat.mul(quat.about_y(np.full(motion.num_frames, d)), rot[:, 0])
    c, s = math.cos(d), math.sin(d)
    x, z = trans[:, 0, 0] - g0[0], trans[:, 0, 2] - g0[1]
    trans[:, 0, 0] = c * x + s * z + g0[0] + shift[0]
    trans[:, 0, 2] = -s * x + c * z + g0[1] + shift[1]
    return motion.copy(rotations=rot, translations=trans)


def _keep(graph, folder: Path, motion, truth, rec, result, pred_labels, per_frame, fixes, starts) -> dict:
    """Write the clip's files into `folder`, setup.keep_dir (`report.load.keep_clip`),
    the reconstruction placed as the metrics placed it."""
    out = result.motion
    (fix_position, fix_heading), (true_g0, true_h0, pred_ground, pred_heading) = fixes, starts
    if fix_position or fix_heading:  # (the same rigid move as `place_start`)
        d = float(true_h0 - pred_heading[0]) if fix_heading else 0.0
        shift = (np.asarray(true_g0, float) - pred_ground[0]) if fix_position else np.zeros(2)
        out = placed_motion(out, d, pred_ground[0], shift)
    virtual = None
    if result.node_path is not None:
        timeline = timeline_from_nodes(graph, result.node_path)
        virtual = path_readings(graph, result.node_path)
    else:
        p = result.provenance
        timeline = timeline_from_sources([str(c["name"]) for c in graph.clips], pred_labels, p.clip, p.frame, p.weight)
        virtual = source_readings(graph, p.clip, p.frame, p.weight)
    stem = kept_name(motion.name, hashlib.sha256(f"{motion.source}/{motion.name}".encode()).hexdigest()[:8])
    return keep_clip(
        folder, stem, out.copy(name=motion.name), truth, rec, timeline, per_frame, pred_labels, rec.constraints, virtual
    )


# ---------------------------------------------------------------- many clips

_PRIVATE = ("per_frame", "node_path", "pred_labels")
_worker: dict = {}


def _init_worker(graph_path: str, setup: EvalSetup, threads: int) -> None:
    # The search kernels are numba-parallel: share the cores among workers rather
    # than letting every worker start a thread per core.
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))  # type: ignore[attr-defined]
    # The parent wrote (or verified) this file moments ago: skip re-hashing it.
    _worker["graph"] = load_graph(graph_path, mmap=True, verify=False)
    _worker["setup"] = setup


def _evaluate_item(graph: MotionGraph, item: tuple, setup: EvalSetup) -> dict:
    """`evaluate_clip` of one item of `run_leave_one_out`'s tests."""
    return evaluate_clip(graph, item[0], item[1], setup, item[2] if len(item) > 2 else None)


def _evaluate_in_worker(item: tuple) -> dict:
    row = _evaluate_item(_worker["graph"], item, _worker["setup"])
    return {k: v for k, v in row.items() if k not in ("node_path", "pred_labels")}


def run_leave_one_out(
    graph: MotionGraph,
    tests: list[tuple],
    setup: EvalSetup,
    jobs: int = 1,
    graph_path: StrPath | None = None,
    progress: bool | None = None,
) -> list[dict]:
    """`evaluate_clip` for each (motion, graph clip index) in `tests` — or (motion,
    clip indices, per-frame labels) for a joined performance; rows in the order of
    `tests` whatever `jobs`. jobs > 1: that many worker processes, each
    memory-mapping `graph_path` (the graph's file; written to a temporary file when
    None) and using cores/jobs numba threads."""
    from tqdm import tqdm

    bar = {"total": len(tests), "desc": "clips", "unit": "clip", "disable": None if progress is None else not progress}
    jobs = max(1, min(int(jobs), len(tests)))
    if jobs == 1:
        return [_evaluate_item(graph, item, setup) for item in tqdm(tests, **bar)]
    with tempfile.TemporaryDirectory(prefix="graphsvc-eval-") as tmp:
        if graph_path is None:
            graph_path = Path(tmp) / "graph.mgraph"
            save_graph(graph, graph_path)
        threads = max(1, (os.cpu_count() or 1) // jobs)
        # spawn, not fork: numba's thread pool in the parent is not fork-safe.
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            jobs, mp_context=ctx, initializer=_init_worker, initargs=(str(graph_path), setup, threads)
        ) as pool:
            return list(tqdm(pool.map(_evaluate_in_worker, tests), **bar))


def peak_rss_mb() -> float:
    """Peak resident memory (MB) of this process and of its finished workers, the
    larger of the two (workers share the memory-mapped graph pages)."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 1024.0  # Linux reports KiB


def summarize_run(rows: list[dict]) -> dict:
    """JSON-ready {"clips": [...], "mean": {...}} (`metrics.summarize`'s shape), rows
    without their per-frame arrays, plus samples_per_s: per clip the search speed,
    overall the total samples over the total search time."""
    out = summarize([{k: v for k, v in r.items() if k not in _PRIVATE} for r in rows])
    search_s = sum(r["search_s"] for r in rows)
    samples = sum(r["samples"] for r in rows)
    out["mean"]["samples_per_s"] = round(samples / search_s, 1) if search_s > 0 else None
    for key in ("calibration_error_deg", "calibration_residual_deg"):  # (per clip: one calibration each)
        have = [r[key] for r in out["clips"] if r.get(key) is not None]
        if have:
            out["mean"][key] = float(np.mean(have))
    if any("calibration_flagged" in r for r in out["clips"]):
        out["mean"]["calibration_flagged_clips"] = sum(bool(r.get("calibration_flagged")) for r in out["clips"])
    out["groups"] = {}
    for group in ("locomotion", "gestures"):
        members = [r for r in out["clips"] if r.get("activity") == group]
        if members:
            out["groups"][group] = summarize(members)["mean"]
    return out
