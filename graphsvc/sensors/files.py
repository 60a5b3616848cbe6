"""Recording files by format: which reader reads a file, from its suffix and, for a
CSV, its header — the native container and a device CSV (`sensors.recording`), an
Xsens MVNX file (`sensors.devices`), a C3D file and a marker CSV (`sensors.optical`).
"""

from __future__ import annotations

from pathlib import Path

from graphsvc.errors import InputError
from graphsvc.fileio import StrPath
from graphsvc.sensors.devices import read_mvnx
from graphsvc.sensors.optical import read_c3d, read_marker_csv
from graphsvc.sensors.recording import UNITS, Recording, import_csv, load_recording

# The suffixes of the recording files `read_recording` reads (any other: the native container).
RECORDING_SUFFIXES = (".rec", ".csv", ".c3d", ".mvnx")


def is_marker_csv(path) -> bool:
    """Whether a CSV file is a marker CSV (its header's first column is `time`)."""
    try:
        with open(path, encoding="utf-8-sig") as f:
            for line in f:
                s = line.strip()
                if s and not s.startswith("#"):
                    return s.split(",")[0].strip().lower() in ("time", "time_s")
    except (OSError, UnicodeDecodeError):
        return False
    return False


def read_recording(
    path: StrPath, rate_hz: float | None = None, up: str | None = None, units: str | None = None
) -> Recording:
    """A recording from a `.rec` file, a device CSV, an Xsens MVNX file, a C3D file or a
    marker CSV (by suffix, and a CSV by its first column: `time` for markers, `t_s` for
    devices). up, units: where the file does not say, for marker files the vertical axis
    and length unit (m, cm, mm; `sensors.optical`), for a device CSV its orientations'
    up axis and acceleration unit (m/s2, g); an MVNX file takes neither (Xsens's axes
    and units)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".mvnx":
        if up is not None or units is not None:
            raise InputError(f"{path}: up and units do not apply to an MVNX file (Xsens's axes, m/s²)")
        return read_mvnx(path)
    if suffix not in (".c3d", ".csv"):
        return load_recording(path)
    if suffix == ".csv" and not is_marker_csv(path):
        if units is not None and units not in UNITS:
            raise InputError(f"{path}: a device CSV's acceleration unit is {' or '.join(UNITS)}, not {units!r}")
        return import_csv(path, rate_hz=rate_hz, units=units, up=up)
    if units in UNITS:
        raise InputError(f"{path}: {units} is an acceleration unit; a marker file's unit is a length (m, cm, mm)")
    if suffix == ".c3d":
        return read_c3d(path, up=up, units=units)
    return read_marker_csv(path, up=up, units=units, rate_hz=rate_hz)
