"""A headless pybullet client and the static boxes scenes are made of."""

from __future__ import annotations

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
    """(x, y, z, w) of a rotation matrix (pybullet's order)."""
    w = np.sqrt(max(0.0, 1 + R[0, 0] + R[1, 1] + R[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + R[0, 0] - R[1, 1] - R[2, 2])) / 2, R[2, 1] - R[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] + R[1, 1] - R[2, 2])) / 2, R[0, 2] - R[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - R[0, 0] - R[1, 1] + R[2, 2])) / 2, R[1, 0] - R[0, 1])
    return np.array([x, y, z, w])


def pose_matrix(position, R: np.ndarray) -> np.ndarray:
    """The 4 × 4 homogeneous transform of a position and a rotation matrix."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = position
    return T


def add_box(client: int, size, position, yaw: float = 0.0, rgba=(0.6, 0.6, 0.6, 1.0)) -> int:
    """A static box of full extents ``size`` centred at ``position``, rotated by ``yaw``."""
    half = [float(s) / 2 for s in size]
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
    visual = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=list(rgba),
                                  physicsClientId=client)
    return pb.createMultiBody(baseMass=0, baseCollisionShapeIndex=shape,
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
