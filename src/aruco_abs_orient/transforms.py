"""Rotations, quaternions and rigid transforms (the package's one copy of this algebra).

Conventions (doc/design.md §2): attitude ``R = Rz(yaw) · Ry(pitch) · Rx(roll)``, angles in radians;
quaternions are ``(x, y, z, w)`` as in ROS/TUM; a 4×4 homogeneous matrix ``a_T_b`` maps
b-coordinates into a. Functions are vectorised over leading dimensions where noted.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "cross3",
    "rot_x",
    "rot_y",
    "rot_z",
    "rpy_to_matrix",
    "matrix_to_rpy",
    "rotvec_to_matrix",
    "yaw_of",
    "wrap_angle",
    "quat_to_matrix",
    "matrix_to_quat",
    "make_T",
    "invert_T",
    "transform_points",
]


def wrap_angle(angle):
    """Angle(s) (radians) wrapped to [−π, π)."""
    return (np.asarray(angle, dtype=float) + math.pi) % (2.0 * math.pi) - math.pi


def _rotation_about(axis: int, a) -> np.ndarray:
    """Rotation(s) (..., 3, 3) about coordinate ``axis`` (0 x, 1 y, 2 z) by ``a`` radians: filled in place
    (the solver and the tracker build tens of thousands a run; nested np.stack costs 20 µs each)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    R = np.zeros(a.shape + (3, 3))
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    R[..., j, j] = c
    return R


def rot_x(a) -> np.ndarray:
    """Rotation(s) (..., 3, 3) about x by ``a`` radians."""
    return _rotation_about(0, a)


def rot_y(a) -> np.ndarray:
    """Rotation(s) (..., 3, 3) about y by ``a`` radians."""
    return _rotation_about(1, a)


def rot_z(a) -> np.ndarray:
    """Rotation(s) (..., 3, 3) about z by ``a`` radians."""
    return _rotation_about(2, a)


def cross3(a, b) -> np.ndarray:
    """``np.cross`` of 3-vectors (..., 3), broadcast, with the same arithmetic (the same bits) without its
    axis handling (15 µs a call in the solver's and the camera model's inner loops)."""
    a = np.asarray(a)
    b = np.asarray(b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast(a0, b0).shape + (3,), dtype=np.result_type(a, b))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def rpy_to_matrix(roll, pitch, yaw) -> np.ndarray:
    """``Rz(yaw) · Ry(pitch) · Rx(roll)`` (..., 3, 3); angles in radians."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def rotvec_to_matrix(w) -> np.ndarray:
    """Rotation matrix/matrices (..., 3, 3) of rotation vector(s) ``w`` (..., 3): the axis times the angle in
    radians (Rodrigues; exact for any angle, the identity for a zero vector)."""
    w = np.asarray(w, dtype=float)
    theta = np.sqrt(np.sum(w * w, axis=-1))
    small = theta < 1e-12
    k = w / np.where(small, 1.0, theta)[..., None]
    K = np.zeros(w.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = k[..., 2], -k[..., 1], k[..., 0]
    s = np.sin(theta)[..., None, None]
    c = (1.0 - np.cos(theta))[..., None, None]
    return np.eye(3) + s * K + c * (K @ K)


def matrix_to_rpy(R):
    """(roll, pitch, yaw) in radians of rotation matrix/matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    pitch = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 2, 1], R[..., 2, 2]))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    return roll, pitch, yaw


def yaw_of(R):
    """Yaw (radians) of rotation matrix/matrices (..., 3, 3) in the Z-Y-X convention."""
    R = np.asarray(R, dtype=float)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def quat_to_matrix(q) -> np.ndarray:
    """Rotation matrix/matrices (..., 3, 3) of quaternion(s) ``(x, y, z, w)`` (normalised here)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def matrix_to_quat(R) -> np.ndarray:
    """Quaternion(s) ``(x, y, z, w)`` with w ≥ 0 of rotation matrix/matrices (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # Squared magnitudes of the components; take signs from the off-diagonal terms of the
    # largest one (numerically stable everywhere).
    w2 = np.maximum(0.0, 1 + m00 + m11 + m22)
    x2 = np.maximum(0.0, 1 + m00 - m11 - m22)
    y2 = np.maximum(0.0, 1 - m00 + m11 - m22)
    z2 = np.maximum(0.0, 1 - m00 - m11 + m22)
    cand = np.stack([
        np.stack([w2, R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1),
        np.stack([R[..., 2, 1] - R[..., 1, 2], x2, R[..., 1, 0] + R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0]], -1),
        np.stack([R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] + R[..., 0, 1], y2, R[..., 2, 1] + R[..., 1, 2]], -1),
        np.stack([R[..., 1, 0] - R[..., 0, 1], R[..., 0, 2] + R[..., 2, 0], R[..., 2, 1] + R[..., 1, 2], z2], -1),
    ], -2)  # row k: 4·q_k·(w, x, y, z)
    k = np.argmax(np.stack([w2, x2, y2, z2], -1), axis=-1)
    row = np.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]
    wxyz = row / np.linalg.norm(row, axis=-1, keepdims=True)
    wxyz = wxyz * np.where(wxyz[..., :1] < 0, -1.0, 1.0)
    return np.concatenate([wxyz[..., 1:], wxyz[..., :1]], axis=-1)


def _broadcast_shapes(*shapes) -> tuple:
    """``np.broadcast_shapes`` (numpy ≥ 1.20) for numpy 1.17 too (Noetic's python3-numpy)."""
    return np.broadcast(*[np.empty(s + (0,), dtype=bool) for s in shapes]).shape[:-1]


def make_T(R=None, t=None) -> np.ndarray:
    """4×4 homogeneous transform(s) from rotation (..., 3, 3) and translation (..., 3)."""
    if R is None:
        R = np.eye(3)
    R = np.asarray(R, dtype=float)
    t = np.zeros(R.shape[:-2] + (3,)) if t is None else np.asarray(t, dtype=float)
    shape = _broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_T(T) -> np.ndarray:
    """Inverse of rigid transform(s) (..., 4, 4): ``b_T_a`` from ``a_T_b``."""
    T = np.asarray(T, dtype=float)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    return make_T(Rt, -(Rt @ T[..., :3, 3:4])[..., 0])


def transform_points(a_T_b, points_b) -> np.ndarray:
    """Points (..., 3) in frame b mapped into frame a by ``a_T_b`` (4, 4)."""
    a_T_b = np.asarray(a_T_b, dtype=float)
    p = np.asarray(points_b, dtype=float)
    return p @ a_T_b[:3, :3].T + a_T_b[:3, 3]
