"""Rigid transforms as numpy arrays (no simulator): rotations about the vertical,
quaternions in pybullet's (x, y, z, w) order, homogeneous 4 × 4 poses."""

from __future__ import annotations

import math

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
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(R, float).tolist()  # the
    # same operations in the same order as on numpy scalars, at half the cost
    t = r00 + r11 + r22
    diag = (t, r00, r11, r22)
    k = diag.index(max(diag))
    if k == 0:
        w = math.sqrt(1 + t) / 2
        q = [(r21 - r12) / (4 * w), (r02 - r20) / (4 * w), (r10 - r01) / (4 * w), w]
    else:
        M = ((r00, r01, r02), (r10, r11, r12), (r20, r21, r22))
        i = k - 1
        j, m = (i + 1) % 3, (i + 2) % 3
        v = math.sqrt(max(0.0, 1 + 2 * M[i][i] - t)) / 2
        q = [0.0, 0.0, 0.0, (M[m][j] - M[j][m]) / (4 * v)]
        q[i] = v
        q[j] = (M[j][i] + M[i][j]) / (4 * v)
        q[m] = (M[m][i] + M[i][m]) / (4 * v)
    q = np.array(q)
    return q / np.linalg.norm(q)


def pose_matrix(position, R: np.ndarray) -> np.ndarray:
    """The 4 × 4 homogeneous transform of a position and a rotation matrix."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = position
    return T
