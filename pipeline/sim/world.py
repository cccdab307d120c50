"""A headless pybullet client and the static boxes scenes are made of."""

from __future__ import annotations

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
