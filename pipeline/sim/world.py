"""A headless pybullet client and the static boxes scenes are made of."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as pb
import pybullet_data

from pipeline.sim.transforms import pose_matrix, quaternion, rot_z, yaw_quaternion

__all__ = ["add_box", "camera_image", "connect", "pose_matrix", "quaternion", "rot_z",
           "save_png", "yaw_quaternion"]


def connect() -> int:
    """A new DIRECT (headless) client with pybullet_data on its search path."""
    client = pb.connect(pb.DIRECT)
    pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
    return client


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
    """Write an RGB image as a PNG (matplotlib's image module: no backend, no pyplot)."""
    from matplotlib.image import imsave

    out = Path(path)
    imsave(out, rgb)
    return out
