"""What `graphsvc report RESULT` reads: a `synthesize --report` JSON, an `evaluate
--json` output written with `--keep-motions`, or a batch folder; each becomes the
page's document ({"title", "clips": [view...], "table"}).

A synthesize report names its output (BVH or glTF), graph and recording (`files`); the
graph gives the timeline its clips and kinds (without it, the labels alone). A kept
evaluation clip (`evaluate.keep.keep_clip`) is a small JSON beside its BVH files that
already holds its timeline, per-frame errors and labels, so the page needs no graph.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, GraphsvcError, InputError
from graphsvc.evaluate.metrics import motion_plausibility
from graphsvc.fileio import read_json_file
from graphsvc.graph.file import load_graph
from graphsvc.motion.library import load_motion
from graphsvc.motion.output import read_motion_output
from graphsvc.motion.resample import resample
from graphsvc.pipeline import read_searched_recording
from graphsvc.report.gather import clip_view
from graphsvc.sensors.files import read_recording
from graphsvc.strategies.sources import (
    path_readings,
    source_readings,
    timeline_from_labels,
    timeline_from_nodes,
    timeline_from_sources,
)

TABLE_COLUMNS = (
    "clip",
    "label",
    "frames",
    "joint_err_cm",
    "joint_err_scaled_cm",
    "root_err_cm",
    "heading_err_deg",
    "label_acc",
    "samples_per_s",
    "jitter_km_s3",
    "truth_jitter_km_s3",
    "skate_cm_s",
    "truth_skate_cm_s",
)
SEEN = (
    "jitter_km_s3",
    "truth_jitter_km_s3",
    "skate_cm_s",
    "truth_skate_cm_s",
)  # (what a viewer sees, in a view's info)


def _file(path, what: str, base: Path) -> Path:
    p = Path(path)
    if not p.is_absolute():
        p = base / p
    if not p.is_file():
        raise InputError(f"{what} {p} does not exist (moved since the report was written?)")
    return p


def report_timeline(report: dict, graph) -> dict:
    """The timeline of a synthesize report: from its node path or its sources (with
    the graph), else from its label runs."""
    if graph is not None and report.get("node_path"):
        return timeline_from_nodes(graph, np.asarray(report["node_path"], dtype=np.int64))
    src = report.get("sources")
    if graph is not None and src:
        names = [str(c["name"]) for c in graph.clips]
        labels = _labels_from_runs(report.get("labels", []), len(src["clip"]))
        return timeline_from_sources(
            names, labels, np.array(src["clip"]), np.array(src["frame"]), np.array(src["weight"])
        )
    return timeline_from_labels(report.get("labels", []))


def _labels_from_runs(runs, T: int) -> list[str]:
    labels = [""] * T
    for r in runs:
        labels[int(r["start_frame"]) : int(r["start_frame"]) + int(r["frames"])] = [str(r["label"])] * int(r["frames"])
    return labels


def synthesize_view(report: dict, base: Path, truth=None, graph=None, truth_mapping=None, notes=None) -> dict:
    """The view of one synthesize report (its files resolved against `base` when
    relative). truth: a Motion, or a path to one, or None; truth_mapping: its joint
    map (a file, "guess" or None: a built-in one). graph: the graph already loaded,
    else read from the report's path when it is there (else no sources). notes: a
    list that collects remarks for the user (the error charts left out), or None."""
    files = report.get("files")
    if not isinstance(files, dict) or "output" not in files:
        raise InputError("the report names no output file (write it with `graphsvc synthesize --report`)")
    motion = read_motion_output(_file(files["output"], "output", base))
    if graph is None and files.get("graph") and Path(files["graph"]).is_file():
        graph = load_graph(files["graph"], mmap=True, verify=False)
    rec = None
    if files.get("recording"):
        read = files.get("read", {})
        path = _file(files["recording"], "recording", base)
        if graph is not None:  # (as the search read it: device names mapped, calibration applied)
            rec = read_searched_recording(
                graph, path, read.get("up"), read.get("units"), read.get("device_map"), read.get("calibration")
            )
        else:
            rec = read_recording(path, up=read.get("up"), units=read.get("units"))
    if truth is not None and not hasattr(truth, "skeleton"):
        truth = load_motion(truth)
    if truth is not None:
        truth = resample(truth, motion.rate_hz)
    options = report.get("options", {})
    constraints = options.get("constraints") or (rec.constraints if rec is not None else [])
    mapping = graph.params.get("mapping") if graph is not None else None
    labels = _labels_from_runs(report.get("labels", []), motion.num_frames)
    info = {
        "strategy": report.get("strategy", "?"),
        "samples": report.get("samples"),
        "graph": Path(files.get("graph", "")).name,
    }
    if "cost" in report:
        info["cost"] = round(float(report["cost"]), 3)
    try:  # what a viewer sees, of the output (and of the truth)
        info.update({k: _num(v) for k, v in motion_plausibility(motion, mapping).items() if k in SEEN})
        if truth is not None:
            info.update({f"truth_{k}": _num(v) for k, v in motion_plausibility(truth).items() if f"truth_{k}" in SEEN})
    except GraphsvcError:  # (a skeleton no joint map knows, too few frames: shown without them)
        pass
    virtual = None
    if graph is not None and report.get("node_path") and len(report["node_path"]) == motion.num_frames:
        virtual = path_readings(graph, np.asarray(report["node_path"], dtype=np.int64))
    elif graph is not None and report.get("sources") and len(report["sources"]["clip"]) == motion.num_frames:
        src = report["sources"]
        virtual = source_readings(graph, np.array(src["clip"]), np.array(src["frame"]), np.array(src["weight"]))
    return clip_view(
        Path(files["output"]).stem,
        motion,
        report_timeline(report, graph),
        rec,
        truth,
        constraints=constraints,
        labels=labels,
        mapping=mapping,
        info=info,
        virtual=virtual,
        truth_mapping=truth_mapping,
        notes=notes,
    )


# ---------------------------------------------------------------- evaluation


def kept_view(folder: Path, files: dict, row: dict) -> dict:
    """The view of one kept evaluation clip (the files `evaluate.keep.keep_clip` wrote
    into `folder`) with its evaluation row's scores above it."""
    doc = read_json_file(_file(files["view"], "kept clip", folder))
    motion = load_motion(_file(files["output"], "kept motion", folder))
    truth = load_motion(_file(files["truth"], "kept truth", folder))
    rec = read_recording(_file(files["recording"], "kept recording", folder))
    per_frame = doc.get("per_frame")
    if per_frame:
        per_frame = {k: np.array([np.nan if v is None else v for v in vals]) for k, vals in per_frame.items()}
    virtual = None
    if isinstance(doc.get("virtual"), dict):
        import base64

        v = doc["virtual"]
        virtual = np.frombuffer(base64.b64decode(v["f32"]), dtype="<f4").astype(np.float64).reshape(v["shape"])
    info = {
        k: round(row[k], 2) if isinstance(row[k], float) else row[k]
        for k in ("file", "label", "joint_err_cm", "root_err_cm", "heading_err_deg", *SEEN)
        if row.get(k) is not None
    }
    return clip_view(
        str(row.get("name", motion.name)),
        motion,
        doc["timeline"],
        rec,
        truth,
        per_frame,
        doc.get("constraints"),
        doc.get("labels"),
        info=info,
        virtual=virtual,
    )


def evaluation_document(result: dict, base: Path) -> dict:
    """The page of an evaluation JSON with kept motions: one view a clip and the
    metrics table."""
    rows = [r for r in result.get("clips", []) if isinstance(r, dict)]
    kept = [r for r in rows if isinstance(r.get("kept"), dict)]
    if not kept:
        raise InputError("the evaluation kept no motions: run `graphsvc evaluate ... --keep-motions DIR --json OUT`")
    folder = Path(result.get("config", {}).get("keep_motions") or base)
    if not folder.is_absolute():
        folder = base / folder
    clips, table = [], []
    for r in kept:
        clips.append(kept_view(folder, r["kept"], r))
        table.append([r.get("name"), r.get("label"), r.get("frames"), *(_num(r.get(k)) for k in TABLE_COLUMNS[3:])])
    cfg = result.get("config", {})
    title = (
        f"graphsvc evaluation: {len(clips)} clips, {cfg.get('inputs', '')}, strategy "
        f"{cfg.get('options', {}).get('strategy', '?')}"
    )
    return {
        "title": title,
        "clips": clips,
        "table": {"columns": list(TABLE_COLUMNS), "rows": table, "clip": list(range(len(clips)))},
    }


def _num(v):
    return None if v is None else round(float(v), 4)


# ---------------------------------------------------------------- any result


def batch_document(folder: Path) -> dict:
    """The page of a batch folder: one view per item report (OUTPUT.json) found in it."""
    clips, table = [], []
    for path in sorted(folder.rglob("*.json")):
        if path.name == "summary.json":
            continue
        try:
            report = read_json_file(path)
        except FormatError:
            continue
        if not isinstance(report, dict) or not isinstance(report.get("files"), dict):
            continue
        view = synthesize_view(report, path.parent)
        view["name"] = str(path.relative_to(folder).with_suffix(""))
        clips.append(view)
        table.append([view["name"], report.get("strategy"), view["frames"], report.get("samples_per_s")])
    if not clips:
        raise InputError(f"{folder}: no item reports (OUTPUT.json of `graphsvc batch`) in the folder")
    return {
        "title": f"graphsvc batch {folder.name}: {len(clips)} items",
        "clips": clips,
        "table": {
            "columns": ["item", "strategy", "frames", "samples_per_s"],
            "rows": table,
            "clip": list(range(len(clips))),
        },
    }


def load_document(result, truth=None, truth_mapping=None, notes=None) -> dict:
    """The page's document for RESULT: a synthesize report, an evaluation JSON with
    kept motions, or a batch folder. truth: a motion file (synthesize reports only);
    truth_mapping: its joint map (a file or "guess"; None: a built-in one); notes: a
    list that collects remarks for the user, or None."""
    path = Path(result)
    if truth_mapping is not None and truth is None:
        raise InputError("--mapping is the joint map of --truth: give --truth too")
    if truth is not None and (path.is_dir() or path.is_file() and "mean" in (read_json_file(path) or {})):
        raise InputError("--truth applies to a synthesize report (an evaluation keeps its truths, a batch has none)")
    if path.is_dir():
        return batch_document(path)
    if not path.is_file():
        raise InputError(f"{path} does not exist")
    data = read_json_file(path)
    if isinstance(data, dict) and "clips" in data and "mean" in data:
        return evaluation_document(data, path.parent)
    if isinstance(data, dict) and isinstance(data.get("files"), dict):
        view = synthesize_view(data, path.parent, truth, truth_mapping=truth_mapping, notes=notes)
        return {"title": f"graphsvc reconstruction: {view['name']}", "clips": [view], "table": None}
    raise FormatError(path, "not a synthesize report, an evaluation JSON or a batch folder")
