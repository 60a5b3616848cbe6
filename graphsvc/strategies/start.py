"""Where a reconstruction starts: its first ground position and heading, estimated from
the measurements of its first second (`start_placement`), or the first measured ones
(`first_measured`) for a strategy that cannot wait for them."""

from __future__ import annotations

import numpy as np

# Where a reconstruction starts is estimated from the measurements of its first second:
# anchoring it to the first sample alone carried that sample's tracker noise (σ 10 cm,
# 10° by default) into the whole path.
START_WINDOW_S = 1.0
# Without a measured heading, a reconstruction starts facing its track's direction of
# travel when the track moves at least this far (m) over the first second (a standing
# performer keeps facing +Z: the track says nothing of the facing).
START_TRAVEL_M = 0.3


def start_samples(rate_hz: float) -> int:
    """How many samples `start_placement` reads at the graph rate (a live decoder waits
    for them before its search starts)."""
    return max(1, int(round(START_WINDOW_S * float(rate_hz))))


# Below these white-noise levels (estimated from the measurements' second differences)
# the first measurement is the start: a line cannot follow a walk's sway, so its
# intercept is off by a centimetre or two where the measurements themselves are not.
EXACT_POSITION_M = 0.02
EXACT_HEADING_RAD = np.radians(2.0)


def _white_noise(values: np.ndarray) -> float:
    """The white noise σ of samples of a smooth signal (n, ...): from the median
    absolute second difference (σ·√6 for white noise; a smooth motion's own second
    differences at 30 Hz are millimetres)."""
    if len(values) < 3:
        return 0.0
    d2 = values[2:] - 2.0 * values[1:-1] + values[:-2]
    return float(np.median(np.abs(d2)) / 0.6745 / np.sqrt(6.0))


def start_placement(position, heading, rate_hz: float) -> tuple[np.ndarray | None, float | None]:
    """Where a reconstruction starts, from the measurements of its first
    `start_samples(rate_hz)` samples (a live decoder has them all before it starts):
    ground position (2,) m and heading rad, None for what they do not tell (the search
    then anchors to the first later measurement: `ViterbiSearch._anchor`).

    - Position: the value at sample 0 of a straight line fitted to the window's
      measured positions — its intercept, where one sample's noise shrinks by about
      2 / √n — unless they are exact (white noise below EXACT_POSITION_M) and
      sample 0 is measured: then that sample; with fewer than three measured, the
      first measured position.
    - Heading measured: the same with the window's unwrapped headings
      (EXACT_HEADING_RAD).
    - Only positions measured: the direction of travel of the fitted line, when the
      track moves at least START_TRAVEL_M over the window.
    position (T, 2) or None, heading (T,) or None (only the window is read)."""
    W = start_samples(rate_hz)
    p0 = velocity = None
    if position is not None:
        pos = np.asarray(position, dtype=np.float64)[:W]
        t = np.flatnonzero(np.isfinite(pos).all(axis=1))
        if len(t) >= 3:
            slope, p0 = np.polyfit(t.astype(np.float64), pos[t], 1)  # (2,) each
            velocity = slope * float(rate_hz)
            if _white_noise(pos[t]) < EXACT_POSITION_M and t[0] == 0:
                p0 = pos[0].copy()  # (exact: the first sample, unless it is missing)
        elif len(t):
            p0 = pos[t[0]].copy()
    h0 = None
    if heading is not None:
        head = np.asarray(heading, dtype=np.float64)[:W]
        t = np.flatnonzero(np.isfinite(head))
        if len(t) >= 3 and (t[0] > 0 or _white_noise(np.unwrap(head[t])) >= EXACT_HEADING_RAD):
            h0 = float(np.polyfit(t.astype(np.float64), np.unwrap(head[t]), 1)[1])
        elif len(t):
            h0 = float(head[t[0]])
    if h0 is None and velocity is not None and float(np.hypot(*velocity)) * (W - 1) / rate_hz >= START_TRAVEL_M:
        h0 = float(np.arctan2(velocity[0], velocity[1]))  # (0 faces +Z, positive toward +X)
    if h0 is not None:
        h0 = float(h0 - 2.0 * np.pi * np.floor((h0 + np.pi) / (2.0 * np.pi)))  # [−π, π)
    return p0, h0


def first_measured(position, heading) -> tuple[np.ndarray, float]:
    """The first measured ground position (T, 2) m and heading (T,) rad, else the
    origin facing +Z: where a strategy that decides each frame at once (a live
    `nearest` session cannot wait for `start_placement`'s second) places its start."""
    g = np.zeros(2)
    if position is not None:
        measured = np.flatnonzero(np.isfinite(position).all(axis=1))
        if len(measured):
            g = np.asarray(position[measured[0]], dtype=np.float64)
    h = 0.0
    if heading is not None:
        measured = np.flatnonzero(np.isfinite(heading))
        if len(measured):
            h = float(heading[measured[0]])
    return g, h


def start_state(position, heading, rate_hz: float) -> tuple[np.ndarray, float]:
    """`start_placement` with what it cannot tell filled in: the first measured position
    and heading, else the origin, facing +Z (where the search's paths start)."""
    p0, h0 = start_placement(position, heading, rate_hz)
    g, h = first_measured(position, heading)
    return (g if p0 is None else np.asarray(p0, dtype=np.float64)), (h if h0 is None else h0)
