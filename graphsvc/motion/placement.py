"""A pose relative to its own root placement, and placed again on another root path.

Synthesis and the graph's bridges both take a pose out of its source clip and
set it down somewhere else: the pelvis rotation is described relative to the frame's
heading and the pelvis by its height (`relative_pose`), the rest of the body by its
local rotations; `place_poses` realises a new ground position and heading at the
carrier joint (`joint_tables`), so every joint above and below it keeps its local
values. Numba kernels with the operations of `quat` in the same order (products and
rotations from `kinematics`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from graphsvc.motion.kinematics import diff3 as _diff3
from graphsvc.motion.kinematics import qmul4 as _qmul
from graphsvc.motion.kinematics import qrot3 as _qrot

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


def joint_tables(skeleton, joints: dict) -> tuple[np.ndarray, int]:
    """Joints under the pelvis (J,) bool, and the carrier joint: the pelvis or its
    nearest ancestor with position channels (joint 0 otherwise), where the placement
    is realised so every joint above and below keeps its local values."""
    parents = skeleton.parents
    pelvis = joints["pelvis"]
    below = np.zeros(parents.shape[0], dtype=bool)
    below[pelvis] = True
    for j in range(pelvis + 1, parents.shape[0]):  # topological order
        if parents[j] >= 0 and below[parents[j]]:
            below[j] = True
    below[pelvis] = False  # the pelvis itself is blended through its relative rotation
    chain = [pelvis]
    while parents[chain[-1]] >= 0:
        chain.append(int(parents[chain[-1]]))
    carrier = next((j for j in chain if any(c.endswith("position") for c in skeleton.channels[j])), 0)
    return below, carrier


@_jit
def relative_pose(world_rot, world_pos, heading, pelvis):
    """Pelvis world rotation with the node heading (K,) (rad) taken off (K, 4), and
    pelvis height (K,) (m), from source-clip FK (K, J, 4/3)."""
    K = world_rot.shape[0]
    rel = np.empty((K, 4))
    height = np.empty(K)
    for k in range(K):
        half = 0.5 * -heading[k]
        p = world_rot[k, pelvis]
        rel[k] = _qmul(math.cos(half), 0.0, math.sin(half), 0.0, p[0], p[1], p[2], p[3])
        height[k] = world_pos[k, pelvis, 1]
    return rel, height


@_jit
def place_poses(rot, trans, rel, height, ground, heading, src_rot, src_pos, parents, pelvis, carrier):
    """Re-place each frame, in place on rot (T, J, 4) and trans (T, J, 3): the pelvis
    world transform from the integrated ground (T, 2) (m) and heading (T,) (rad), the
    relative pelvis rotation (T, 4) and height (T,), realised at the carrier joint
    through the source pose (src_rot, src_pos (T, J, 4/3)) between it and the pelvis."""
    for t in range(rot.shape[0]):
        half = 0.5 * heading[t]
        r = rel[t]
        tw, tx, ty, tz = _qmul(math.cos(half), 0.0, math.sin(half), 0.0, r[0], r[1], r[2], r[3])
        ca, pe = src_rot[t, carrier], src_rot[t, pelvis]
        cw, cx, cy, cz = _qmul(ca[0], -ca[1], -ca[2], -ca[3], pe[0], pe[1], pe[2], pe[3])
        px, py, pz = _qrot(ca[0], -ca[1], -ca[2], -ca[3], *_diff3(src_pos[t, pelvis], src_pos[t, carrier]))
        qw, qx, qy, qz = _qmul(tw, tx, ty, tz, cw, -cx, -cy, -cz)
        vx, vy, vz = _qrot(qw, qx, qy, qz, px, py, pz)
        x, y, z = ground[t, 0] - vx, height[t] - vy, ground[t, 1] - vz
        if carrier > 0:
            p = parents[carrier]
            pr = src_rot[t, p]
            qw, qx, qy, qz = _qmul(pr[0], -pr[1], -pr[2], -pr[3], qw, qx, qy, qz)
            x, y, z = _qrot(pr[0], -pr[1], -pr[2], -pr[3], *_diff3((x, y, z), src_pos[t, p]))
        rot[t, carrier] = (qw, qx, qy, qz)
        trans[t, carrier] = (x, y, z)
