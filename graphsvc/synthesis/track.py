"""The root's ground track fused with an overhead tracker's noisy positions.

A reconstruction's own root track (its path's edge offsets, or its frames' root
steps, integrated from the start) drifts from where the performer is: its steps are
the knowledge base's, not the performer's. The tracker says where the performer is,
with white noise of σ (10 cm for Kelly et al.'s system). The fusion estimates the
offset d between the two, per axis of the ground plane, as a Kalman state with a
constant-velocity model whose motion stops while both feet are planted:

    d_{t+1} = d_t + g_t·ḋ_t·Δt,   ḋ_{t+1} = ḋ_t + w_t,   w ~ N(0, drift²·Δt)
    z_t = (measured − own)_t = d_t + v_t,                v ~ N(0, σ²)

`drift` (m/s per √s) says how fast the offset's rate may wander; g_t is 0 where the
own motion has both feet on the ground into frame t and 1 elsewhere, so the
correction moves the body only while a foot is free (in single support, flight, or
where the motion has no contacts): a standing performer's tracker noise is averaged
over the whole stance instead of sliding the planted feet about.

Batch: the Rauch–Tung–Striebel smoother (forward Kalman filter, backward pass) over
the whole input — the offsets that maximise the likelihood of all measurements at
once, a smooth (C¹ where the body moves) curve that the tracker's noise does not
shake. Live: the same smoother over the last `lag` frames (`FixedLagSmoother`), whose
estimate of frame t − lag once frame t is in equals the batch smoother's over the
samples up to t; a stream emits frame t − lag then, so it adds no latency where the
synthesis already waits `lag` frames.

Written here, not taken from a library: a two-state smoother a sample is a few lines
of numba, where the Kalman packages (filterpy, pykalman) add matrix overhead per step
and are not kept up (filterpy's last release is from 2018).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from graphsvc.graph import metadata as meta
from graphsvc.graph.model import MotionGraph
from graphsvc.motion.quat import wrap_angle

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")

# A first estimate's spread: the offset and its rate are unknown before the first
# measurement (m, m/s).
PRIOR_OFFSET_M = 10.0
PRIOR_RATE_M_S = 5.0


@dataclass(frozen=True)
class TrackModel:
    """sigma_m: the tracker's white noise σ (m); drift: how fast the offset's rate may
    wander (m/s per √s); rate_hz: samples a second."""

    sigma_m: float
    drift: float
    rate_hz: float

    def noise(self) -> tuple[float, float, float]:
        """(Δt, s, r): the step (s), the spectral density drift² of the white
        acceleration that moves the offset's rate, and the measurement variance σ²."""
        return 1.0 / float(self.rate_hz), float(self.drift) ** 2, float(self.sigma_m) ** 2


def free_steps(contacts: np.ndarray) -> np.ndarray:
    """g (T,): 1.0 where a frame's own motion has a foot off the ground, 0.0 where both
    are planted (contacts (T, 2) bool), with which the offset moves into that frame."""
    c = np.asarray(contacts, dtype=bool).reshape(-1, 2)
    return np.where(c[:, 0] & c[:, 1], 0.0, 1.0)


@_jit
def _step_noise(dt, s, g):
    """The process noise (q11, q12, q22) of one step of the gated constant-velocity
    model: the offset moves g·ḋ·Δt, its rate takes a white acceleration of density s."""
    e = g * dt
    return s * e * e * e / 3.0, s * e * e / 2.0, s * dt


@_jit
def _store(state, x, P, t):
    """The state (`_forward`'s layout) into x[t] (2, 2) [axis, (d, ḋ)] and P[t] (2, 2)."""
    x[t, 0, 0] = state[1]
    x[t, 0, 1] = state[2]
    x[t, 1, 0] = state[3]
    x[t, 1, 1] = state[4]
    P[t, 0, 0] = state[5]
    P[t, 0, 1] = state[6]
    P[t, 1, 0] = state[6]
    P[t, 1, 1] = state[7]


@_jit
def _forward(z, g, dt, s, r, state, x, P, xp, Pp):
    """Kalman filter over z (T, 2) (NaN: no measurement) with the steps' gates g (T,)
    (`free_steps`), per axis, from `state` (8,): [started, d₀, ḋ₀, d₁, ḋ₁, p11, p12,
    p22], carried from the previous call (started 0: the prior), updated in place.
    Writes the filtered state x (T, 2, 2) [axis, (d, ḋ)], its covariance P (T, 2, 2)
    (shared by the axes: they see the same times) and the predicted xp, Pp for the
    backward pass."""
    T = z.shape[0]
    for t in range(T):
        if state[0] == 0.0:
            state[0] = 1.0
            state[1] = 0.0
            state[2] = 0.0
            state[3] = 0.0
            state[4] = 0.0
            state[5] = PRIOR_OFFSET_M * PRIOR_OFFSET_M
            state[6] = 0.0
            state[7] = PRIOR_RATE_M_S * PRIOR_RATE_M_S
        else:
            e = g[t] * dt
            q11, q12, q22 = _step_noise(dt, s, g[t])
            state[1] = state[1] + e * state[2]
            state[3] = state[3] + e * state[4]
            p11, p12, p22 = state[5], state[6], state[7]
            state[5] = p11 + 2.0 * e * p12 + e * e * p22 + q11
            state[6] = p12 + e * p22 + q12
            state[7] = p22 + q22
        _store(state, xp, Pp, t)
        if not (np.isnan(z[t, 0]) or np.isnan(z[t, 1])):
            p11, p12, p22 = state[5], state[6], state[7]
            innov_var = p11 + r
            k1 = p11 / innov_var
            k2 = p12 / innov_var
            innov0 = z[t, 0] - state[1]
            innov1 = z[t, 1] - state[3]
            state[1] = state[1] + k1 * innov0
            state[2] = state[2] + k2 * innov0
            state[3] = state[3] + k1 * innov1
            state[4] = state[4] + k2 * innov1
            state[5] = (1.0 - k1) * p11
            state[6] = (1.0 - k1) * p12
            state[7] = p22 - k2 * p12
        _store(state, x, P, t)


@_jit
def _backward(x, P, xp, Pp, g, dt, first, last, out):
    """Rauch–Tung–Striebel pass from `last` down to `first` (inclusive): the smoothed
    offsets (d) into out[t − first] for t in [first, last], given the filter's x, P,
    xp, Pp (`_forward`) and the steps' gates g; the state at `last` is its filtered one."""
    s0 = x[last, 0, 0]
    s0d = x[last, 0, 1]
    s1 = x[last, 1, 0]
    s1d = x[last, 1, 1]
    out[last - first, 0] = s0
    out[last - first, 1] = s1
    for t in range(last - 1, first - 1, -1):
        # C = P_t F' (P_{t+1|t})^-1, F = [[1, g·dt], [0, 1]]
        e = g[t + 1] * dt
        f11 = P[t, 0, 0] + e * P[t, 0, 1]
        f12 = P[t, 0, 1]
        f21 = P[t, 1, 0] + e * P[t, 1, 1]
        f22 = P[t, 1, 1]
        a = Pp[t + 1, 0, 0]
        b = Pp[t + 1, 0, 1]
        d = Pp[t + 1, 1, 1]
        det = a * d - b * b
        i11 = d / det
        i12 = -b / det
        i22 = a / det
        c11 = f11 * i11 + f12 * i12
        c12 = f11 * i12 + f12 * i22
        c21 = f21 * i11 + f22 * i12
        c22 = f21 * i12 + f22 * i22
        e0 = s0 - xp[t + 1, 0, 0]
        e0d = s0d - xp[t + 1, 0, 1]
        e1 = s1 - xp[t + 1, 1, 0]
        e1d = s1d - xp[t + 1, 1, 1]
        s0 = x[t, 0, 0] + c11 * e0 + c12 * e0d
        s0d = x[t, 0, 1] + c21 * e0 + c22 * e0d
        s1 = x[t, 1, 0] + c11 * e1 + c12 * e1d
        s1d = x[t, 1, 1] + c21 * e1 + c22 * e1d
        out[t - first, 0] = s0
        out[t - first, 1] = s1


def _filtered(z: np.ndarray, g: np.ndarray, model: TrackModel, state: np.ndarray | None = None):
    dt, s, r = model.noise()
    T = z.shape[0]
    x, P = np.zeros((T, 2, 2)), np.zeros((T, 2, 2))
    xp, Pp = np.zeros((T, 2, 2)), np.zeros((T, 2, 2))
    _forward(z, g, dt, s, r, np.zeros(8) if state is None else state, x, P, xp, Pp)
    return x, P, xp, Pp, dt


def _gates(free, T: int) -> np.ndarray:
    if free is None:
        return np.ones(T)
    g = np.asarray(free, dtype=np.float64).reshape(-1)
    if g.shape[0] != T:
        raise ValueError(f"free must have one gate a frame ({T}), got {g.shape[0]}")
    return np.ascontiguousarray(g)


def smooth_offsets(z: np.ndarray, model: TrackModel, free: np.ndarray | None = None) -> np.ndarray:
    """The smoothed offsets (T, 2) m from measured − own track z (T, 2) (NaN: no
    measurement), the offset moving into frame t by free[t] (`free_steps`; None: always):
    the Rauch–Tung–Striebel smoother over the whole input. Before the first measurement
    the offsets are the first estimate's; with none, zero."""
    z = np.asarray(z, dtype=np.float64).reshape(-1, 2)
    T = z.shape[0]
    g = _gates(free, T)
    if T == 0 or not np.isfinite(z).all(axis=1).any():
        return np.zeros((T, 2))
    x, P, xp, Pp, dt = _filtered(z, g, model)
    out = np.zeros((T, 2))
    _backward(x, P, xp, Pp, g, dt, 0, T - 1, out)
    return out


class FixedLagSmoother:
    """The smoother live: `push` one measured − own offset (2,) (NaN: none) a frame; the
    offset of frame t is final once frame t + lag is in (`final`), and equals the batch
    smoother's over the frames up to t + lag bit for bit (the same filter steps, one at a
    time, and the same backward pass over the last lag + 1 frames). Memory: the filter's
    state of the last lag + 1 frames."""

    def __init__(self, model: TrackModel, lag: int):
        self.model = model
        self.lag = max(0, int(lag))
        self.state = np.zeros(8)
        self.frames = 0  # frames pushed
        self.seen = False  # any measurement yet
        self._x: list = []  # (x, P, xp, Pp) of the last lag + 1 frames, oldest first
        self.finals: dict[int, np.ndarray] = {}  # frame → its final offset, until taken

    def push(self, z, free: float = 1.0) -> None:
        """z: the frame's measured − own offset (2,); free: its gate (`free_steps`)."""
        z = np.asarray(z, dtype=np.float64).reshape(1, 2)
        self.seen |= bool(np.isfinite(z).all())
        g = np.array([float(free)])
        x, P, xp, Pp, dt = _filtered(z, g, self.model, self.state)
        self._x.append((x[0], P[0], xp[0], Pp[0], g[0]))
        del self._x[: max(0, len(self._x) - (self.lag + 1))]
        self.frames += 1
        t = self.frames - 1 - self.lag
        if t >= 0:
            self.finals[t] = self._smoothed(dt)

    def flush(self) -> None:
        """At the end of the input: the frames still held back become final."""
        if not self._x:
            return
        dt = self.model.noise()[0]
        n = len(self._x)
        out = self._pass(dt, n)
        for k in range(max(0, n - self.lag), n):  # (the first was made final by its push)
            self.finals[self.frames - n + k] = out[k]

    def take(self, t: int) -> np.ndarray:
        """Frame t's final offset (2,), forgotten here once taken."""
        return self.finals.pop(t)

    def _pass(self, dt: float, n: int) -> np.ndarray:
        x = np.array([e[0] for e in self._x])
        P = np.array([e[1] for e in self._x])
        xp = np.array([e[2] for e in self._x])
        Pp = np.array([e[3] for e in self._x])
        g = np.array([e[4] for e in self._x])
        out = np.zeros((n, 2))
        if self.seen:
            _backward(x, P, xp, Pp, g, dt, 0, n - 1, out)
        return out

    def _smoothed(self, dt: float) -> np.ndarray:
        return self._pass(dt, len(self._x))[0]


def fused_track(
    graph: MotionGraph,
    node_path: np.ndarray,
    edge_path: np.ndarray,
    start_ground,
    start_heading: float,
    positions: np.ndarray,
    model: TrackModel,
) -> np.ndarray:
    """The root's ground track (T, 2) m along a path (nodes (T,), edges (T−1,)): its own
    track (the edges' offsets integrated from the start) plus the smoothed offset to the
    tracker's positions (T, 2) (NaN where none; `smooth_offsets`, moving only while the
    path's nodes have a foot off the ground); for `synthesize_motion`'s track."""
    edge_path = np.asarray(edge_path, dtype=np.int64).reshape(-1)
    free = free_steps(graph.node_contacts[np.asarray(node_path, dtype=np.int64).reshape(-1)])
    own, _ = meta.integrate_path(
        np.asarray(start_ground, dtype=np.float64),
        float(start_heading),
        graph.edge_offset[edge_path].astype(np.float64),
        graph.edge_heading[edge_path].astype(np.float64),
    )
    return own + smooth_offsets(np.asarray(positions, dtype=np.float64).reshape(-1, 2) - own, model, free)


def advance_own_track(state, step, turn: float, contacts, position, heading) -> None:
    """One frame of a per-frame strategy's root, in place on `state` (a decoder with t
    (this frame's number), own (2,) its own track, heading (rad), placed,
    heading_placed, filter (a `FixedLagSmoother` of lag 0, or None), track_inputs (a
    list or None), alpha (the heading's pull) and ground (2,)): after the first frame
    the own track moves by its step (2,) m, taken in the previous heading's frame, and
    turns by `turn`; it is snapped to the first measured position and heading; with a
    filter, the offset to the measured positions is filtered (moving only where
    `contacts` (2,) bool has a foot free) and `ground` is the own track plus it (each
    frame's measurement, gate and filtered offset appended to track_inputs, for a
    batch's `shift_to_smoothed`); the heading is pulled toward the measured one by
    the share alpha."""
    if state.t > 0:
        state.own = (
            state.own
            + meta.rotate_ground(np.asarray(step, dtype=np.float64)[None], np.array([state.heading]), np.zeros((1, 2)))[
                0
            ]
        )
        state.heading = float(wrap_angle(state.heading + turn))
    measured = position is not None and bool(np.all(np.isfinite(position)))
    if measured and not state.placed:
        state.own, state.placed = np.asarray(position, dtype=np.float64).copy(), True
    state.ground = state.own
    if state.filter is not None:
        z = np.asarray(position, dtype=np.float64) - state.own if measured else np.full(2, np.nan)
        free = float(free_steps(np.asarray(contacts)[None])[0])
        state.filter.push(z, free)
        offset = state.filter.take(state.t)
        state.ground = state.own + offset
        if state.track_inputs is not None:
            state.track_inputs.append((z, free, offset))
    if heading is not None and math.isfinite(heading):
        if not state.heading_placed:
            state.heading, state.heading_placed = float(heading), True
        elif state.alpha > 0.0:
            state.heading = float(wrap_angle(state.heading + state.alpha * float(wrap_angle(heading - state.heading))))


def shift_to_smoothed(inputs: list | None, model: TrackModel | None, parents: np.ndarray, trans: np.ndarray) -> None:
    """A batch run's root, in place on translations (T, J, 3): each frame shifted from
    the filtered offset a live frame gets (`advance_own_track`'s track_inputs) to the
    smoother's over the whole recording, the whole body at once."""
    if not inputs or model is None:
        return
    z = np.array([i[0] for i in inputs])
    free = np.array([i[1] for i in inputs])
    shift = smooth_offsets(z, model, free) - np.array([i[2] for i in inputs])
    for root in np.flatnonzero(np.asarray(parents) < 0):
        trans[:, root, 0] += shift[:, 0]
        trans[:, root, 2] += shift[:, 1]


def warm_up_track() -> None:
    """Smooth and filter a few samples, so numba compiles (or loads from its cache) the
    smoother's kernels now, not on a client's first frames."""
    model = TrackModel(0.1, 0.3, 30.0)
    z = np.zeros((3, 2))
    smooth_offsets(z, model, np.array([1.0, 0.0, 1.0]))
    live = FixedLagSmoother(model, 1)
    for row in z:
        live.push(row, 1.0)
