"""The pose-oracle floor: the frame-wise closest usable graph pose, by the joint
error's own alignment (each frame in its ground point and heading)."""

import math

import numpy as np
import pytest

from graphsvc.evaluate import oracle
from graphsvc.evaluate.metrics import joint_err_cm


def test_local_positions_take_off_the_ground_point_and_turn_by_the_heading():
    # Facing +X (heading π/2): a joint 1 m ahead of the pelvis sits at ground + (1, 0);
    # in the frame's own heading it is 1 m along +Z, at its own height.
    pos = np.array([[[3.0, 0.5, 2.0]]])
    out = oracle.local_positions(pos, np.array([[2.0, 2.0]]), np.array([math.pi / 2]))
    np.testing.assert_allclose(out, [[[0.0, 0.5, 1.0]]], atol=1e-12)


def test_the_floor_is_the_closest_allowed_pose_by_the_mean_joint_distance():
    # Two joints; three node poses. Truth frame 0 is node 1 moved 1 cm on one joint;
    # truth frame 1 is nearest node 0, which is hidden, so node 2 must serve.
    nodes = np.array(
        [[[0.0, 1.0, 0.0], [0.0, 0.0, 0.0]], [[0.1, 1.0, 0.0], [0.0, 0.0, 0.2]], [[0.0, 1.0, 0.3], [0.0, 0.0, 0.0]]],
        dtype=np.float32,
    )
    truth = np.array([[[0.11, 1.0, 0.0], [0.0, 0.0, 0.2]], [[0.0, 1.0, 0.05], [0.0, 0.0, 0.0]]])
    err, node = oracle.pose_oracle(nodes, np.array([False, True, True]), truth)
    np.testing.assert_array_equal(node, [1, 2])
    # frame 0: (1 cm + 0) / 2; frame 1: node 2 is 25 cm off on joint 0, 0 on joint 1.
    np.testing.assert_allclose(err, [0.5, 12.5], atol=1e-5)
    # The same figure as the metric's, the node placed anywhere and turned any way.
    ground, heading = np.array([[4.0, -1.0]]), np.array([2.0])
    c, s = math.cos(heading[0]), math.sin(heading[0])
    placed = nodes[2].astype(np.float64).copy()
    placed[:, 0], placed[:, 2] = (
        c * nodes[2][:, 0] + s * nodes[2][:, 2] + 4.0,
        -s * nodes[2][:, 0] + c * nodes[2][:, 2] - 1.0,
    )
    _, metric = joint_err_cm(placed[None], truth[1:2], ground, heading, np.zeros((1, 2)), np.zeros(1))
    assert metric == pytest.approx(err[1], abs=1e-4)
