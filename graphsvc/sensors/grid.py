"""A recording's samples on a uniform grid at a given rate: what a strategy searches
(the graph's rate), what calibration and the report compare with a motion.

Linear interpolation from the recording's own timestamps (headings the short way
round; NaN at either neighbouring sample stays NaN: a gap stays a gap, a marker unseen
at either is unseen between them), or the values untouched when the recording is
already uniform at that rate.
"""

from __future__ import annotations

import math

import numpy as np

from graphsvc.motion import quat
from graphsvc.sensors.recording import Recording


def interp_linear(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Linear interpolation along axis 0; NaN at either neighbour gives NaN (a gap
    stays a gap)."""
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    w = ((at - times[i]) / (times[i + 1] - times[i])).reshape((-1,) + (1,) * (values.ndim - 1))
    return values[i] * (1.0 - w) + values[i + 1] * w


def interp_angle(times: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Angles (rad) interpolated the short way round, wrapped to [−π, π)."""
    i = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 2)
    w = (at - times[i]) / (times[i + 1] - times[i])
    return quat.wrap_angle(values[i] + w * quat.wrap_angle(values[i + 1] - values[i]))


def uniform_grid(rec: Recording, rate_hz: float) -> tuple[np.ndarray, np.ndarray | None]:
    """The recording's timestamps and the uniform grid at `rate_hz` from its first
    (None: already uniform at that rate, or a single sample)."""
    t = np.asarray(rec.timestamps_s, dtype=np.float64)
    period = 1.0 / rate_hz
    uniform = abs(rec.rate_hz - rate_hz) < 1e-9 * rate_hz and (
        t.size < 2 or np.max(np.abs(np.diff(t) - period)) < 0.01 * period
    )
    if uniform or t.size < 2:
        return t, None
    n = int(math.floor((t[-1] - t[0]) * rate_hz + 1e-6)) + 1
    return t, t[0] + np.arange(n) * period


def readings_at_rate(rec: Recording, rate_hz: float) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, bool]:
    """The recording's accelerations (T', S, 3), positions (T', 2) and headings (T',)
    on the uniform grid at `rate_hz` from its first timestamp. Returns (acc, position,
    heading, resampled); a recording without accelerations gives (T', 0, 3)."""
    t, grid = uniform_grid(rec, rate_hz)
    acc = np.asarray(rec.accelerations, dtype=np.float64) if rec.accelerations is not None else np.zeros((t.size, 0, 3))
    if grid is None:
        return acc, rec.ground_position, rec.heading, False
    position = None if rec.ground_position is None else interp_linear(t, np.asarray(rec.ground_position, float), grid)
    heading = None if rec.heading is None else interp_angle(t, np.asarray(rec.heading, float), grid)
    return interp_linear(t, acc, grid), position, heading, True


def values_at_rate(rec: Recording, values: np.ndarray, rate_hz: float) -> np.ndarray:
    """Per-sample values of the recording (T, ...) on `readings_at_rate`'s grid,
    interpolated linearly (NaN stays a gap)."""
    t, grid = uniform_grid(rec, rate_hz)
    values = np.asarray(values, dtype=np.float64)
    return values if grid is None else interp_linear(t, values, grid)


def markers_at_rate(rec: Recording, rate_hz: float) -> np.ndarray | None:
    """The recording's marker positions (T', M, 3) on `readings_at_rate`'s grid (a
    marker unseen at either neighbouring sample is unseen between them), or None."""
    if rec.marker_positions is None:
        return None
    return values_at_rate(rec, rec.marker_positions, rate_hz)
