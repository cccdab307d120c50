"""A headless pybullet client and the static boxes scenes are made of."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pybullet as pb
import pybullet_data


def connect() -> int:
    """A new DIRECT (headless) client with pybullet_data on its search path."""
    client = pb.connect(pb.DIRECT)
    pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
    return client


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


def add_box(client: int, size, position, yaw: float = 0.0, rgba=(0.6, 0.6, 0.6, 1.0),
            movable: bool = False) -> int:
    """A box of full extents ``size`` centred at ``position``, rotated by ``yaw``.

    pybullet reports no contacts between two bodies of mass 0, so a box that moves and must
    be checked against the static scenery (a robot's platform, an object it carries) is
    ``movable``: it gets a mass.  Nothing here steps the simulation, so mass moves nothing.
    """
    half = [float(s) / 2 for s in size]
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
    visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=list(rgba),
                                  physicsClientId=client)
    return pb.createMultiBody(baseMass=1.0 if movable else 0.0, baseCollisionShapeIndex=shape,
                              baseVisualShapeIndex=visual,
                              basePosition=[float(p) for p in position],
                              baseOrientation=yaw_quaternion(yaw), physicsClientId=client)


def camera_image(client: int, eye, target, width: int = 480, height: int = 360,
                 fov: float = 50.0) -> np.ndarray:
    """An (height, width, 3) uint8 RGB image from the CPU renderer (works headless)."""
    view = pb.computeViewMatrix(list(eye), list(target), [0, 0, 1], physicsClientId=client)
    proj = pb.computeProjectionMatrixFOV(fov, width / height, 0.05, 20.0, physicsClientId=client)
    img = pb.getCameraImage(width, height, view, proj, renderer=pb.ER_TINY_RENDERER,
                            physicsClientId=client)
    return np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))[..., :3]


def save_png(rgb: np.ndarray, path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(path)
    plt.imsave(out, rgb)
    return out
