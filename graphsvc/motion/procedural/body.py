"""The procedural character: its skeleton and proportions, the small maths the
planner and renderer share, and analytic two-bone IK."""

from __future__ import annotations

import numba
import numpy as np

from graphsvc.motion import quat
from graphsvc.motion.skeleton import Skeleton

ROOT_CHANNELS = (
    "Xposition",
    "Yposition",
    "Zposition",
    "Zrotation",
    "Xrotation",
    "Yrotation",
)
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")

CONTENT_LABELS = (
    "walk",
    "run",
    "stop",
    "idle",
    "forehand",
    "backhand",
    "overhead",
    "punch",
)

# Adult of ~1.75 m (head_End at 1.73 m), T-pose, faces +Z, left is +X.
_BONES = (  # name, parent, offset (m)
    ("pelvis", None, (0.0, 0.99, 0.0)),
    ("spine", "pelvis", (0.0, 0.10, 0.0)),
    ("chest", "spine", (0.0, 0.14, 0.0)),
    ("neck", "chest", (0.0, 0.22, 0.0)),
    ("head", "neck", (0.0, 0.10, 0.0)),
    ("head_End", "head", (0.0, 0.18, 0.0)),
    ("l_shoulder", "chest", (0.17, 0.19, 0.0)),
    ("l_elbow", "l_shoulder", (0.29, 0.0, 0.0)),
    ("l_wrist", "l_elbow", (0.26, 0.0, 0.0)),
    ("l_wrist_End", "l_wrist", (0.18, 0.0, 0.0)),
    ("r_shoulder", "chest", (-0.17, 0.19, 0.0)),
    ("r_elbow", "r_shoulder", (-0.29, 0.0, 0.0)),
    ("r_wrist", "r_elbow", (-0.26, 0.0, 0.0)),
    ("r_wrist_End", "r_wrist", (-0.18, 0.0, 0.0)),
    ("l_hip", "pelvis", (0.09, -0.07, 0.0)),
    ("l_knee", "l_hip", (0.0, -0.42, 0.0)),
    ("l_ankle", "l_knee", (0.0, -0.42, 0.0)),
    ("l_toe", "l_ankle", (0.0, -0.06, 0.13)),
    ("l_toe_End", "l_toe", (0.0, 0.0, 0.05)),
    ("r_hip", "pelvis", (-0.09, -0.07, 0.0)),
    ("r_knee", "r_hip", (0.0, -0.42, 0.0)),
    ("r_ankle", "r_knee", (0.0, -0.42, 0.0)),
    ("r_toe", "r_ankle", (0.0, -0.06, 0.13)),
    ("r_toe_End", "r_toe", (0.0, 0.0, 0.05)),
)
_IDX = {name: i for i, (name, _, _) in enumerate(_BONES)}
_OFF = {name: np.array(off) for name, _, off in _BONES}

THIGH = 0.42
SHIN = 0.42
UPPER_ARM = 0.29
FOREARM = 0.26
ANKLE_H = 0.08  # ankle height above ground with the foot flat (m)
TOE_H = 0.02  # toe (ball) height with the foot flat (m)
TOE_FROM_ANKLE = _OFF["l_toe"]  # (3,) foot frame
PELVIS_H = 0.99  # rest pelvis height (m)
STAND_H = PELVIS_H - 0.01  # knees a touch soft when standing (hip–ankle at 98.8 % of the leg)
STAND_W = 0.10  # lateral half-distance between standing feet (m)
G = 9.81


def standard_skeleton() -> Skeleton:
    """The procedural skeleton: 19 canonical joints plus 5 end sites (head, hand
    tips, toe tips). Root channels: position + ZXY rotation; others ZXY rotation."""
    names = tuple(n for n, _, _ in _BONES)
    parents = np.array([-1 if p is None else _IDX[p] for _, p, _ in _BONES])
    end = np.array([n.endswith("_End") for n in names])
    channels = tuple(ROOT_CHANNELS if p is None else () if n.endswith("_End") else JOINT_CHANNELS for n, p, _ in _BONES)
    offsets = np.array([off for _, _, off in _BONES], dtype=float)
    return Skeleton(names, parents, offsets, channels, end)


# --------------------------------------------------------------------------- maths


def _fwd(heading: float) -> np.ndarray:
    """Ground-plane (x, z) forward direction at `heading`."""
    return np.array([np.sin(heading), np.cos(heading)])


def _left(heading: float) -> np.ndarray:
    """Ground-plane (x, z) left direction at `heading` (+X at heading 0)."""
    return np.array([np.cos(heading), -np.sin(heading)])


def _min_jerk(tau: np.ndarray) -> np.ndarray:
    """0 → 1 with zero velocity and acceleration at both ends (C2)."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)


def _bump(tau: np.ndarray) -> np.ndarray:
    """0 → 1 → 0 over [0, 1], peak at 0.5, C2 at the ends."""
    tau = np.clip(tau, 0.0, 1.0)
    return 64.0 * tau**3 * (1.0 - tau) ** 3


def _rot_x(angle: np.ndarray) -> np.ndarray:
    return quat.from_axis_angle(np.array([1.0, 0.0, 0.0]), np.asarray(angle, dtype=float))


def _rot_z(angle: np.ndarray) -> np.ndarray:
    return quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.asarray(angle, dtype=float))


def _frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrix with columns a, b, a × b (a ⟂ b, unit)."""
    return np.stack([a, b, np.cross(a, b)], axis=-1)


@numba.njit(cache=True)
def _bend_directions(u, pole):
    """Unit directions (F, 3) ⟂ u toward which the middle joint bends: the pole's
    component across the limb where the pole is well across it, otherwise (pole
    nearly along the limb) the previous frame's direction carried over, blended
    smoothly, so the elbow never flips when a pole and a limb line up."""
    F = u.shape[0]
    out = np.empty((F, 3))
    prev = np.zeros(3)
    for t in range(F):
        pn = pole[t] / max(np.sqrt(np.sum(pole[t] ** 2)), 1e-12)
        b = pn - np.sum(pn * u[t]) * u[t]
        n = np.sqrt(np.sum(b * b))
        w = min(1.0, max(0.0, (n - 0.15) / 0.45))
        w = w * w * (3.0 - 2.0 * w)
        if t == 0 or w >= 1.0:
            c = b
        else:
            q = prev - np.sum(prev * u[t]) * u[t]
            c = w * b / max(n, 1e-12) + (1.0 - w) * q
        cn = np.sqrt(np.sum(c * c))
        if cn < 1e-9:  # fully degenerate: any perpendicular
            c = np.array([u[t, 1], -u[t, 0], 0.0]) if abs(u[t, 2]) < 0.9 else np.array([0.0, u[t, 2], -u[t, 1]])
            cn = np.sqrt(np.sum(c * c))
        out[t] = c / cn
        prev = out[t]
    return out


def two_bone_ik(root, target, pole, parent_rot, l1, l2, rest_dir, rest_pole, soft=False):
    """Analytic two-bone IK over frames.

    root, target, pole: (F, 3) world positions of the first joint, the end effector
    target and a direction the middle joint should bend toward. parent_rot: (F, 4)
    world rotation of the first joint's parent. l1, l2: bone lengths (m). rest_dir:
    (3,) direction of both bones in the rest pose; rest_pole: (3,) direction in
    which the middle joint moves when the limb bends in the rest frame.
    Returns local rotations (F, 4) of the first and middle joints and the first
    joint's world rotation (F, 4). Out-of-reach targets are clamped to 99.95 % of
    full extension, so the caller must keep targets reachable; with soft=True,
    distances beyond 85 % of full extension saturate smoothly below 98 % instead (near
    full extension the middle joint's position changes infinitely fast with the
    distance, which would spike its acceleration)."""
    vec = target - root
    dist = np.linalg.norm(vec, axis=-1, keepdims=True)
    u = vec / np.maximum(dist, 1e-9)
    if soft:
        r0, r1 = 0.85 * (l1 + l2), 0.98 * (l1 + l2)
        dist = np.where(dist > r0, r0 + (r1 - r0) * np.tanh((dist - r0) / (r1 - r0)), dist)
    d = np.clip(dist, abs(l1 - l2) + 1e-3, (l1 + l2) * 0.9995)
    cos_a = np.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a * cos_a)
    b = _bend_directions(
        np.ascontiguousarray(u.reshape(-1, 3)),
        np.ascontiguousarray(pole.reshape(-1, 3)),
    )
    dir1 = cos_a * u + sin_a * b
    perp1 = -sin_a * u + cos_a * b
    mid = root + l1 * dir1
    dir2 = (root + d * u) - mid
    dir2 /= np.linalg.norm(dir2, axis=-1, keepdims=True)
    rest = _frame(np.asarray(rest_dir, float), np.asarray(rest_pole, float))
    world1 = quat.from_matrix(_frame(dir1, perp1) @ rest.T)
    local1 = quat.mul(quat.conjugate(parent_rot), world1)
    local2 = quat.between(
        np.broadcast_to(np.asarray(rest_dir, float), dir2.shape),
        quat.inv_rotate(world1, dir2),
    )
    return local1, local2, world1
