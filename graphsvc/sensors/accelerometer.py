"""Virtual accelerometers (Tautges 2012, §3.3).

reading = R_sensorᵀ · (p̈_world + g_up), g_up = (0, +9.81, 0): a sensor at rest reads
+1 g upward in its own frame. p̈ comes from the 5-point stencil (TH eq. 3.1–3.2),
O(h⁴); the first and last two frames use one-sided six-point stencils of the same
order, so clip edges get finite, equally accurate values. The kernels are numba:
knowledge bases are many short clips, where numpy call overhead would dominate.
"""

from __future__ import annotations

import numba
import numpy as np

from graphsvc.motion.kinematics import qmul, qrot
from graphsvc.sensors.layout import Placement

GRAVITY = 9.81  # m/s², the unit "g" of all costs 
G_UP = np.array([0.0, GRAVITY, 0.0])

_CENTRAL = np.array([-1.0, 16.0, -30.0, 16.0, -1.0]) / 12.0
_FORWARD0 = np.array([45.0, -154.0, 214.0, -156.0, 61.0, -10.0]) / 12.0  # f''(x0) from x0..x5
_FORWARD1 = np.array([10.0, -15.0, -4.0, 14.0, -6.0, 1.0]) / 12.0  # f''(x1) from x0..x5


@numba.njit(cache=True, nogil=True)
def _second_derivative(x, rate_hz, out):
    """x, out: (F, K). See second_derivative."""
    F, K = x.shape
    inv_h2 = rate_hz * rate_hz
    out[:] = 0.0
    if F < 3:
        return
    if F < 6:
        for t in range(1, F - 1):
            for k in range(K):
                out[t, k] = (x[t + 1, k] - 2.0 * x[t, k] + x[t - 1, k]) * inv_h2
        out[0] = out[1]
        out[F - 1] = out[F - 2]
        return
    for t in range(2, F - 2):
        for k in range(K):
            out[t, k] = (
                _CENTRAL[0] * x[t - 2, k] + _CENTRAL[1] * x[t - 1, k] + _CENTRAL[2] * x[t, k]
                + _CENTRAL[3] * x[t + 1, k] + _CENTRAL[4] * x[t + 2, k]
            ) * inv_h2  # fmt: skip
    for k in range(K):
        a0 = 0.0
        a1 = 0.0
        b0 = 0.0
        b1 = 0.0
        for i in range(6):
            a0 += _FORWARD0[i] * x[i, k]
            a1 += _FORWARD1[i] * x[i, k]
            b0 += _FORWARD0[i] * x[F - 1 - i, k]  # mirrored: the same stencils backwards in time
            b1 += _FORWARD1[i] * x[F - 1 - i, k]
        out[0, k] = a0 * inv_h2
        out[1, k] = a1 * inv_h2
        out[F - 1, k] = b0 * inv_h2
        out[F - 2, k] = b1 * inv_h2


def second_derivative(x: np.ndarray, rate_hz: float) -> np.ndarray:
    """d²x/dt² along axis 0 of (F, ...) samples, exact for polynomials of degree ≤ 5
    when F ≥ 6; second order for 3 ≤ F < 6; zeros for F < 3."""
    flat = np.ascontiguousarray(x, dtype=np.float64).reshape(x.shape[0], -1)
    out = np.empty_like(flat)
    _second_derivative(flat, float(rate_hz), out)
    return out.reshape(x.shape)


@numba.njit(cache=True, nogil=True)
def _sensor_poses(world_rot, world_pos, segment, toward, along, offset, rotation, position, orientation):
    F, S = position.shape[0], position.shape[1]
    tmp = np.empty(3)
    for f in range(F):
        for s in range(S):
            seg, tow = segment[s], toward[s]
            qrot(world_rot[f, seg], offset[s], tmp)
            for k in range(3):
                base = world_pos[f, seg, k]
                position[f, s, k] = base + along[s] * (world_pos[f, tow, k] - base) + tmp[k]
            qmul(world_rot[f, seg], rotation[s], orientation[f, s])


@numba.njit(cache=True, nogil=True)
def _to_sensor_frames(orientation, world_acc, gravity, out):
    F, S = out.shape[0], out.shape[1]
    conj = np.empty(4)
    v = np.empty(3)
    r = np.empty(3)
    for f in range(F):
        for s in range(S):
            q = orientation[f, s]
            conj[0], conj[1], conj[2], conj[3] = q[0], -q[1], -q[2], -q[3]
            v[0] = world_acc[f, s, 0]
            v[1] = world_acc[f, s, 1] + gravity
            v[2] = world_acc[f, s, 2]
            qrot(conj, v, r)
            out[f, s, 0], out[f, s, 1], out[f, s, 2] = r[0], r[1], r[2]


def sensor_poses(world_rot: np.ndarray, world_pos: np.ndarray, placement: Placement):
    """World positions (F, S, 3) and orientations (F, S, 4) of the sensors."""
    F, S = world_rot.shape[0], len(placement.segment)
    position = np.empty((F, S, 3))
    orientation = np.empty((F, S, 4))
    _sensor_poses(
        np.ascontiguousarray(world_rot), np.ascontiguousarray(world_pos),
        placement.segment, placement.toward, placement.along,
        np.ascontiguousarray(placement.offset), np.ascontiguousarray(placement.rotation),
        position, orientation,
    )  # fmt: skip
    return position, orientation


def to_sensor_frames(orientation: np.ndarray, world_acc: np.ndarray) -> np.ndarray:
    """(F, S, 3) float32 readings: world accelerations (F, S, 3) m/s² plus gravity's
    reaction, in the sensor frames of orientations (F, S, 4)."""
    out = np.empty(world_acc.shape, dtype=np.float32)
    _to_sensor_frames(np.ascontiguousarray(orientation, dtype=np.float64),
                      np.ascontiguousarray(world_acc, dtype=np.float64), GRAVITY, out)  # fmt: skip
    return out


def simulate_accelerations(
    world_rot: np.ndarray, world_pos: np.ndarray, placement: Placement, rate_hz: float
) -> np.ndarray:
    """(F, S, 3) float32 readings in m/s², each in its sensor's frame."""
    position, orientation = sensor_poses(world_rot, world_pos, placement)
    world_acc = second_derivative(position, rate_hz)
    out = np.empty(position.shape, dtype=np.float32)
    _to_sensor_frames(orientation, world_acc, GRAVITY, out)
    return out
