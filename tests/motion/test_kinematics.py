import numpy as np

from graphsvc.motion import quat
from graphsvc.motion.kinematics import forward_kinematics, motion_fk
from tests.conftest import still_motion


def test_rest_pose_positions_are_summed_offsets(skeleton):
    motion = still_motion(2)
    _, pos = motion_fk(motion)
    assert np.allclose(pos[0, skeleton.index("l_wrist")], [0.18 + 0.28 + 0.25, 0.96 + 0.1 + 0.2 + 0.2, 0.0])
    assert np.allclose(pos[0, skeleton.index("r_toe")], [-0.10, 0.96 - 0.05 - 0.84 - 0.07, 0.13])


def test_elbow_bend_moves_wrist_around_elbow(skeleton):
    motion = still_motion(1)
    e = skeleton.index("l_elbow")
    motion.rotations[0, e] = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(np.pi / 2))
    _, pos = motion_fk(motion)
    # The forearm (0.25 m along +X) turns to +Y about the elbow.
    np.testing.assert_allclose(pos[0, skeleton.index("l_wrist")] - pos[0, e], [0.0, 0.25, 0.0], atol=1e-12)


def test_bone_lengths_preserved_under_random_rotations(skeleton):
    rng = np.random.default_rng(4)
    F, J = 50, skeleton.num_joints
    rot = quat.normalize(rng.standard_normal((F, J, 4)))
    trans = np.broadcast_to(skeleton.offsets, (F, J, 3)).copy()
    trans[:, 0] = rng.standard_normal((F, 3))
    world_rot, pos = forward_kinematics(rot, trans, skeleton.parents)
    lengths = np.linalg.norm(pos[:, 1:] - pos[:, skeleton.parents[1:]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(skeleton.bone_lengths()[1:], lengths.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(world_rot, axis=-1), 1.0, atol=1e-12)
