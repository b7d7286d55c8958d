"""transforms.py: the package's rotation algebra (R = Rz·Ry·Rx, quaternions x,y,z,w, a_T_b), by
property tests against the definitions."""
import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from aruco_abs_orient.transforms import (
    cross3,
    invert_T,
    make_T,
    matrix_to_quat,
    matrix_to_rpy,
    quat_to_matrix,
    rot_x,
    rot_y,
    rot_z,
    rpy_to_matrix,
    transform_points,
    wrap_angle,
    yaw_of,
)

angles = st.floats(-math.pi + 1e-6, math.pi - 1e-6)
pitches = st.floats(-math.pi / 2 + 1e-3, math.pi / 2 - 1e-3)
vectors = st.lists(st.floats(-100, 100), min_size=3, max_size=3)


def test_hand_checked_axes():
    np.testing.assert_allclose(rot_z(math.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # x → y (left)
    np.testing.assert_allclose(rot_y(math.pi / 2) @ [1, 0, 0], [0, 0, -1], atol=1e-15)  # nose down
    np.testing.assert_allclose(rot_x(math.pi / 2) @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(matrix_to_quat(rot_z(math.pi / 2)), [0, 0, math.sqrt(0.5), math.sqrt(0.5)])


@given(angles, pitches, angles)
def test_rpy_round_trip_and_order(roll, pitch, yaw):
    R = rpy_to_matrix(roll, pitch, yaw)
    np.testing.assert_allclose(R, rot_z(yaw) @ rot_y(pitch) @ rot_x(roll), atol=1e-15)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    r, p, y = matrix_to_rpy(R)
    np.testing.assert_allclose([r, p, y], [roll, pitch, yaw], atol=1e-9)
    assert abs(float(yaw_of(R)) - yaw) < 1e-9


@given(angles, pitches, angles)
def test_quaternion_round_trip(roll, pitch, yaw):
    R = rpy_to_matrix(roll, pitch, yaw)
    q = matrix_to_quat(R)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12 and q[3] >= 0
    np.testing.assert_allclose(quat_to_matrix(q), R, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(-q), R, atol=1e-12)  # q and −q: one rotation


@given(angles, pitches, angles, vectors, vectors)
def test_rigid_transforms(roll, pitch, yaw, t, p):
    a_T_b = make_T(rpy_to_matrix(roll, pitch, yaw), t)
    np.testing.assert_allclose(invert_T(a_T_b) @ a_T_b, np.eye(4), atol=1e-9)
    p_a = transform_points(a_T_b, p)
    np.testing.assert_allclose(p_a, a_T_b[:3, :3] @ p + np.asarray(t), atol=1e-9)
    np.testing.assert_allclose(transform_points(invert_T(a_T_b), p_a), p, atol=1e-8)


@given(st.floats(-1e3, 1e3))
def test_wrap_angle(a):
    w = float(wrap_angle(a))
    assert -math.pi <= w < math.pi
    assert abs(math.remainder(w - a, 2 * math.pi)) < 1e-9


@given(st.lists(vectors, min_size=1, max_size=4), vectors)
def test_cross3_is_numpys_cross_to_the_bit(many, one):
    """cross3 (the solver's and camera model's fast path) gives np.cross's bits, broadcasting as it does."""
    a, b = np.array(many), np.array(one)
    for x, y in ((a, b), (b, a), (a, a[::-1]), (b, b)):
        assert cross3(x, y).tobytes() == np.cross(x, y).tobytes() and cross3(x, y).shape == np.cross(x, y).shape


@given(st.lists(angles, min_size=0, max_size=3))
def test_rotations_about_an_axis_by_their_definition(a):
    """rot_x/y/z (filled in place) against the textbook matrices, for a scalar and for arrays."""
    for x in (np.array(a), a[0] if a else 0.0):
        c, s = np.cos(x), np.sin(x)
        o, z = np.ones_like(c), np.zeros_like(c)
        want = {rot_x: [[o, z, z], [z, c, -s], [z, s, c]], rot_y: [[c, z, s], [z, o, z], [-s, z, c]],
                rot_z: [[c, -s, z], [s, c, z], [z, z, o]]}
        for f, rows in want.items():
            assert np.array_equal(f(x), np.moveaxis(np.array(rows), (0, 1), (-2, -1)))
