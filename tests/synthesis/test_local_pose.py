"""Local poses as vectors (`synthesis.local_pose`): a motion's own poses put back change
nothing, and a pose put in keeps the frame's ground position and heading."""

from __future__ import annotations

import numpy as np

from graphsvc.motion import quat, signals
from graphsvc.motion.joints import joint_map
from graphsvc.motion.kinematics import forward_kinematics
from graphsvc.synthesis.local_pose import place_local_poses, pose_layout, pose_vectors
from tests.conftest import tpose_skeleton


def _moving(T: int = 12):
    """The T-pose walking along a curve, turning, its joints bending."""
    sk = tpose_skeleton()
    J = len(sk.names)
    rng = np.random.default_rng(4)
    t = np.arange(T) / 30.0
    rot = quat.normalize(np.tile([1.0, 0.0, 0.0, 0.0], (T, J, 1)) + rng.normal(0, 0.15, (T, J, 4)))
    rot[:, 0] = quat.about_y(0.9 * t + 0.4)
    trans = np.tile(np.asarray(sk.offsets, dtype=np.float64), (T, 1, 1))
    trans[:, 0] += np.stack([np.sin(t), 0.02 * np.cos(9 * t), 1.3 * t], axis=-1)
    return sk, rot, trans


def test_a_motions_own_local_poses_put_back_give_the_same_joints():
    sk, rot, trans = _moving()
    layout = pose_layout(sk)
    p = pose_vectors(rot, trans, sk.parents, layout)
    assert p.shape == (rot.shape[0], layout.dims) and np.all(p[:, 0] >= 0) and np.all(p[:, 5] >= 0)
    r, t = place_local_poses(rot, trans, sk.parents, layout, p, np.ones(rot.shape[0], dtype=bool))
    np.testing.assert_allclose(
        forward_kinematics(r, t, sk.parents)[1], forward_kinematics(rot, trans, sk.parents)[1], atol=1e-9
    )


def test_another_pose_put_in_keeps_the_frames_place_and_heading_and_only_where_asked():
    sk, rot, trans = _moving()
    layout = pose_layout(sk)
    table = joint_map(sk)
    other = pose_vectors(rot[::-1].copy(), trans[::-1].copy(), sk.parents, layout)  # (the poses in reverse order)
    use = np.arange(rot.shape[0]) % 2 == 0
    r, t = place_local_poses(rot, trans, sk.parents, layout, other, use)
    before, after = forward_kinematics(rot, trans, sk.parents)[1], forward_kinematics(r, t, sk.parents)[1]
    np.testing.assert_allclose(
        signals.ground_position(after, table["pelvis"]), signals.ground_position(before, table["pelvis"]), atol=1e-9
    )
    np.testing.assert_allclose(signals.heading(after[use], table), signals.heading(before[use], table), atol=1e-9)
    np.testing.assert_array_equal(r[~use], rot[~use])
    # the frames asked for hold the other poses: the same vectors read back
    np.testing.assert_allclose(pose_vectors(r, t, sk.parents, layout)[use], other[use], atol=1e-9)
