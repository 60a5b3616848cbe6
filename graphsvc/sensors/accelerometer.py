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
                _CENTRAL[0] * x[t - 2, k]
                + _CENTRAL[1] * x[t - 1, k]
                + _CENTRAL[2] * x[t, k]
                + _CENTRAL[3] * x[t + 1, k]
                + _CENTRAL[4] * x[t + 2, k]
            ) * inv_h2
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
def _frame_quat(x, y, out):
    """The rotation (w, x, y, z) whose matrix has columns x, y ⊥ x (unit) and x × y."""
    z0 = x[1] * y[2] - x[2] * y[1]
    z1 = x[2] * y[0] - x[0] * y[2]
    z2 = x[0] * y[1] - x[1] * y[0]
    m00, m01, m02 = x[0], y[0], z0
    m10, m11, m12 = x[1], y[1], z1
    m20, m21, m22 = x[2], y[2], z2
    tr = m00 + m11 + m22
    if tr > 0.0:
        s = np.sqrt(tr + 1.0) * 2.0
        out[0], out[1], out[2], out[3] = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif m00 > m11 and m00 > m22:
        s = np.sqrt(1.0 + m00 - m11 - m22) * 2.0
        out[0], out[1], out[2], out[3] = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif m11 > m22:
        s = np.sqrt(1.0 + m11 - m00 - m22) * 2.0
        out[0], out[1], out[2], out[3] = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        s = np.sqrt(1.0 + m22 - m00 - m11) * 2.0
        out[0], out[1], out[2], out[3] = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    if out[0] < 0.0:
        for k in range(4):
            out[k] = -out[k]


@numba.njit(cache=True, nogil=True)
def carried_frame(seg_rot, rotation, carrier_rot, axis, out):
    """A carried sensor's orientation (`layout.Placement`): X = seg_rot ⊗ rotation's X,
    Y = carrier_rot's view of `axis` made orthogonal to X, Z = X × Y."""
    ex = np.empty(3)
    ex[0] = 1.0 - 2.0 * (rotation[2] * rotation[2] + rotation[3] * rotation[3])
    ex[1] = 2.0 * (rotation[1] * rotation[2] + rotation[0] * rotation[3])
    ex[2] = 2.0 * (rotation[1] * rotation[3] - rotation[0] * rotation[2])
    x = np.empty(3)
    y = np.empty(3)
    qrot(seg_rot, ex, x)
    qrot(carrier_rot, axis, y)
    d = x[0] * y[0] + x[1] * y[1] + x[2] * y[2]
    n = 0.0
    for k in range(3):
        y[k] -= d * x[k]
        n += y[k] * y[k]
    if n < 1e-18:  # (the carried axis along the bone: never for a hinge; keep the rigid frame)
        qmul(seg_rot, rotation, out)
        return
    n = np.sqrt(n)
    for k in range(3):
        y[k] /= n
    _frame_quat(x, y, out)


@numba.njit(cache=True, nogil=True)
def _sensor_poses(world_rot, world_pos, segment, toward, along, offset, rotation, carrier, axis, position, orientation):
    F, S = position.shape[0], position.shape[1]
    tmp = np.empty(3)
    for f in range(F):
        for s in range(S):
            seg, tow = segment[s], toward[s]
            qrot(world_rot[f, seg], offset[s], tmp)
            for k in range(3):
                base = world_pos[f, seg, k]
                position[f, s, k] = base + along[s] * (world_pos[f, tow, k] - base) + tmp[k]
            if carrier[s] < 0:
                qmul(world_rot[f, seg], rotation[s], orientation[f, s])
            else:
                carried_frame(world_rot[f, seg], rotation[s], world_rot[f, carrier[s]], axis[s], orientation[f, s])


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
        np.ascontiguousarray(world_rot),
        np.ascontiguousarray(world_pos),
        placement.segment,
        placement.toward,
        placement.along,
        np.ascontiguousarray(placement.offset),
        np.ascontiguousarray(placement.rotation),
        np.ascontiguousarray(placement.carrier),
        np.ascontiguousarray(placement.axis, dtype=np.float64),
        position,
        orientation,
    )
    return position, orientation


def to_sensor_frames(orientation: np.ndarray, world_acc: np.ndarray) -> np.ndarray:
    """(F, S, 3) float32 readings: world accelerations (F, S, 3) m/s² plus gravity's
    reaction, in the sensor frames of orientations (F, S, 4)."""
    out = np.empty(world_acc.shape, dtype=np.float32)
    _to_sensor_frames(
        np.ascontiguousarray(orientation, dtype=np.float64),
        np.ascontiguousarray(world_acc, dtype=np.float64),
        GRAVITY,
        out,
    )
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
