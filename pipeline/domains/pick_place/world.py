"""The pick_place world as data: rooms, walls, tables, the rod and its 81 grasps, the
instance and the constraint θ (a :class:`Route`).  No simulator."""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from pipeline.domains.geometry import Box, rectangle
from pipeline.domains.grasps import hand_orientation
from pipeline.domains.mobile_world import Table
from pipeline.sim.transforms import pose_matrix, rot_z

ROD_RGBA = (0.1, 0.1, 0.1, 1.0)
ROD_SECTION = 0.04  # the rod's square cross-section, metres
WALL_THICKNESS = 0.10
WALL_HEIGHT = 1.5
ROOMS = (-3.0, 3.0, -1.6, 1.6)  # x0, x1, y0, y1 of both rooms together
START_TABLE = Table((-1.9, -1.15), (1.2, 0.6), 0.40)
GOAL_TABLE = Table((2.1, 0.0), (0.8, 2.4), 0.40)
#: the goal table's top, corner to corner (x, y): where a placed rod must lie
_GOAL_LO = np.subtract(GOAL_TABLE.centre, np.divide(GOAL_TABLE.size, 2))
_GOAL_HI = np.add(GOAL_TABLE.centre, np.divide(GOAL_TABLE.size, 2))
ROD_START = (-1.9, -1.05)  # centre (x, y) of the rod on the start table, along x
START_POSE = np.array([-1.9, -0.35, -np.pi / 2])  # facing the start table
PARK_POSE = np.array([0.0, -4.0, 0.0])  # outside the rooms: where carry IK is solved
SUBGOAL_GAP = 0.6  # metres in front of the wall where k_sg is taken from a raw solution
CARRY_TCP = np.array([0.55, 0.0, 1.0])  # the TCP while driving, in the base frame
FRACTIONS = np.linspace(-0.8, 0.8, 9)  # grasp position along the rod, × half-length
ANGLES = (-np.pi / 6, 0.0, np.pi / 6)


@dataclass(frozen=True)
class RodGrasp:
    fraction: float  # TCP position along the rod, × half-length, from its centre
    rotation: float  # wrist rotation about the approach, from across the rod
    tilt: float  # approach tilt about the rod's axis, from straight down

    @property
    def features(self) -> np.ndarray:
        return np.array([self.fraction, self.rotation, self.tilt])

    def rod_tcp(self, length: float) -> np.ndarray:
        """The TCP in the rod's frame (x along the rod, z up): on the rod's axis, its z
        along the approach; at rotation 0 its x is along the rod, so the fingers close
        across it.  (A new array each call; computed once per grasp and length.)"""
        return _rod_tcp(self.fraction, self.rotation, self.tilt, float(length)).copy()

    def rod_in_hand(self, length: float) -> np.ndarray:
        """The rod in the TCP frame, ``inv(rod_tcp(length))`` (a new array each call)."""
        return _rod_in_hand(self.fraction, self.rotation, self.tilt, float(length)).copy()


@functools.lru_cache(maxsize=1024)
def _rod_tcp(fraction: float, rotation: float, tilt: float, length: float) -> np.ndarray:
    approach = rot_x(tilt) @ np.array([0.0, 0.0, -1.0])
    return pose_matrix((fraction * length / 2, 0.0, 0.0), hand_orientation(approach, rotation))


@functools.lru_cache(maxsize=1024)
def _rod_in_hand(fraction: float, rotation: float, tilt: float, length: float) -> np.ndarray:
    return np.linalg.inv(_rod_tcp(fraction, rotation, tilt, length))


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rod_grasps() -> list[RodGrasp]:
    return [RodGrasp(round(float(f), 9), a, t) for f in FRACTIONS for a in ANGLES for t in ANGLES]


@dataclass(frozen=True)
class PickPlaceInstance:
    seed: int
    rod_length: float
    obstacles: tuple[Box, ...]


@dataclass(frozen=True)
class Route:
    """θ: grasp, placement (x, y, yaw), pre-place base pose, subgoal base pose."""

    grasp: RodGrasp
    placement: np.ndarray
    place_pose: np.ndarray
    subgoal: np.ndarray

    @property
    def features(self) -> np.ndarray:
        return np.concatenate([self.grasp.features, self.placement, self.place_pose,
                               self.subgoal])


def rod_box(length: float, x: float, y: float, yaw: float, table: Table) -> Box:
    return Box((length, ROD_SECTION, ROD_SECTION), (x, y, table.height + ROD_SECTION / 2 + 1e-3),
               yaw)


def start_rod(length: float) -> Box:
    """The rod where every instance starts: on the start table, along x."""
    return rod_box(length, *ROD_START, 0.0, START_TABLE)


def placed_rod(length: float, placement) -> Box:
    """The rod lying at placement (x, y, yaw) on the goal table."""
    return rod_box(length, placement[0], placement[1], placement[2], GOAL_TABLE)


def rod_pose(length: float, placement) -> np.ndarray:
    """World transform of the rod lying at placement (x, y, yaw) on the goal table."""
    box = placed_rod(length, placement)
    return pose_matrix(box.position, rot_z(box.yaw))


def walls(door_width: float) -> list[Box]:
    x0, x1, y0, y1 = ROOMS
    t, h = WALL_THICKNESS, WALL_HEIGHT
    side = (y1 - y0 - door_width) / 2  # the middle wall on each side of the door
    return [Box((x1 - x0 + 2 * t, t, h), ((x0 + x1) / 2, y0 - t / 2, h / 2), 0.0),
            Box((x1 - x0 + 2 * t, t, h), ((x0 + x1) / 2, y1 + t / 2, h / 2), 0.0),
            Box((t, y1 - y0, h), (x0 - t / 2, (y0 + y1) / 2, h / 2), 0.0),
            Box((t, y1 - y0, h), (x1 + t / 2, (y0 + y1) / 2, h / 2), 0.0),
            Box((t, side, h), (0.0, y0 + side / 2, h / 2), 0.0),
            Box((t, side, h), (0.0, y1 - side / 2, h / 2), 0.0)]


def furniture(door_width: float) -> list[Box]:
    return [START_TABLE.box(), GOAL_TABLE.box(), *walls(door_width)]


def on_goal_table(length: float, placement) -> bool:
    corners = rectangle(placement[:2], (length, ROD_SECTION), placement[2])
    return bool(np.all(corners >= _GOAL_LO) and np.all(corners <= _GOAL_HI))


def in_rooms(pose) -> bool:
    return ROOMS[0] < pose[0] < ROOMS[1] and ROOMS[2] < pose[1] < ROOMS[3]


def subgoal_on(path: np.ndarray) -> np.ndarray:
    """Where the base path first crosses x = -SUBGOAL_GAP, in front of the door (on a
    checked edge, so collision-free); the start if it never does."""
    for a, b in zip(path[:-1], path[1:], strict=True):
        if a[0] < -SUBGOAL_GAP <= b[0]:
            t = (-SUBGOAL_GAP - a[0]) / (b[0] - a[0])
            return np.round(a + t * (b - a), 6)
    return START_POSE.copy()
