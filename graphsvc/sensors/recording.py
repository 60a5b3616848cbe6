"""Input streams on disk: the native `.rec` container and CSV for real devices (any
recording file, by its format: `sensors.files.read_recording`).

A Recording is what the body-worn sensors, an optical capture and the overhead tracker
reported, each stream optional: timestamps, per-sensor accelerations in each sensor's
own frame, per-sensor orientations (quaternions, as a real IMU reports them), labelled
marker positions, ground position and heading, annotation constraint sets, the sensor
layout and provenance.

Native format (`.rec`)
    A graphsvc container (graphsvc/store.py) of kind "recording", format_version 1.
    Arrays: ``timestamps_s`` (T,) <f8 and, when present, ``accelerations`` (T, S, 3)
    <f4, ``orientations`` (T, S, 4) <f4, ``marker_positions`` (T, M, 3) <f8,
    ``ground_position`` (T, 2) <f8 and ``heading`` (T,) <f8. The JSON meta holds
    ``rate_hz``, ``sensor_names``, ``marker_names`` (when there are markers),
    ``constraints``, ``layout`` and ``meta``. Everything round-trips exactly.

CSV format
    UTF-8 text, comma-separated, one header row then one row per sample::

        # graphsvc recording v1
        # rate_hz=30
        t_s,l_wrist_ax,l_wrist_ay,l_wrist_az,r_ankle_ax,r_ankle_ay,r_ankle_az,pos_x_m,pos_z_m,heading_rad
        0,0.12,9.79,-0.3,...

    - Lines starting with ``#`` are comments; ``# key=value`` comments before the
      header (keys and values in any case) say how to read the file. export_csv
      writes the two lines shown; files from devices may have none:

      ``rate_hz=HZ``
          the sample rate (else the median timestamp step).
      ``units=m/s2|g``
          the acceleration columns' unit (default m/s²; g is converted with 9.81
          m/s²). ``import_csv(..., units=)`` overrides it.
      ``up=y|z``
          the vertical axis of the world the orientations are given in (default y,
          graphsvc's). A Z-up world (X forward, Y left, as Xsens's) is turned onto
          graphsvc's Y-up world by (x, y, z) → (y, z, x), as for MVNX and C3D:
          q_world = Q_Z_UP_TO_Y_UP ⊗ q (`sensors.axes`). It concerns the
          orientations only; markers, ground position and heading are always in
          graphsvc's world. ``import_csv(..., up=)`` overrides it.
      ``sensor_frame=device|layout``
          whose frames the readings are in, kept in meta["sensor_frame"]: ``layout``,
          each sensor's frame as the graph layout defines it (what graphsvc
          simulates), or ``device``, each device's own frame, to be calibrated onto
          the layout's. Without it: ``layout`` when the file starts with the
          ``# graphsvc recording v1`` line (written by graphsvc), else ``device``.

      meta keeps the units, up and sensor_frame used and, in meta["read_from"], where
      each came from: "argument" (import_csv's, a command's flag), "file" (the
      comment) or "default".
    - ``t_s``: seconds, required, finite, strictly increasing.
    - ``<sensor>_ax, <sensor>_ay, <sensor>_az``: acceleration in the sensor's frame
      (gravity included: +9.81 "up" at rest), m/s² or g (``units``).
      ``<sensor>_qw … _qz``: the sensor's orientation, a unit quaternion (w, x, y, z):
      the sensor frame's rotation into the world (``up``). A sensor has all three (all
      four) columns or none, in any column order; sensors are numbered in the order
      their first column appears; a sensor without acceleration columns, in a file
      where others have them, reads NaN (missing).
    - ``<marker>_px, <marker>_py, <marker>_pz``: a labelled optical marker's position,
      m, Y up; empty = not seen. Markers are numbered in the order their first column
      appears.
    - ``pos_x_m, pos_z_m`` (both or neither): overhead-tracker ground position, m.
    - ``heading_rad``: facing about +Y, radians. Optional.
    - An empty cell or ``nan`` (any case) means missing (NaN); ``inf`` is refused.
    - Numbers are written with ``'%.9g'``: exact for the float32 accelerations, 9
      significant digits for times (1 µs at 1000 s), positions and heading.
    - Constraint sets, the layout and provenance are not carried by CSV; pass
      ``layout=`` to import_csv. The rate comes from ``rate_hz=``, else the
      ``# rate_hz=`` comment, else the median timestamp step.
    Errors name the file and line: wrong column counts, non-numeric cells, a
    missing ``t_s`` column, incomplete sensor triplets, unknown columns,
    non-increasing timestamps, bad ``units``, ``up`` or ``sensor_frame`` values.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from graphsvc.errors import FormatError, InputError
from graphsvc.fileio import StrPath, atomic_writer, read_input_text
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.anatomy import CONVENTIONS, REST_POSE
from graphsvc.sensors.axes import z_up_to_y_up
from graphsvc.store import read_container, write_container

KIND = "recording"
FORMAT_VERSION = 1
CSV_MAGIC = "# graphsvc recording v1"
CONTACTS = ("left", "right", "both", "none")
UNITS = ("m/s2", "g")
_UNIT_NAMES = {"m/s2": "m/s2", "m/s^2": "m/s2", "m/s²": "m/s2", "g": "g"}
UPS = ("y", "z")
SENSOR_FRAMES = ("device", "layout")
_AXES = ("x", "y", "z")
_QUAT = ("w", "x", "y", "z")
_SENSOR_COLUMN = re.compile(r"^(.+)_a([xyz])$")
_ORIENTATION_COLUMN = re.compile(r"^(.+)_q([wxyz])$")
_MARKER_COLUMN = re.compile(r"^(.+)_p([xyz])$")
_POSITION_COLUMNS = ("pos_x_m", "pos_z_m")
_HEADING_COLUMN = "heading_rad"
_BAD_NAME_CHARS = set(',"\r\n')


@dataclass(eq=False)
class Recording:
    """One input stream. T samples of S sensors.

    rate_hz: nominal sample rate, Hz. timestamps_s: (T,) float64 s, finite, strictly
    increasing. accelerations: (T, S, 3) float32 m/s² in each sensor's frame, NaN =
    missing, or None. ground_position: (T, 2) float64 m (x, z) or None. heading: (T,)
    float64 rad about +Y or None. constraints: annotation constraint sets in priority
    order, each a list of {"start_s", "end_s", "require": {"contact":
    left|right|both|none} or {"label": NAME}}. layout: the sensor layout description
    (JSON-able) or None. meta: provenance (JSON-able). orientations: (T, S, 4) float32
    unit quaternions (w, x, y, z), each sensor's frame in the world, NaN = missing, or
    None. marker_names: M names; marker_positions: (T, M, 3) float64 m, NaN = not
    seen, or None."""

    rate_hz: float
    timestamps_s: np.ndarray
    sensor_names: tuple[str, ...]
    accelerations: np.ndarray | None
    ground_position: np.ndarray | None = None
    heading: np.ndarray | None = None
    constraints: list = field(default_factory=list)
    layout: dict | None = None
    meta: dict = field(default_factory=dict)
    orientations: np.ndarray | None = None
    marker_names: tuple[str, ...] = ()
    marker_positions: np.ndarray | None = None

    @property
    def num_samples(self) -> int:
        return int(self.timestamps_s.shape[0])

    @property
    def num_sensors(self) -> int:
        return len(self.sensor_names)

    @property
    def duration_s(self) -> float:
        """Span covered, each sample lasting one nominal period: T / rate_hz for a
        uniformly sampled stream (as Motion.duration_s)."""
        return float(self.timestamps_s[-1] - self.timestamps_s[0]) + 1.0 / self.rate_hz

    def validate(self) -> None:
        """Raise InputError unless the recording is usable (see the class docstring).
        NaN is allowed as "missing" in the readings, ±inf nowhere."""
        validate_recording(self)


# Bounds on time: a rate no sensor has, and a gap between consecutive samples longer
# than a stream could mean (the strategies fill gaps on the graph's grid, so a gap of
# 1e12 s would be 3e13 samples to allocate).
MAX_RATE_HZ = 100_000.0
MAX_GAP_S = 3600.0


def check_rate(rate, what: str = "rate_hz") -> float:
    """`rate` as a float in Hz: finite, positive, at most MAX_RATE_HZ; InputError else."""
    if isinstance(rate, bool) or not isinstance(rate, (int, float, np.integer, np.floating)):
        raise InputError(f"{what} must be a number, got {rate!r}")
    if not math.isfinite(rate) or rate <= 0 or rate > MAX_RATE_HZ:
        raise InputError(f"{what} must be positive and at most {MAX_RATE_HZ:g} Hz, got {rate}")
    return float(rate)


def check_gap(previous_s: float, t_s: float) -> None:
    """InputError when sample times `previous_s` → `t_s` are more than MAX_GAP_S apart."""
    if t_s - previous_s > MAX_GAP_S:
        raise InputError(
            f"{t_s!r} s is {t_s - previous_s:.6g} s after the previous sample at {previous_s!r} s "
            f"(at most {MAX_GAP_S:g} s between samples)"
        )


def validate_recording(rec: Recording) -> None:
    """Recording.validate as a free function."""
    check_rate(rec.rate_hz)
    t = rec.timestamps_s
    if not isinstance(t, np.ndarray) or t.ndim != 1 or t.dtype.kind not in "fiu":
        raise InputError("timestamps_s must be a 1-D numeric array")
    T = t.shape[0]
    if T == 0:
        raise InputError("recording has zero samples")
    if not np.isfinite(t).all():
        raise InputError("timestamps_s contains NaN or infinite values")
    steps = np.diff(t)
    if (steps <= 0).any():
        i = int(np.argmax(steps <= 0)) + 1
        raise InputError(f"timestamps_s must be strictly increasing (sample {i}: {t[i]} after {t[i - 1]})")
    if T > 1 and steps.max() > MAX_GAP_S:
        i = int(np.argmax(steps)) + 1
        try:
            check_gap(float(t[i - 1]), float(t[i]))
        except InputError as exc:
            raise InputError(f"timestamps_s (sample {i}): {exc}") from None
    names = rec.sensor_names
    _check_names("sensor", names)
    if rec.accelerations is not None:
        _check_readings("accelerations", rec.accelerations, (T, len(names), 3))
    if rec.orientations is not None:
        _check_readings("orientations", rec.orientations, (T, len(names), 4))
        q = rec.orientations[np.all(np.isfinite(rec.orientations), axis=-1)]
        if q.size and np.max(np.abs(np.linalg.norm(q, axis=-1) - 1.0)) > 1e-3:
            raise InputError("orientations must be unit quaternions (w, x, y, z), or NaN for missing")
    if rec.marker_positions is not None:
        _check_names("marker", rec.marker_names)
        _check_readings("marker_positions", rec.marker_positions, (T, len(rec.marker_names), 3))
    elif rec.marker_names:
        raise InputError("marker_names given without marker_positions")
    if rec.ground_position is not None:
        _check_readings("ground_position", rec.ground_position, (T, 2))
    if rec.heading is not None:
        _check_readings("heading", rec.heading, (T,))
    validate_constraints(rec.constraints)
    if rec.layout is not None and not isinstance(rec.layout, dict):
        raise InputError(f"layout must be a dict or None, got {type(rec.layout).__name__}")
    if not isinstance(rec.meta, dict):
        raise InputError(f"meta must be a dict, got {type(rec.meta).__name__}")


def _check_names(what: str, names) -> None:
    if not isinstance(names, tuple) or not all(isinstance(n, str) for n in names):
        raise InputError(f"{what}_names must be a tuple of strings")
    for n in names:
        if not n or n != n.strip() or _BAD_NAME_CHARS & set(n):
            raise InputError(f"bad {what} name {n!r} (non-empty, no commas, quotes, newlines or edge spaces)")
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"duplicate {what} names: {', '.join(dup)}")


def _check_readings(name: str, a, shape: tuple[int, ...]) -> None:
    if not isinstance(a, np.ndarray) or a.dtype.kind != "f":
        raise InputError(f"{name} must be a floating-point array")
    if a.shape != shape:
        raise InputError(f"{name} has shape {a.shape}, expected {shape}")
    if np.isinf(a).any():
        raise InputError(f"{name} contains infinite values (use NaN for missing)")


def validate_constraints(constraints) -> None:
    """Raise InputError unless `constraints` is a list of constraint sets, each a
    list of {"start_s": s, "end_s": s, "require": {"contact": ...} | {"label": ...}}
    with 0 <= start_s < end_s."""
    if not isinstance(constraints, list):
        raise InputError("constraints must be a list of constraint sets")
    for i, cset in enumerate(constraints):
        if not isinstance(cset, list):
            raise InputError(f"constraint set {i} must be a list")
        for j, c in enumerate(cset):
            where = f"constraint {j} of set {i}"
            if not isinstance(c, dict) or set(c) != {"start_s", "end_s", "require"}:
                raise InputError(f"{where} must have exactly the keys start_s, end_s, require")
            s, e = c["start_s"], c["end_s"]
            for key, v in (("start_s", s), ("end_s", e)):
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise InputError(f"{where}: {key} must be a finite number, got {v!r}")
            if s < 0 or not s < e:
                raise InputError(f"{where}: need 0 <= start_s < end_s, got {s}..{e}")
            req = c["require"]
            if not isinstance(req, dict) or len(req) != 1:
                raise InputError(f"{where}: require must be {{'contact': ...}} or {{'label': ...}}")
            ((key, value),) = req.items()
            if key == "contact":
                if value not in CONTACTS:
                    raise InputError(f"{where}: contact must be one of {', '.join(CONTACTS)}, got {value!r}")
            elif key == "label":
                if not isinstance(value, str) or not value:
                    raise InputError(f"{where}: label must be a non-empty string, got {value!r}")
            else:
                raise InputError(f"{where}: unknown requirement {key!r} (contact or label)")


# ---------------------------------------------------------------- native .rec


def save_recording(rec: Recording, path: StrPath) -> None:
    """Validate `rec` and write it atomically as a `.rec` container. Equal
    recordings give byte-identical files."""
    rec.validate()
    arrays = {"timestamps_s": np.asarray(rec.timestamps_s, dtype=np.float64)}
    if rec.accelerations is not None:
        arrays["accelerations"] = np.asarray(rec.accelerations, dtype=np.float32)
    if rec.orientations is not None:
        arrays["orientations"] = np.asarray(rec.orientations, dtype=np.float32)
    if rec.marker_positions is not None:
        arrays["marker_positions"] = np.asarray(rec.marker_positions, dtype=np.float64)
    if rec.ground_position is not None:
        arrays["ground_position"] = np.asarray(rec.ground_position, dtype=np.float64)
    if rec.heading is not None:
        arrays["heading"] = np.asarray(rec.heading, dtype=np.float64)
    meta = {
        "rate_hz": float(rec.rate_hz),
        "sensor_names": list(rec.sensor_names),
        "constraints": rec.constraints,
        "layout": rec.layout,
        "meta": rec.meta,
    }
    if rec.marker_positions is not None:
        meta["marker_names"] = list(rec.marker_names)
    write_container(path, KIND, meta, arrays, FORMAT_VERSION)


def load_recording(path: StrPath) -> Recording:
    """Read a `.rec` file. Arrays are read into memory (recordings are small), so
    the file is closed on return. FormatError for anything but an intact, valid
    recording file."""
    meta, arrays, version = read_container(path, kind=KIND, mmap=False)
    if version != FORMAT_VERSION:
        raise FormatError(
            path, f"unsupported recording format version {version} (this graphsvc reads {FORMAT_VERSION})"
        )
    try:
        rate = meta["rate_hz"]
        names = meta["sensor_names"]
        if not isinstance(names, list):
            raise TypeError("sensor_names is not a list")
        rec = Recording(
            rate_hz=rate,
            timestamps_s=arrays["timestamps_s"],
            sensor_names=tuple(names),
            accelerations=arrays.get("accelerations"),
            ground_position=arrays.get("ground_position"),
            heading=arrays.get("heading"),
            constraints=meta["constraints"],
            layout=meta["layout"],
            meta=meta["meta"],
            orientations=arrays.get("orientations"),
            marker_names=tuple(meta.get("marker_names", ())),
            marker_positions=arrays.get("marker_positions"),
        )
    except (KeyError, TypeError) as e:
        raise FormatError(path, f"not a valid recording: missing or bad {e}") from None
    try:
        rec.validate()
    except InputError as e:
        raise FormatError(path, f"not a valid recording: {e}") from None
    return rec


# ---------------------------------------------------------------- CSV


def csv_columns(rec: Recording) -> list[str]:
    """The CSV header export_csv writes for `rec`."""
    cols = ["t_s"]
    if rec.accelerations is not None:
        cols += [f"{n}_a{k}" for n in rec.sensor_names for k in _AXES]
    if rec.orientations is not None:
        cols += [f"{n}_q{k}" for n in rec.sensor_names for k in _QUAT]
    if rec.marker_positions is not None:
        cols += [f"{n}_p{k}" for n in rec.marker_names for k in _AXES]
    if rec.ground_position is not None:
        cols += list(_POSITION_COLUMNS)
    if rec.heading is not None:
        cols.append(_HEADING_COLUMN)
    return cols


def export_csv(rec: Recording, path) -> None:
    """Write `rec` as CSV (format in the module docstring), atomically; NaN → empty
    cell, numbers as '%.9g', so equal recordings give identical files."""
    rec.validate()
    T = rec.num_samples
    parts = [rec.timestamps_s.astype(np.float64)[:, None]]
    for a in (rec.accelerations, rec.orientations, rec.marker_positions):
        if a is not None:
            parts.append(a.astype(np.float64).reshape(T, -1))
    if rec.ground_position is not None:
        parts.append(rec.ground_position.astype(np.float64))
    if rec.heading is not None:
        parts.append(rec.heading.astype(np.float64)[:, None])
    table = np.concatenate(parts, axis=1)
    lines = [CSV_MAGIC, f"# rate_hz={_shortest(rec.rate_hz)}"]
    if rec.meta.get("sensor_frame") == "device":  # (readings not yet calibrated: said, not assumed)
        lines.append("# sensor_frame=device")
    if rec.meta.get("sensor_frames"):
        lines.append(f"# sensor_frames={rec.meta['sensor_frames']}")
    lines.append(",".join(csv_columns(rec)))
    lines += csv_rows(table)
    with atomic_writer(path) as f:
        f.write(("\n".join(lines) + "\n").encode("utf-8"))


def csv_rows(table: np.ndarray) -> list[str]:
    """A CSV's rows of numbers: '%.9g', NaN as an empty cell."""
    return [",".join("" if v != v else f"{v:.9g}" for v in row) for row in table.tolist()]  # (v != v ⇔ NaN)


def _shortest(x: float) -> str:
    """The shortest text that reads back as exactly `x` (30.0 → "30")."""
    s = repr(float(x))
    return s[:-2] if s.endswith(".0") else s


@dataclass
class CsvTable:
    """A CSV file as read by `read_csv_table`: its text, the `# key=value` comments
    before the header (keys lower-cased) and their lines, the header's cells and line,
    what `on_header` made of it, the rows (n, columns) float64 (NaN: empty or nan) and
    their lines."""

    text: str
    comments: dict
    comment_lines: dict
    header: list
    header_line: int
    parsed_header: Any  # (what `on_header` returned)
    table: np.ndarray
    row_lines: list


def read_csv_table(path, expect: str, on_header=None) -> CsvTable:
    """The comma-separated, UTF-8 (a BOM tolerated) file every graphsvc CSV is: blank
    lines skipped, `#` lines comments (`# key=value` before the header kept), then a
    header row and rows of numbers with as many cells (empty or `nan`: NaN; ±inf
    refused). on_header(cells, line) checks the header where it stands; expect: the
    header the "no header row" error suggests. FormatError with the line for anything
    else, and for a file with no row after its header."""
    path = Path(path)
    text = read_input_text(path, encoding="utf-8-sig")  # tolerate a BOM from spreadsheet tools
    comments: dict[str, str] = {}
    comment_lines: dict[str, int] = {}
    header: list[str] | None = None
    header_line = 0
    parsed = None
    rows: list[list[float]] = []
    row_lines: list[int] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            if header is None and "=" in stripped:
                key, _, value = stripped[1:].partition("=")
                comments[key.strip().lower()] = value.strip()
                comment_lines[key.strip().lower()] = lineno
            continue
        cells = [c.strip() for c in line.split(",")]
        if header is None:
            header, header_line = cells, lineno
            parsed = None if on_header is None else on_header(cells, lineno)
            continue
        if len(cells) != len(header):
            raise FormatError(path, f"expected {len(header)} columns, got {len(cells)}", line=lineno)
        rows.append([_parse_cell(path, c, header[k], lineno) for k, c in enumerate(cells)])
        row_lines.append(lineno)
    if header is None:
        raise FormatError(path, f"no header row (expected {expect})")
    if not rows:
        raise FormatError(path, "no samples after the header", line=header_line)
    return CsvTable(
        text, comments, comment_lines, header, header_line, parsed, np.array(rows, dtype=np.float64), row_lines
    )


def import_csv(
    path, rate_hz: float | None = None, units: str | None = None, layout: dict | None = None, up: str | None = None
) -> Recording:
    """Read a CSV recording (ours or a device's; format in the module docstring).

    rate_hz: overrides the file's; else `# rate_hz=` or the median timestamp step.
    units: "m/s2" or "g" for the acceleration columns (g × 9.81 → m/s²); overrides the
    file's `# units=` (default m/s²).
    layout: the sensor layout description to attach.
    up: "y" or "z", the orientations' world up axis; overrides the file's `# up=`.
    FormatError (with the line number) for malformed files."""
    if units is not None and units not in UNITS:
        raise InputError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    if up is not None and up not in UPS:
        raise InputError(f"up must be one of {', '.join(UPS)}, got {up!r}")
    path = Path(path)
    csv = read_csv_table(path, "t_s,<sensor>_ax,...", lambda cells, lineno: _parse_header(path, cells, lineno))
    comments, comment_lines, row_lines, layout_cols = csv.comments, csv.comment_lines, csv.row_lines, csv.parsed_header
    ours = re.match(r"\s*" + re.escape(CSV_MAGIC) + r"[ \t]*(\r?\n|$)", csv.text) is not None  # written by graphsvc

    table = csv.table
    t_col, sensor_names, acc_cols, pos_cols, heading_col, quat_cols, marker_names, marker_cols = layout_cols
    t = table[:, t_col]
    missing = np.isnan(t)
    if missing.any():
        raise FormatError(path, "t_s is empty or nan", line=row_lines[int(np.argmax(missing))])
    bad = np.diff(t) <= 0
    if bad.any():
        i = int(np.argmax(bad)) + 1
        raise FormatError(
            path, f"timestamps must be strictly increasing ({t[i]:g} after {t[i - 1]:g})", line=row_lines[i]
        )

    rate_hz = sample_rate(path, rate_hz, comments, t)

    def gather(cols, width):  # per sensor, its columns or NaN where it has none
        if all(c is None for c in cols):
            return None
        out = np.full((len(t), len(cols)), np.nan)
        for k, c in enumerate(cols):
            if c is not None:
                out[:, k] = table[:, c]
        return out.reshape(len(t), -1, width)

    units, up, sensor_frame, read_from = _device_comments(path, comments, comment_lines, units, up, ours)
    acc = gather(acc_cols, 3)
    if acc is not None and units == "g":
        acc = acc * GRAVITY
    orientations = gather(quat_cols, 4)
    if orientations is not None and up == "z":
        orientations = z_up_to_y_up(orientations)
    rec = Recording(
        rate_hz=float(rate_hz),
        timestamps_s=np.ascontiguousarray(t),
        sensor_names=sensor_names,
        accelerations=None if acc is None else acc.astype(np.float32),
        ground_position=np.ascontiguousarray(table[:, pos_cols]) if pos_cols else None,
        heading=np.ascontiguousarray(table[:, heading_col]) if heading_col is not None else None,
        layout=layout,
        meta={
            "source": str(path),
            "imported_from": "csv",
            "units": units,
            "up": up,
            "sensor_frame": sensor_frame,
            "read_from": read_from,
            **_frames_comment(path, comments, comment_lines, ours and sensor_frame == "layout"),
        },
        orientations=None if orientations is None else orientations.astype(np.float32),
        marker_names=marker_names,
        marker_positions=np.ascontiguousarray(table[:, marker_cols].reshape(len(t), -1, 3)) if marker_cols else None,
    )
    rec.validate()
    return rec


def _frames_comment(path, comments: dict, lines: dict, ours_in_layout: bool) -> dict:
    """{"sensor_frames": convention} from a `# sensor_frames=` comment (`sensors.anatomy`);
    a layout-frame file graphsvc wrote without one predates anatomical frames."""
    if "sensor_frames" not in comments:
        return {"sensor_frames": REST_POSE} if ours_in_layout else {}
    value = comments["sensor_frames"].lower()
    if value not in CONVENTIONS:
        raise FormatError(
            path,
            f"bad sensor_frames comment {comments['sensor_frames']!r} (expected {' or '.join(CONVENTIONS)})",
            line=lines["sensor_frames"],
        )
    return {"sensor_frames": value}


def _device_comments(
    path, comments: dict, lines: dict, units: str | None, up: str | None, ours: bool
) -> tuple[str, str, str, dict]:
    """(units, up, sensor_frame, read_from) of a device CSV: the arguments where given,
    else its `# units=`, `# up=`, `# sensor_frame=` comments, else the defaults (module
    docstring); read_from says which for each: "argument", "file" or "default".
    FormatError with the comment's line for a bad value."""
    read_from = {}

    def setting(key: str, given: str | None, allowed: dict, default: str) -> str:
        if given is not None:
            read_from[key] = "argument"
            return given
        if key not in comments:
            read_from[key] = "default"
            return default
        value = comments[key].lower()
        if value not in allowed:
            expected = " or ".join(dict.fromkeys(allowed.values()))
            raise FormatError(path, f"bad {key} comment {comments[key]!r} (expected {expected})", line=lines[key])
        read_from[key] = "file"
        return allowed[value]

    units = setting("units", units, _UNIT_NAMES, "m/s2")
    up = setting("up", up, {u: u for u in UPS}, "y")
    sensor_frame = setting("sensor_frame", None, {f: f for f in SENSOR_FRAMES}, "layout" if ours else "device")
    return units, up, sensor_frame, read_from


def sample_rate(path, rate_hz: float | None, comments: dict, t: np.ndarray) -> float:
    """A CSV's sample rate: `rate_hz` when given, else its `# rate_hz=` comment, else the
    median step of its timestamps t (s)."""
    if rate_hz is None and "rate_hz" in comments:
        try:
            rate_hz = float(comments["rate_hz"])
        except ValueError:
            raise FormatError(path, f"bad rate_hz comment {comments['rate_hz']!r}") from None
    if rate_hz is None:
        if len(t) < 2:
            raise InputError(f"{path}: cannot infer the sample rate from one sample; pass rate_hz")
        rate_hz = 1.0 / float(np.median(np.diff(t)))
    return float(rate_hz)


def _parse_header(path: Path, cols: list[str], lineno: int):
    """Column indices: (t, sensor names, acceleration columns in (sensor, axis)
    order, position columns or [], heading column or None)."""
    seen: dict[str, int] = {}
    for k, c in enumerate(cols):
        if not c:
            raise FormatError(path, f"column {k + 1} has an empty name", line=lineno)
        if c in seen:
            raise FormatError(path, f"duplicate column {c!r}", line=lineno)
        seen[c] = k
    if "t_s" not in seen:
        raise FormatError(path, "missing t_s column (seconds)", line=lineno)
    sensors: dict[str, dict[str, dict[str, int]]] = {}  # name → {"a": axes, "q": components}
    markers: dict[str, dict[str, int]] = {}
    for c, k in seen.items():
        m, q, p = _SENSOR_COLUMN.match(c), _ORIENTATION_COLUMN.match(c), _MARKER_COLUMN.match(c)
        if m:
            sensors.setdefault(m.group(1), {}).setdefault("a", {})[m.group(2)] = k
        elif q:
            sensors.setdefault(q.group(1), {}).setdefault("q", {})[q.group(2)] = k
        elif p:
            markers.setdefault(p.group(1), {})[p.group(2)] = k
        elif c not in ("t_s", _HEADING_COLUMN, *_POSITION_COLUMNS):
            raise FormatError(
                path,
                f"unknown column {c!r} (expected t_s, <sensor>_ax/_ay/_az, <sensor>_qw…_qz, "
                f"<marker>_px/_py/_pz, {', '.join(_POSITION_COLUMNS)}, {_HEADING_COLUMN})",
                line=lineno,
            )
    acc_cols: list[int | None] = []
    quat_cols: list[int | None] = []
    any_acc = any("a" in v for v in sensors.values())
    any_quat = any("q" in v for v in sensors.values())
    for name, kinds in sensors.items():
        if name != name.strip() or '"' in name:
            raise FormatError(path, f"bad sensor name {name!r}", line=lineno)
        for key, parts, into, wanted in (("a", _AXES, acc_cols, any_acc), ("q", _QUAT, quat_cols, any_quat)):
            got = kinds.get(key)
            if got is not None:
                absent = [f"{name}_{key}{a}" for a in parts if a not in got]
                if absent:
                    raise FormatError(path, f"sensor {name!r} lacks column(s) {', '.join(absent)}", line=lineno)
                into += [got[a] for a in parts]
            elif wanted:
                into += [None] * len(parts)
    marker_cols: list[int] = []
    for name, axes in markers.items():
        absent = [f"{name}_p{a}" for a in _AXES if a not in axes]
        if absent:
            raise FormatError(path, f"marker {name!r} lacks column(s) {', '.join(absent)}", line=lineno)
        marker_cols += [axes[a] for a in _AXES]
    have_pos = [c in seen for c in _POSITION_COLUMNS]
    if any(have_pos) and not all(have_pos):
        raise FormatError(path, "pos_x_m and pos_z_m must both be present or both absent", line=lineno)
    pos_cols = [seen[c] for c in _POSITION_COLUMNS] if all(have_pos) else []
    return (
        seen["t_s"],
        tuple(sensors),
        acc_cols,
        pos_cols,
        seen.get(_HEADING_COLUMN),
        quat_cols,
        tuple(markers),
        marker_cols,
    )


def _parse_cell(path: Path, cell: str, column: str, lineno: int) -> float:
    if not cell or cell.lower() == "nan":
        return math.nan
    try:
        v = float(cell)
    except ValueError:
        raise FormatError(path, f"non-numeric value {cell!r} in column {column}", line=lineno) from None
    if math.isinf(v):
        raise FormatError(
            path, f"infinite value {cell!r} in column {column} (leave the cell empty for missing)", line=lineno
        )
    if v != v:  # float() also reads "+nan", "-NaN"
        return math.nan
    return v


# ---------------------------------------------------------------- inspect


def describe_recording(rec: Recording) -> dict:
    """What `graphsvc inspect` shows of a recording: {"samples", "sensors" (names),
    "channels" (e.g. "l_wrist.ax", ..., "ground_position.x", "ground_position.z",
    "heading"), "rate_hz", "duration_s", "has_ground_position", "has_heading",
    "constraint_sets"}; with markers, "markers" (names) and "markers_seen" (the
    share of marker samples seen); for a device file (CSV, MVNX), "reading": how its
    sensor frame, up axis and units were read (`reading_settings`)."""
    channels = [f"{n}.a{k}" for n in rec.sensor_names for k in _AXES] if rec.accelerations is not None else []
    if rec.orientations is not None:
        channels += [f"{n}.q{k}" for n in rec.sensor_names for k in _QUAT]
    if rec.marker_positions is not None:
        channels += [f"{n}.p{k}" for n in rec.marker_names for k in _AXES]
    if rec.ground_position is not None:
        channels += ["ground_position.x", "ground_position.z"]
    if rec.heading is not None:
        channels.append("heading")
    out = {
        "samples": rec.num_samples,
        "sensors": list(rec.sensor_names),
        "channels": channels,
        "rate_hz": float(rec.rate_hz),
        "duration_s": round(rec.duration_s, 6),
        "has_ground_position": rec.ground_position is not None,
        "has_heading": rec.heading is not None,
        "constraint_sets": len(rec.constraints),
    }
    if rec.marker_positions is not None:
        out["markers"] = list(rec.marker_names)
        out["markers_seen"] = round(float(np.isfinite(rec.marker_positions).all(axis=-1).mean()), 4)
    reading = reading_settings(rec.meta)
    if reading:
        out["reading"] = reading
    return out


# What an MVNX export fixes: readings in each device's frame, m/s², a Z-up world.
_MVNX_SETTINGS = {"sensor_frame": "device", "up": "z", "units": "m/s2"}


def reading_settings(meta: dict) -> dict:
    """{setting: {"value", "from"}} for a device file's sensor_frame, up and units:
    from "argument" (a flag), "file" (a CSV's header comment), "format" (what MVNX
    fixes) or "default"; {} for a recording of another kind (a .rec, a marker file)."""
    if meta.get("imported_from") == "mvnx":
        return {k: {"value": v, "from": "format"} for k, v in _MVNX_SETTINGS.items()}
    read_from = meta.get("read_from")
    if meta.get("imported_from") != "csv" or not isinstance(read_from, dict):  # (or read before it was kept)
        return {}
    return {
        k: {"value": meta[k], "from": read_from[k]}
        for k in ("sensor_frame", "up", "units")
        if k in meta and read_from.get(k) in ("argument", "file", "default")
    }
