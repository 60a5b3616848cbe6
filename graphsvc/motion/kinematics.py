"""Forward kinematics for all frames at once, in numba.

Clips in a knowledge base are short (a few hundred frames), so a per-joint numpy
loop would spend most of its time in call overhead; one compiled pass over frames
and joints does not.
"""

from __future__ import annotations

import numba
import numpy as np

from graphsvc.motion.skeleton import Motion


@numba.njit(cache=True)
def qmul4(aw, ax, ay, az, bw, bx, by, bz):
    """a ⊗ b on (w, x, y, z) components, as four floats (the formula of `quat.mul`)."""
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@numba.njit(cache=True)
def qrot3(w, x, y, z, vx, vy, vz):
    """v rotated by the unit quaternion (w, x, y, z), as three floats: v + w·t + u × t,
    t = 2·u × v (the formula of `quat.rotate`)."""
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx)


@numba.njit(cache=True)
def diff3(a, b):
    """a − b for length-3 arrays, as three floats."""
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


@numba.njit(cache=True, inline="always")
def qmul(a, b, out):
    """out = a ⊗ b for length-4 (w, x, y, z) arrays; out may not alias a or b."""
    out[0], out[1], out[2], out[3] = qmul4(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])


@numba.njit(cache=True, inline="always")
def qrot(q, v, out):
    """out = q · v · q* for a length-4 quaternion and a length-3 vector."""
    out[0], out[1], out[2] = qrot3(q[0], q[1], q[2], q[3], v[0], v[1], v[2])


@numba.njit(cache=True, nogil=True)
def _fk(rotations, translations, parents, world_rot, world_pos):
    F, J = rotations.shape[0], rotations.shape[1]
    tmp = np.empty(3)
    for f in range(F):
        world_rot[f, 0] = rotations[f, 0]
        world_pos[f, 0] = translations[f, 0]
        for j in range(1, J):
            p = parents[j]
            qrot(world_rot[f, p], translations[f, j], tmp)
            world_pos[f, j, 0] = world_pos[f, p, 0] + tmp[0]
            world_pos[f, j, 1] = world_pos[f, p, 1] + tmp[1]
            world_pos[f, j, 2] = world_pos[f, p, 2] + tmp[2]
            qmul(world_rot[f, p], rotations[f, j], world_rot[f, j])


def forward_kinematics(
    rotations: np.ndarray, translations: np.ndarray, parents: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Local (F, J, 4) rotations and (F, J, 3) translations → world rotations
    (F, J, 4) and world positions (F, J, 3) in metres."""
    F, J = rotations.shape[:2]
    world_rot = np.empty((F, J, 4))
    world_pos = np.empty((F, J, 3))
    _fk(
        np.ascontiguousarray(rotations, dtype=np.float64),
        np.ascontiguousarray(translations, dtype=np.float64),
        np.ascontiguousarray(parents, dtype=np.int64),
        world_rot,
        world_pos,
    )
    return world_rot, world_pos


def motion_fk(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (F, J, 4) and positions (F, J, 3) of a Motion."""
    return forward_kinematics(motion.rotations, motion.translations, motion.skeleton.parents)
