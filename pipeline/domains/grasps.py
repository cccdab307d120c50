"""Grasps of a box-shaped object by a Panda hand (grasp_arm and grasp_base): 9 approach
directions (one from above, eight from the sides) × 3 wrist rotations × 3 depths, and the
pre-grasp pose ``offset`` metres back along the approach."""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np

from pipeline.domains.base import Feature
from pipeline.domains.geometry import Box
from pipeline.sim.transforms import quaternion, rot_z

#: A grasp's feature row after its arm (grasp_base has one arm, so its θ starts here).
GRASP_FEATURES = (
    Feature("approach_x", "1", "direction the hand moves in, object frame, x"),
    Feature("approach_y", "1", "direction the hand moves in, object frame, y"),
    Feature("approach_z", "1", "direction the hand moves in, object frame, z"),
    Feature("rotation", "rad", "wrist rotation about the approach"),
    Feature("depth", "m", "TCP offset from the object's centre along the approach"),
)


@dataclass(frozen=True)
class Grasp:
    arm: int
    approach: np.ndarray  # unit vector in the object frame: the direction the hand moves in
    rotation: float  # about the approach axis, radians
    depth: float  # TCP offset from the object centre along the approach, metres

    @property
    def features(self) -> np.ndarray:
        return np.array([self.arm, *self.approach, self.rotation, self.depth])

    @functools.cached_property
    def hand(self) -> np.ndarray:
        """The TCP's rotation in the object frame (:func:`hand_orientation`), computed once
        per grasp: every planning call with this grasp needs it."""
        return hand_orientation(self.approach, self.rotation)


def grasp_set() -> list[Grasp]:
    """The 162 constraints of grasp_arm: 2 arms × (9 approaches × 3 rotations × 3 depths);
    those of arm 0 are grasp_base's 81."""
    approaches = [np.array([0.0, 0.0, -1.0])] + [
        np.array([-np.cos(a), -np.sin(a), 0.0]) for a in np.arange(8) * np.pi / 4]
    return [Grasp(arm, np.round(d, 12), rot, depth)
            for arm, d, rot, depth in itertools.product(
                (0, 1), approaches, (0.0, np.pi / 4, np.pi / 2), (-0.02, 0.0, 0.02))]


@functools.lru_cache(maxsize=1)
def _feature_table() -> dict[tuple, int]:
    return {tuple(np.round(g.features, 9)): k for k, g in enumerate(grasp_set())}


def grasp_index(features) -> int | None:
    """The index in :func:`grasp_set` of the grasp with this feature row, or None."""
    row = np.asarray(features, float)
    return _feature_table().get(tuple(np.round(row, 9))) if row.shape == (6,) else None


def hand_orientation(approach: np.ndarray, rotation: float) -> np.ndarray:
    """Rotation matrix of the TCP frame: z along the approach, x turned by ``rotation``."""
    z = approach / np.linalg.norm(approach)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x0 = ref - z * (ref @ z)
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(z, x0)
    x = np.cos(rotation) * x0 + np.sin(rotation) * y0
    return np.column_stack([x, np.cross(z, x), z])


def pregrasp_pose(target: Box, g: Grasp, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """World position and quaternion of the TCP at g's pre-grasp of the ``target`` box:
    ``offset`` metres back along the approach from the grasp."""
    R_obj = rot_z(target.yaw)
    approach = R_obj @ g.approach
    pre = np.asarray(target.position) + approach * (g.depth - offset)
    return pre, quaternion(R_obj @ g.hand)
