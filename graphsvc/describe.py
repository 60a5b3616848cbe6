"""What `graphsvc inspect` reports: per clip frames, rate, joints and duration with
per-folder and overall totals, and for recordings their samples, sensors, channels."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

from tqdm import tqdm

from graphsvc.errors import InputError, UnknownFormatError
from graphsvc.motion.library import MOTION_SUFFIXES, find_motion_files, is_motion_file, load_motion
from graphsvc.sensors.files import RECORDING_SUFFIXES, read_recording
from graphsvc.sensors.recording import describe_recording


def describe_paths(
    paths: list[str], progress: bool | None = None, up: str | None = None, units: str | None = None
) -> dict:
    """{"clips": [...], "folders": [...], "totals": {...}, "recordings": [...]}. up,
    units: how to read a recording file where it does not say (`read_recording`).

    Motion files are fully parsed, so a file that would fail to load fails here too."""
    recordings = []
    motion_inputs = []
    for p in paths:
        if not str(p).strip():
            raise InputError("an empty path is not a file or folder")
        path = Path(p)
        if path.suffix.lower() in RECORDING_SUFFIXES:
            rec = read_recording(path, up=up, units=units)
            info = describe_recording(rec)
            recordings.append({"path": str(path), **info})
        elif path.is_file() and not is_motion_file(path):
            raise UnknownFormatError(
                f"{path}: unknown format (motion: {', '.join(MOTION_SUFFIXES)}; recordings: {', '.join(RECORDING_SUFFIXES)})"
            )
        else:
            motion_inputs.append(p)
    clips = []
    if motion_inputs:
        files = find_motion_files(motion_inputs)
        for f in tqdm(files, desc="reading", unit="clip", disable=None if progress is None else not progress):
            m = load_motion(f)
            clips.append(
                {
                    "path": str(f),
                    "name": m.name,
                    "frames": m.num_frames,
                    "rate_hz": m.rate_hz,
                    "joints": m.skeleton.num_joints_excluding_end_sites,
                    "duration_s": round(m.duration_s, 6),
                    "labels": list(m.labels),
                }
            )
    if not clips and not recordings:
        raise InputError(
            f"no motion files or recordings found in {', '.join(map(str, paths))} (motion: "
            f"{', '.join(MOTION_SUFFIXES)}; recordings: {', '.join(RECORDING_SUFFIXES)})"
        )
    folders = defaultdict(list)
    for c in clips:
        folders[str(Path(c["path"]).parent)].append(c)
    return {
        "clips": clips,
        "folders": [{"path": k, **_totals(v)} for k, v in sorted(folders.items())],
        "totals": _totals(clips),
        "recordings": recordings,
    }


def _totals(clips: list[dict]) -> dict:
    return {
        "clips": len(clips),
        "frames": sum(c["frames"] for c in clips),
        "duration_s": round(sum(c["duration_s"] for c in clips), 6),
        "rates_hz": sorted({c["rate_hz"] for c in clips}),
    }


def format_description(info: dict) -> str:
    """The human-readable table `graphsvc inspect` prints."""
    lines = []
    if info["clips"]:
        width = max(len(c["name"]) for c in info["clips"])
        lines.append(f"{'clip':<{width}}  {'frames':>7}  {'rate':>6}  {'joints':>6}  {'duration':>9}  labels")
        for c in info["clips"]:
            lines.append(
                f"{c['name']:<{width}}  {c['frames']:>7}  {c['rate_hz']:>6g}  {c['joints']:>6}  "
                f"{c['duration_s']:>8.2f}s  {','.join(c['labels'])}"
            )
        lines.append("")
        for f in info["folders"]:
            lines.append(_total_line(f["path"], f))
        lines.append(_total_line("total", info["totals"]))
    for r in info["recordings"]:
        what = [f"{len(r['sensors'])} sensors ({', '.join(r['sensors'])})"] if r["sensors"] else []
        if r.get("markers"):
            what.append(
                f"{len(r['markers'])} markers ({', '.join(r['markers'][:12])}"
                f"{' …' if len(r['markers']) > 12 else ''}), seen {100 * r['markers_seen']:.0f} %"
            )
        lines.append(
            f"{r['path']}: recording, {r['samples']} samples of {' and '.join(what) or 'nothing'} at "
            f"{r['rate_hz']:g} Hz, {r['duration_s']:.2f} s"
        )
        lines.append(f"  channels: {', '.join(r['channels'][:36])}{' …' if len(r['channels']) > 36 else ''}")
        if r.get("reading"):
            lines.append(
                "  read: "
                + ", ".join(
                    f"{_SETTING_NAMES[k]} {v['value']} ({_FROM[k][v['from']]})" for k, v in r["reading"].items()
                )
            )
    return "\n".join(lines)


_SETTING_NAMES = {"sensor_frame": "sensor frame", "up": "up", "units": "units"}
_FROM = {
    k: {"argument": f"--{k}", "file": "file header", "format": "MVNX format", "default": "default"}
    for k in _SETTING_NAMES
}


def _total_line(label: str, t: dict) -> str:
    rates = "/".join(f"{r:g}" for r in t["rates_hz"])
    return f"{label}: {t['clips']} clips, {t['frames']:,} frames at {rates} Hz, {t['duration_s'] / 60:.1f} min"
