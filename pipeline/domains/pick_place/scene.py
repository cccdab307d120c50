"""The pick_place scene: the mobile Panda's scene with the instance's obstacles and the rod,
and the few things the steps do to it (reset, hold the rod, put it somewhere, check it)."""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pybullet as pb

from pipeline.domains.geometry import Box
from pipeline.domains.mobile_world import OBSTACLE_RGBA, MobileScene
from pipeline.domains.pick_place.world import (
    ROD_RGBA,
    ROOMS,
    START_POSE,
    PickPlaceInstance,
    RodGrasp,
    start_rod,
)
from pipeline.sim import panda as P
from pipeline.sim.contacts import collides as collides_afresh
from pipeline.sim.mobile import MobileArm, MobileBase
from pipeline.sim.world import add_box, quaternion, rot_z

_SCENES = itertools.count()


@functools.lru_cache(maxsize=4096)
def _yaw_turn(yaw: float) -> list:
    """``quaternion(rot_z(yaw))`` as a list (shared: pybullet only reads it)."""
    return quaternion(rot_z(yaw)).tolist()


class PickPlaceScene:
    """One pybullet client: floor, furniture, the mobile Panda, the instance's obstacles and
    the rod (a movable body, so that its contacts with the static world are reported)."""

    def __init__(self, furniture: list[Box], psi_scale: float, contacts: str = "cached"):
        self.mobile = MobileScene(furniture, contacts)
        self.client_id = self.mobile.client_id
        self.robot = self.mobile.robot
        self.robot_ids = self.mobile.robot_ids
        self.rod: int | None = None
        self._serial, self._loads = next(_SCENES), 0
        self.robot.world_key = self.world_key
        #: the robot models planners see: the arm (base fixed, rod checked when held) and
        #: the base in (x, y, psi_scale · ψ) inside the rooms (arm fixed)
        self.arm = MobileArm(self.robot)
        self.base = MobileBase(self.robot, psi_scale, [ROOMS[0], ROOMS[2], -np.pi * psi_scale],
                               [ROOMS[1], ROOMS[3], np.pi * psi_scale])

    def load(self, inst: PickPlaceInstance) -> None:
        """Put ``inst``'s obstacles and rod in (unless it is loaded already) and reset."""
        if self.mobile.key != inst:
            bodies = self.mobile.load(inst, [(b, OBSTACLE_RGBA) for b in inst.obstacles])
            rod = start_rod(inst.rod_length)
            bodies.append(add_box(self.client_id, rod.size, rod.position, 0.0, rgba=ROD_RGBA,
                                  movable=True))
            self.rod = bodies[-1]
            self._loads += 1
        self.reset(inst)

    def world_key(self) -> tuple:
        """What is not the robot: the same key, the same bodies at the same poses (the
        obstacles change only when another instance is loaded; the rod is the robot's
        while held, else where it lies)."""
        rod = None
        if self.rod is not None and self.robot.held != self.rod:
            rod = pb.getBasePositionAndOrientation(self.rod, physicsClientId=self.client_id)
        return self._serial, self._loads, rod

    def reset(self, inst: PickPlaceInstance) -> None:
        """Rod on the start table, robot at the start with the arm at home, nothing held."""
        self.robot.release()
        self.put_rod(start_rod(inst.rod_length))
        self.robot.set_base(START_POSE)
        self.robot.set_arm(P.HOME)

    def put_rod(self, box: Box) -> None:
        pb.resetBasePositionAndOrientation(self.rod, list(box.position), _yaw_turn(box.yaw),
                                           physicsClientId=self.client_id)

    def rod_collides(self) -> bool:
        c = self.client_id
        if self.robot.fresh_contacts:
            return collides_afresh(c, self.rod)
        pb.performCollisionDetection(physicsClientId=c)
        return any(pt[8] < 0 for pt in pb.getContactPoints(bodyA=self.rod, physicsClientId=c))

    def hold(self, inst: PickPlaceInstance, g: RodGrasp, carry: np.ndarray) -> None:
        """The rod in the hand, the arm in the carry configuration."""
        self.robot.grasp(self.rod, g.rod_in_hand(inst.rod_length), carry)

    def set_configuration(self, q) -> None:
        """q = (x, y, ψ, 7 arm joints)."""
        self.mobile.set_configuration(q)

    def close(self) -> None:
        self.mobile.close()
