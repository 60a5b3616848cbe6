"""The calibration pose prepended to a clip: bone directions as the pose says, the
clip's facing, ground position and floor kept, the blend ending at the first frame and
the clip's frames unchanged after it."""

from __future__ import annotations

import numpy as np
import pytest

from graphsvc.errors import InputError
from graphsvc.motion.calibration_pose import calibration_frame, with_calibration_pose
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics, motion_fk
from graphsvc.motion.procedural import generate_knowledge_base


@pytest.fixture(scope="module")
def clip():
    clips = generate_knowledge_base(seed=3, minutes=0.5)
    return next(c for c in clips if c.labels and c.labels[0] == "run")


def _unit(v):
    return v / np.linalg.norm(v)


def _deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(_unit(a), _unit(b)), -1, 1))))


@pytest.mark.parametrize("pose", ["npose", "tpose"])
def test_bones_point_as_the_pose_says(clip, pose):
    table = joint_map(clip.skeleton)
    rot, trans = calibration_frame(clip, pose)
    pos = forward_kinematics(rot[None], trans[None], clip.skeleton.parents)[1][0]
    first = motion_fk(clip)[1][0]
    left = first[table["l_hip"]] - first[table["r_hip"]]
    left[1] = 0.0
    up, down = np.array([0.0, 1.0, 0.0]), np.array([0.0, -1.0, 0.0])
    for a, b in (("pelvis", "spine"), ("spine", "chest"), ("chest", "neck"), ("neck", "head")):
        assert _deg(pos[table[b]] - pos[table[a]], up) < 1e-4
    for side, out in (("l_", left), ("r_", -left)):
        assert _deg(pos[table[side + "knee"]] - pos[table[side + "hip"]], down) < 1e-4
        assert _deg(pos[table[side + "ankle"]] - pos[table[side + "knee"]], down) < 1e-4
        arm = out if pose == "tpose" else down
        assert _deg(pos[table[side + "elbow"]] - pos[table[side + "shoulder"]], arm) < 1e-4
        assert _deg(pos[table[side + "wrist"]] - pos[table[side + "elbow"]], arm) < 1e-4
        foot = pos[table[side + "toe"]] - pos[table[side + "ankle"]]
        assert abs(foot[1]) < 1e-9  # level
    # The lowest foot joint stands as high as the first frame's lowest.
    feet = [table[f] for f in ("l_ankle", "r_ankle", "l_toe", "r_toe")]
    assert pos[feet, 1].min() == pytest.approx(first[feet, 1].min(), abs=1e-9)
    # Ground position kept (the root only turns and rises).
    assert np.allclose(pos[table["pelvis"], [0, 2]], first[table["pelvis"], [0, 2]], atol=1e-9)


def test_prepended_pose_is_held_then_blends_into_the_clip(clip):
    out = with_calibration_pose(clip, "npose", 2.0)
    n = int(round(2.0 * clip.rate_hz))
    assert out.num_frames == clip.num_frames + n
    assert np.array_equal(out.rotations[n:], clip.rotations)
    assert np.array_equal(out.translations[n:], clip.translations)
    rot, trans = calibration_frame(clip, "npose")
    held = n - int(round(0.5 * clip.rate_hz))
    assert np.allclose(out.rotations[:held], rot[None])
    pos = motion_fk(out)[1]
    # The blend is smooth: no joint jumps more than the clip's own fastest step at the seam.
    steps = np.linalg.norm(np.diff(pos[held - 1 : n + 1], axis=0), axis=-1).max(axis=-1)
    assert steps.max() < 0.1  # m a frame; a jump to the first frame would be ~0.5 m for the arms
    assert np.linalg.norm(pos[n - 1] - pos[n], axis=-1).max() < 0.05


def test_bad_arguments(clip):
    with pytest.raises(InputError, match="calibration pose"):
        calibration_frame(clip, "squat")
    with pytest.raises(InputError, match="seconds"):
        with_calibration_pose(clip, "tpose", -1.0)
    with pytest.raises(InputError, match="less than a frame"):
        with_calibration_pose(clip, "tpose", 0.001)
