"""Quaternion helpers on flat arrays. Quaternions are (..., 4) arrays in (w, x, y, z)
order, unit length, Hamilton product; `mul(a, b)` applies b first, then a.

Euler conversions go through scipy's Rotation (C speed, every axis order)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def identity(shape=()) -> np.ndarray:
    out = np.zeros(tuple(shape) + (4,))
    out[..., 0] = 1.0
    return out


def normalize(q: np.ndarray) -> np.ndarray:
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def conjugate(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


inverse = conjugate  # for unit quaternions


def mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by quaternions q (..., 4)."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def inv_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v by the inverse of q (world → local)."""
    return rotate(conjugate(q), v)


def from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    half = 0.5 * angle[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def about_y(angle: np.ndarray) -> np.ndarray:
    """Rotation by `angle` radians about +Y (a heading), shape angle.shape + (4,)."""
    angle = np.asarray(angle, dtype=float)
    out = np.zeros(angle.shape + (4,))
    out[..., 0] = np.cos(0.5 * angle)
    out[..., 2] = np.sin(0.5 * angle)
    return out


def to_scipy(q: np.ndarray) -> Rotation:
    flat = np.asarray(q, dtype=float).reshape(-1, 4)
    return Rotation.from_quat(flat[:, [1, 2, 3, 0]])


def from_scipy(r: Rotation, shape=()) -> np.ndarray:
    xyzw = r.as_quat().reshape(tuple(shape) + (4,))
    return xyzw[..., [3, 0, 1, 2]]


def from_euler(angles: np.ndarray, order: str, degrees: bool = False) -> np.ndarray:
    """Intrinsic rotations applied in `order` (e.g. "ZXY": R = Rz·Rx·Ry, the BVH
    convention). angles: (..., len(order)). Returns (..., 4)."""
    angles = np.asarray(angles, dtype=float)
    shape = angles.shape[:-1]
    if len(order) == 0:
        return identity(shape)
    r = Rotation.from_euler(order.upper(), angles.reshape(-1, len(order)), degrees=degrees)
    return from_scipy(r, shape)


def to_euler(q: np.ndarray, order: str, degrees: bool = False) -> np.ndarray:
    """Inverse of from_euler for three distinct axes; for one or two axes the
    rotation is assumed to have no component about the missing axes."""
    q = np.asarray(q, dtype=float)
    shape = q.shape[:-1]
    order = order.upper()
    if len(order) == 0:
        return np.zeros(shape + (0,))
    if len(order) == 3 and len(set(order)) == 3:
        r = to_scipy(q)
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # gimbal-lock warning: result still valid
                return r.as_euler(order, degrees=degrees).reshape(shape + (3,))
    # Fewer axes: complete to a proper three-axis order and keep the named angles.
    full = order + "".join(a for a in "XYZ" if a not in order)
    full = full[:3] if len(set(full[:3])) == 3 else full
    angles = to_euler(q, full[:3], degrees=degrees)
    return angles[..., : len(order)]


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation, shortest arc; t broadcasts against a[..., 0]."""
    t = np.asarray(t, dtype=float)[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0.0, -b, b)
    dot = np.abs(dot)
    close = dot > 1.0 - 1e-12  # angle below ~1.4e-6 rad: lerp is exact to float precision
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    safe = np.where(close, 1.0, sin_theta)
    wa = np.where(close, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    wb = np.where(close, t, np.sin(t * theta) / safe)
    return normalize(wa * a + wb * b)


def to_matrix(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def from_matrix(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, dtype=float)
    shape = m.shape[:-2]
    return from_scipy(Rotation.from_matrix(m.reshape(-1, 3, 3)), shape)


def between(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest rotation taking direction u onto direction v (both (..., 3))."""
    u = u / np.linalg.norm(u, axis=-1, keepdims=True)
    v = v / np.linalg.norm(v, axis=-1, keepdims=True)
    w = 1.0 + np.sum(u * v, axis=-1, keepdims=True)
    axis = np.cross(u, v)
    # Opposite directions: any axis orthogonal to u.
    opposite = w[..., 0] < 1e-9
    if np.any(opposite):
        alt = np.cross(u, np.array([1.0, 0.0, 0.0]))
        alt2 = np.cross(u, np.array([0.0, 1.0, 0.0]))
        alt = np.where(np.linalg.norm(alt, axis=-1, keepdims=True) < 1e-6, alt2, alt)
        axis = np.where(opposite[..., None], alt, axis)
        w = np.where(opposite[..., None], 0.0, w)
    return normalize(np.concatenate([w, axis], axis=-1))


def heading_angle(q: np.ndarray, forward=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Heading in radians about +Y of the direction `forward` rotated by q, measured
    from +Z toward +X (atan2(x, z)); shape q.shape[:-1]."""
    f = rotate(q, np.broadcast_to(np.asarray(forward, dtype=float), q.shape[:-1] + (3,)))
    return np.arctan2(f[..., 0], f[..., 2])


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Wrap radians to [-π, π)."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi
