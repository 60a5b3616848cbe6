"""Per-frame global signals of a motion: ground-plane root position, heading and
foot-contact state . All functions take world joint positions (F, J, 3)
from forward kinematics and canonical joint indices from `joints.joint_map`."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class ContactThresholds:
    """Heights in metres above the clip's resting foot height, speeds in m/s.
    A foot enters contact below both *_on thresholds and leaves above either *_off
    threshold (hysteresis keeps flags from flickering at the boundary)."""

    height_on: float = 0.05
    height_off: float = 0.08
    speed_on: float = 0.35
    speed_off: float = 0.60


def ground_position(world_pos: np.ndarray, pelvis: int) -> np.ndarray:
    """(F, 2) pelvis position projected on the ground plane, (x, z) in metres."""
    return world_pos[:, pelvis][:, [0, 2]].copy()


def heading(world_pos: np.ndarray, joints: dict[str, int]) -> np.ndarray:
    """(F,) heading in radians about +Y, 0 facing +Z, positive turning toward +X.

    Facing is taken from the pose (hips and shoulders, right → left, crossed with up),
    not from a root axis, so it means the same for every skeleton family whatever
    its local axis conventions."""
    across = (
        world_pos[:, joints["l_hip"]]
        - world_pos[:, joints["r_hip"]]
        + world_pos[:, joints["l_shoulder"]]
        - world_pos[:, joints["r_shoulder"]]
    )
    # forward = across × up, with up = +Y: (ax, ay, az) × (0, 1, 0) = (-az, 0, ax)
    return np.arctan2(-across[:, 2], across[:, 0])


def speeds(positions: np.ndarray, rate_hz: float) -> np.ndarray:
    """(F, ...) speed in m/s of (F, ..., 3) trajectories, every frame's over two frame
    steps: central differences, and at the first and last frame, which have a
    neighbour on one side only, the two steps next to them (their neighbour's speed).
    A one-step difference there (np.gradient's) is twice as noisy as the central ones:
    a reconstruction's planted feet, slid a centimetre a frame back and forth by the
    track's pull, read as moving at frame 0 alone. Two frames: their one step; one: 0."""
    positions = np.asarray(positions, dtype=np.float64)
    F = positions.shape[0]
    if F < 2:
        return np.zeros(positions.shape[:-1])
    if F == 2:
        step = np.linalg.norm(positions[1] - positions[0], axis=-1) * rate_hz
        return np.stack([step, step])
    out = np.empty(positions.shape[:-1])
    out[1:-1] = np.linalg.norm(positions[2:] - positions[:-2], axis=-1) * (0.5 * rate_hz)
    out[0], out[-1] = out[1], out[-2]
    return out


@numba.njit(cache=True, nogil=True)
def _hysteresis(height, speed, h_on, h_off, v_on, v_off):
    F = height.shape[0]
    out = np.zeros(F, dtype=np.bool_)
    state = height[0] < h_on and speed[0] < v_on
    for t in range(F):
        if state:
            if height[t] > h_off or speed[t] > v_off:
                state = False
        else:
            if height[t] < h_on and speed[t] < v_on:
                state = True
        out[t] = state
    return out


def foot_contacts(
    world_pos: np.ndarray,
    joints: dict[str, int],
    rate_hz: float,
    thresholds: ContactThresholds = ContactThresholds(),
) -> np.ndarray:
    """(F, 2) bool contact flags, column 0 the left foot, column 1 the right.

    A foot is planted when its ankle or its toe is near its resting height and
    nearly still. Resting heights are the 5th percentile over the clip of each
    joint over both feet, so floors not at y = 0 and different ankle heights across
    skeletons need no tuning."""
    out = np.zeros((world_pos.shape[0], 2), dtype=bool)
    ankles = world_pos[:, [joints["l_ankle"], joints["r_ankle"]]]
    toes = world_pos[:, [joints["l_toe"], joints["r_toe"]]]
    ankle_rest = np.percentile(ankles[..., 1], 5.0)
    toe_rest = np.percentile(toes[..., 1], 5.0)
    ankle_speed = speeds(ankles, rate_hz)
    toe_speed = speeds(toes, rate_hz)
    for side in range(2):
        # Per frame, the better-planted of heel (ankle) and toe decides.
        height = np.minimum(ankles[:, side, 1] - ankle_rest, toes[:, side, 1] - toe_rest)
        speed = np.where(
            ankles[:, side, 1] - ankle_rest < toes[:, side, 1] - toe_rest,
            ankle_speed[:, side],
            toe_speed[:, side],
        )
        out[:, side] = _hysteresis(
            np.ascontiguousarray(height),
            np.ascontiguousarray(speed),
            thresholds.height_on,
            thresholds.height_off,
            thresholds.speed_on,
            thresholds.speed_off,
        )
    return out


def contact_changes(contacts: np.ndarray) -> np.ndarray:
    """(F,) bool: frame t's contact state differs from frame t−1's (frame 0: False)."""
    out = np.zeros(contacts.shape[0], dtype=bool)
    out[1:] = np.any(contacts[1:] != contacts[:-1], axis=-1)
    return out
