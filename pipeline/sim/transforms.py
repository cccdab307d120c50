"""Rigid transforms as numpy arrays (no simulator): rotations about the vertical,
quaternions in pybullet's (x, y, z, w) order, homogeneous 4 × 4 poses."""

from __future__ import annotations

import numpy as np


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2)))


def rot_z(yaw: float) -> np.ndarray:
    """The 3 × 3 rotation by ``yaw`` about the vertical."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def quaternion(R: np.ndarray) -> np.ndarray:
    """(x, y, z, w) of a rotation matrix (pybullet's order).

    Shepperd's method: solve for the largest of |w|, |x|, |y|, |z| first and get the
    others from off-diagonal sums, so rotations by π (w = 0) keep their axis's signs.
    """
    t = np.trace(R)
    k = int(np.argmax([t, R[0, 0], R[1, 1], R[2, 2]]))
    if k == 0:
        w = np.sqrt(1 + t) / 2
        q = [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
             (R[1, 0] - R[0, 1]) / (4 * w), w]
    else:
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        v = np.sqrt(max(0.0, 1 + 2 * R[i, i] - t)) / 2
        q = [0.0, 0.0, 0.0, (R[m, j] - R[j, m]) / (4 * v)]
        q[i] = v
        q[j] = (R[j, i] + R[i, j]) / (4 * v)
        q[m] = (R[m, i] + R[i, m]) / (4 * v)
    q = np.asarray(q)
    return q / np.linalg.norm(q)


def pose_matrix(position, R: np.ndarray) -> np.ndarray:
    """The 4 × 4 homogeneous transform of a position and a rotation matrix."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = position
    return T
