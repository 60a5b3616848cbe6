"""A calibration pose before a clip: how a wearer of real sensors starts a take.

Devices are calibrated from a pose held at the start of the stream (an N-pose: standing,
arms down; a T-pose: arms out to the sides; `stand`: standing as the N-pose). A test clip
of the knowledge base does not start that way, so the simulated setting prepends one
(`with_calibration_pose`): the pose is held, then blended into the clip's first frame,
and the evaluation calibrates from it and scores only the clip.

The pose is made on the clip's own skeleton from its first frame (`calibration_frame`):
each canonical bone is turned, parents first, by the shortest rotation onto the pose's
direction in the world (trunk and neck up, legs down, upper and lower arms down or out
to the sides, feet forward and level), the performer keeps the first frame's facing and
ground position, and the figure is lifted or lowered so that its lowest foot joint
stands as high as in the first frame. Everything a canonical bone does not cover (hands,
fingers, clavicles) keeps the first frame's local rotation.
"""

from __future__ import annotations

import numpy as np

from graphsvc.errors import InputError
from graphsvc.motion import quat
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.motion.skeleton import Motion

POSES = ("npose", "tpose", "stand")
HOLD_BLEND_S = 0.5  # of the prepended seconds, the last this many blend into the clip

# (joint, the canonical joint its bone points at) in the order they are turned.
_BONES = (
    ("pelvis", "spine"),
    ("spine", "chest"),
    ("chest", "neck"),
    ("neck", "head"),
    ("l_hip", "l_knee"),
    ("l_knee", "l_ankle"),
    ("l_ankle", "l_toe"),
    ("r_hip", "r_knee"),
    ("r_knee", "r_ankle"),
    ("r_ankle", "r_toe"),
    ("l_shoulder", "l_elbow"),
    ("l_elbow", "l_wrist"),
    ("r_shoulder", "r_elbow"),
    ("r_elbow", "r_wrist"),
)


def _targets(pose: str, left: np.ndarray) -> dict[str, np.ndarray]:
    """Each bone's world direction in `pose` for a performer whose left is `left` (a
    horizontal unit vector; Y is up)."""
    up, forward = np.array([0.0, 1.0, 0.0]), np.cross(left, np.array([0.0, 1.0, 0.0]))
    out = {j: up for j in ("pelvis", "spine", "chest", "neck")}
    for side in ("l_", "r_"):
        out.update({side + "hip": -up, side + "knee": -up, side + "ankle": forward})
        arm = (left if side == "l_" else -left) if pose == "tpose" else -up
        out.update({side + "shoulder": arm, side + "elbow": arm})
    return out


def calibration_frame(motion: Motion, pose: str, mapping=None) -> tuple[np.ndarray, np.ndarray]:
    """(J, 4) local rotations and (J, 3) local translations of `motion`'s skeleton in
    `pose` (module docstring), made from its first frame. InputError for an unknown pose
    or a skeleton without the canonical joints the pose turns."""
    if pose not in POSES:
        raise InputError(f"unknown calibration pose {pose!r} (one of {', '.join(POSES)})")
    table = joint_map(motion.skeleton, mapping)
    missing = sorted({a for bone in _BONES for a in bone} - set(table))
    if missing:
        raise InputError(f"{motion.name or 'the clip'}: its skeleton lacks {', '.join(missing)} for a calibration pose")
    parents = motion.skeleton.parents
    rot = motion.rotations[0].copy()
    trans = motion.translations[0].copy()
    world_rot, world_pos = forward_kinematics(rot[None], trans[None], parents)
    floor = min(world_pos[0, table[f], 1] for f in ("l_ankle", "r_ankle", "l_toe", "r_toe"))
    side = world_pos[0, table["l_hip"]] - world_pos[0, table["r_hip"]]
    side[1] = 0.0
    if np.linalg.norm(side) < 1e-9:
        raise InputError(f"{motion.name or 'the clip'}: its hips coincide in the first frame; no facing to pose from")
    targets = _targets(pose, side / np.linalg.norm(side))
    for joint, child in _BONES:
        j, c = table[joint], table[child]
        world_rot, world_pos = forward_kinematics(rot[None], trans[None], parents)
        turn = quat.between(world_pos[0, c] - world_pos[0, j], targets[joint])
        new_world = quat.mul(turn, world_rot[0, j])
        p = parents[j]
        rot[j] = new_world if p < 0 else quat.mul(quat.conjugate(world_rot[0, p]), new_world)
    world_rot, world_pos = forward_kinematics(rot[None], trans[None], parents)
    lowest = min(world_pos[0, table[f], 1] for f in ("l_ankle", "r_ankle", "l_toe", "r_toe"))
    trans[0, 1] += floor - lowest
    return quat.normalize(rot), trans


def with_calibration_pose(motion: Motion, pose: str, seconds: float, mapping=None) -> Motion:
    """`motion` with `seconds` of `pose` before it: held, then over the last
    min(HOLD_BLEND_S, seconds / 2) blended (smoothstep; local rotations slerped, local
    translations interpolated) into the first frame. The clip's own frames follow
    unchanged; the result has round(seconds × rate) more frames."""
    if not (np.isfinite(seconds) and seconds > 0):
        raise InputError(f"a calibration pose lasts a finite number of seconds > 0, got {seconds}")
    n = int(round(seconds * motion.rate_hz))
    if n < 1:
        raise InputError(f"{seconds} s of calibration pose is less than a frame at {motion.rate_hz:g} Hz")
    rot, trans = calibration_frame(motion, pose, mapping)
    blend = max(1, min(int(round(HOLD_BLEND_S * motion.rate_hz)), n // 2))
    # Weight of the clip's first frame over the prepended frames: 0 while held, then a
    # smoothstep reaching 1 at the clip's first frame (not included).
    s = np.clip((np.arange(n) - (n - blend)) / blend, 0.0, 1.0)
    w = s * s * (3.0 - 2.0 * s)
    J = rot.shape[0]
    pre_rot = quat.slerp(
        np.broadcast_to(rot, (n, J, 4)),
        np.broadcast_to(motion.rotations[0], (n, J, 4)),
        np.broadcast_to(w[:, None], (n, J)),
    )
    pre_trans = (1.0 - w)[:, None, None] * trans + w[:, None, None] * motion.translations[0]
    return Motion(
        motion.skeleton,
        np.concatenate([pre_rot, motion.rotations]),
        np.concatenate([pre_trans, motion.translations]),
        motion.rate_hz,
        name=motion.name,
        source=motion.source,
        labels=motion.labels,
    )
