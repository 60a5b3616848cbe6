"""Optical marker files in: C3D (through the `ezc3d` package) and a plain marker CSV,
as recordings with labelled markers (`sensors.recording.Recording`), in metres with
+Y up.

C3D
    Points, their labels (`POINT:LABELS`, `LABELS2` …; a subject prefix `Name:` is
    dropped, unlabelled points `*12` are skipped), rate and units (`POINT:UNITS`) come
    from the file. A point whose residual is negative or whose coordinates are NaN is
    not seen. A file shorter than its header says is refused as truncated.

Marker CSV
    UTF-8, comma-separated; optional ``# key=value`` comment lines before the header
    (``rate_hz``, ``units`` m | cm | mm, ``up`` y | z), then a header whose first column
    is ``time`` (seconds) and whose others are ``NAME_x, NAME_y, NAME_z`` for each
    marker, then one row a sample; an empty cell or ``nan`` is "not seen"::

        # graphsvc markers v1
        # rate_hz=120
        # units=mm
        # up=z
        time,LFHD_x,LFHD_y,LFHD_z,LTOE_x,LTOE_y,LTOE_z
        0.0,1278.5,1088.0,1754.9,1361.8,1183.9,57.0

    Without ``units`` the values are metres; without ``up``, +Y is up.

Axes: a file with +Z up is turned onto +Y up by the cyclic change (x, y, z) → (y, z, x),
a proper rotation (`sensors.axes.to_y_up`); it is how HDM05's Vicon exports relate
their C3D to the skeleton fitted to the same take (measured on the shared HDM05 take:
10 cm RMS between markers and the nearest joints, the skin's offset). For C3D without `up`, the vertical is the
axis along which the markers of a frame spread most (a standing body is taller than
wide) when that is clear, else what `POINT:Y_SCREEN` says (+Y or +Z), else +Z, the
usual C3D convention; the recording's meta says which and why. The SSG strategy's
local cost does not depend on the heading or the ground position, so only the vertical
matters for reconstruction.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from graphsvc.errors import FormatError, InputError
from graphsvc.fileio import atomic_writer, require_file
from graphsvc.sensors.axes import to_y_up
from graphsvc.sensors.c3d_guard import check_c3d, read_isolated
from graphsvc.sensors.recording import Recording, csv_rows, read_csv_table, sample_rate

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
UPS = ("y", "z")
CSV_MAGIC = "# graphsvc markers v1"


def _unit_scale(units: str, source) -> float:
    key = str(units).strip().lower()
    if key in ("millimeters", "millimetres"):
        key = "mm"
    if key not in UNITS:
        raise FormatError(source, f"unknown length unit {units!r} (m, cm or mm)")
    return UNITS[key]


def _check_up(up: str | None) -> None:
    if up is not None and up not in UPS:
        raise InputError(f"up axis must be y or z, got {up!r}")


def _spread_axis(points: np.ndarray) -> str | None:
    """The axis ("y" or "z") along which the markers of a frame spread most, if clearly
    (median over frames with ≥ 3 markers seen, 1.5 times the next axis), else None."""
    seen = np.isfinite(points).all(axis=-1)
    rows = np.flatnonzero(seen.sum(axis=1) >= 3)
    if not rows.size:
        return None
    rows = rows[:: max(1, rows.size // 200)]
    spans = []
    for t in rows:
        p = points[t][seen[t]]
        spans.append(p.max(axis=0) - p.min(axis=0))
    extent = np.median(np.array(spans), axis=0)
    order = np.argsort(-extent)
    if order[0] == 0 or extent[order[0]] < 1.5 * extent[order[1]]:
        return None
    return "yz"[order[0] - 1]


# ---------------------------------------------------------------- C3D


def _declared_frames(path: Path) -> int | None:
    """The frame count a C3D file's own header declares (words 4 and 5: first and last
    frame; ezc3d rewrites them to what it could read), or None where the header cannot
    tell (a last frame of 65535: longer files keep the count elsewhere)."""
    with open(path, "rb") as f:
        head = f.read(512)
        if len(head) < 10:
            return 0
        f.seek(512 * max(0, head[0] - 1))
        params = f.read(4)
    big = len(params) == 4 and params[3] == 86  # MIPS processor: big-endian integers
    order = ">" if big else "<"
    first, last = np.frombuffer(head[6:10], dtype=f"{order}u2")
    if last == 65535:
        return None
    return int(last) - int(first) + 1


def read_c3d(path, up: str | None = None, units: str | None = None) -> Recording:
    """A C3D file's labelled markers as a recording (module docstring). up: "y" or "z"
    (None: decided as the module docstring says); units: overrides the file's."""
    _check_up(up)
    path = require_file(path)
    data = path.read_bytes()
    check_c3d(path, data)  # what ezc3d would follow fits in the file: it does not check
    c3d = read_isolated(path, len(data))  # and what else it cannot survive ends a child process
    header, params = c3d["header"], c3d["params"]
    points = c3d["points"]  # (4, M, F)
    if points.ndim != 3 or points.shape[0] < 3:
        raise FormatError(path, f"not a readable C3D file: points of shape {points.shape}")
    M, F = points.shape[1], points.shape[2]
    declared = _declared_frames(path)
    if declared is None:
        declared = int(header.get("last_frame", 0)) - int(header.get("first_frame", 0)) + 1
    if M == 0 or declared <= 0:
        raise FormatError(path, "holds no marker points")
    if F < declared:
        raise FormatError(path, f"truncated: the header declares {declared} frames, the file holds {F}")
    rate = float(header.get("frame_rate") or 0.0)
    if not (math.isfinite(rate) and rate > 0):
        raise FormatError(path, f"bad point rate {rate!r}")
    labels: list[str] = []
    for key in ["LABELS"] + [f"LABELS{k}" for k in range(2, 10)]:
        if key in params:
            labels += params[key]
    labels = (labels + [f"*{k}" for k in range(len(labels), M)])[:M]
    scale = _unit_scale(units if units is not None else (params.get("UNITS") or ["mm"])[0], path)
    residual = c3d["residuals"]
    if residual.size != M * F:
        raise FormatError(path, f"not a readable C3D file: {residual.size} residuals for {M} points × {F} frames")
    residual = residual.reshape(M, F)
    xyz = np.transpose(points[:3], (2, 1, 0)) * scale  # (F, M, 3)
    xyz[(residual < 0).T] = np.nan
    names, cols = [], []
    for k, label in enumerate(labels):
        name = label.strip().split(":")[-1].strip()
        if not name or name.startswith("*") or name in names or set(name) & set(',"\r\n'):
            continue
        names.append(name)
        cols.append(k)
    if not names:
        raise FormatError(path, "holds no labelled markers (only unlabelled points)")
    xyz = xyz[:, cols]
    how = "given"
    if up is None:
        up = _spread_axis(xyz)
        how = "the markers' spread"
        if up is None:
            screen = str((params.get("Y_SCREEN") or [""])[0]).strip().upper()
            up, how = (
                ({"+Y": "y", "+Z": "z"}[screen], "POINT:Y_SCREEN")
                if screen in ("+Y", "+Z")
                else ("z", "the C3D convention")
            )
    xyz = np.ascontiguousarray(to_y_up(xyz, up))
    if not np.isfinite(xyz).any():
        raise FormatError(path, "every marker is missing in every frame")
    rec = Recording(
        rate_hz=rate,
        timestamps_s=np.arange(F, dtype=np.float64) / rate,
        sensor_names=(),
        accelerations=None,
        marker_names=tuple(names),
        marker_positions=xyz,
        meta={
            "source": str(path),
            "imported_from": "c3d",
            "up": up,
            "up_from": how,
            "units_scale_m": scale,
            "first_frame": int(header.get("first_frame", 0)),
        },
    )
    rec.validate()
    return rec


# ---------------------------------------------------------------- CSV


def _marker_columns(path: Path, header: list, line: int) -> dict[str, dict[str, int]]:
    """A marker CSV's header → {marker: {axis: column}}; FormatError for anything but
    `time` then whole NAME_x, NAME_y, NAME_z triplets."""
    if header[0].lower() not in ("time", "time_s"):
        raise FormatError(path, f"the first column must be time (seconds), got {header[0]!r}", line=line)
    markers: dict[str, dict[str, int]] = {}
    for k, c in enumerate(header[1:], start=1):
        name, _, axis = c.rpartition("_")
        if not name or axis.lower() not in ("x", "y", "z"):
            raise FormatError(path, f"column {c!r} is not NAME_x, NAME_y or NAME_z", line=line)
        if axis.lower() in markers.setdefault(name, {}):
            raise FormatError(path, f"duplicate column {c!r}", line=line)
        markers[name][axis.lower()] = k
    for name, axes in markers.items():
        if len(axes) != 3:
            raise FormatError(
                path,
                f"marker {name!r} lacks column(s) {', '.join(f'{name}_{a}' for a in 'xyz' if a not in axes)}",
                line=line,
            )
    if not markers:
        raise FormatError(path, "no marker columns", line=line)
    return markers


def read_marker_csv(path, up: str | None = None, units: str | None = None, rate_hz: float | None = None) -> Recording:
    """A marker CSV (module docstring) as a recording; up, units, rate_hz override the
    file's comments. FormatError with the line for malformed files."""
    _check_up(up)
    path = Path(path)
    csv = read_csv_table(path, "time,NAME_x,NAME_y,NAME_z,...", lambda cells, line: _marker_columns(path, cells, line))
    comments, lines, markers, table = csv.comments, csv.row_lines, csv.parsed_header, csv.table
    t = table[:, 0]
    if np.isnan(t).any():
        raise FormatError(path, "time is empty or nan", line=lines[int(np.argmax(np.isnan(t)))])
    bad = np.diff(t) <= 0
    if bad.any():
        i = int(np.argmax(bad)) + 1
        raise FormatError(path, f"times must be strictly increasing ({t[i]:g} after {t[i - 1]:g})", line=lines[i])
    up = up if up is not None else comments.get("up", "y").lower()
    if up not in UPS:
        raise FormatError(path, f"up must be y or z, got {up!r}")
    scale = _unit_scale(units if units is not None else comments.get("units", "m"), path)
    rate_hz = sample_rate(path, rate_hz, comments, t)
    names = tuple(markers)
    xyz = np.stack([table[:, [markers[n]["x"], markers[n]["y"], markers[n]["z"]]] for n in names], axis=1) * scale
    xyz[~np.isfinite(xyz).all(axis=-1)] = np.nan
    rec = Recording(
        rate_hz=float(rate_hz),
        timestamps_s=np.ascontiguousarray(t),
        sensor_names=(),
        accelerations=None,
        marker_names=names,
        marker_positions=np.ascontiguousarray(to_y_up(xyz, up)),
        meta={"source": str(path), "imported_from": "marker csv", "up": up, "units_scale_m": scale},
    )
    rec.validate()
    return rec


def export_marker_csv(rec: Recording, path) -> None:
    """Write a recording's markers as a marker CSV (metres, +Y up), atomically."""
    if rec.marker_positions is None:
        raise InputError("the recording has no markers")
    rec.validate()
    lines = [
        CSV_MAGIC,
        f"# rate_hz={rec.rate_hz:.12g}",
        "# units=m",
        "# up=y",
        ",".join(["time"] + [f"{n}_{a}" for n in rec.marker_names for a in "xyz"]),
    ]
    T = rec.num_samples
    lines += csv_rows(np.concatenate([rec.timestamps_s[:, None], rec.marker_positions.reshape(T, -1)], axis=1))
    with atomic_writer(path) as f:
        f.write(("\n".join(lines) + "\n").encode("utf-8"))
