import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from graphsvc.motion import quat

angles = st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3)


def test_rotate_about_y_quarter_turn_takes_z_to_x():
    q = quat.about_y(np.pi / 2)
    np.testing.assert_allclose(quat.rotate(q, np.array([0.0, 0.0, 1.0])), [1.0, 0.0, 0.0], atol=1e-12)


def test_heading_angle_of_about_y_is_the_angle():
    a = np.linspace(-3.0, 3.0, 13)
    np.testing.assert_allclose(quat.heading_angle(quat.about_y(a)), a, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(angles, st.sampled_from(["ZXY", "XYZ", "YZX", "ZYX", "XZY", "YXZ"]))
def test_euler_round_trip_and_bvh_convention(a, order):
    q = quat.from_euler(np.array(a), order)
    # BVH convention: R = R_first · R_second · R_third.
    axes = {"X": [1, 0, 0], "Y": [0, 1, 0], "Z": [0, 0, 1]}
    expected = quat.IDENTITY
    for axis, angle in zip(order, a):
        expected = quat.mul(expected, quat.from_axis_angle(np.array(axes[axis], float), np.array(angle)))
    assert abs(abs(np.dot(q, expected)) - 1.0) < 1e-9
    back = quat.from_euler(quat.to_euler(q, order), order)
    assert abs(abs(np.dot(q, back)) - 1.0) < 1e-9


def test_slerp_halfway_is_half_angle_and_endpoints_exact():
    a = quat.IDENTITY
    b = quat.about_y(1.2)
    np.testing.assert_allclose(quat.slerp(a, b, 0.0), a, atol=1e-12)
    np.testing.assert_allclose(quat.slerp(a, b, 1.0), b, atol=1e-12)
    np.testing.assert_allclose(quat.slerp(a, b, 0.5), quat.about_y(0.6), atol=1e-12)
    # Takes the short way round when the quaternions are on opposite hemispheres.
    np.testing.assert_allclose(np.abs(quat.slerp(a, -b, 0.5)), np.abs(quat.about_y(0.6)), atol=1e-12)


def test_between_maps_u_onto_v_including_opposite():
    u = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]])
    v = np.array([[0, 1.0, 0], [0, -1.0, 0], [0.6, 0, 0.8]])
    np.testing.assert_allclose(quat.rotate(quat.between(u, v), u), v, atol=1e-12)


def test_matrix_round_trip():
    q = quat.normalize(np.array([0.3, -0.2, 0.9, 0.1]))
    np.testing.assert_allclose(np.abs(quat.from_matrix(quat.to_matrix(q))), np.abs(q), atol=1e-12)
    np.testing.assert_allclose(
        quat.to_matrix(q) @ [1.0, 2.0, 3.0], quat.rotate(q, np.array([1.0, 2.0, 3.0])), atol=1e-12
    )


def test_wrap_angle():
    np.testing.assert_allclose(
        quat.wrap_angle(np.array([0.0, 3 * np.pi / 2, -3 * np.pi / 2, 7.0])),
        [0.0, -np.pi / 2, np.pi / 2, 7.0 - 2 * np.pi],
        atol=1e-12,
    )
