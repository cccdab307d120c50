"""A Panda on a mobile base (x, y, ψ) whose platform collides, optionally holding an object.

The platform is a box (``PLATFORM``) and the arm is mounted on its top, ``MOUNT`` metres
ahead of its centre.  Moving the base resets three bodies (platform, arm and, when one is
held, the object), about 30 µs per reset as measured for this project.

A held object follows the hand rigidly.  During base motion the arm does not move, so the
object's pose in the base frame is fixed and no forward kinematics is needed per check;
during arm motion it is placed from the TCP pose at every check.  Contacts between the
held object and the hand or fingers are the grasp itself, not collisions.

What planners see of it are robot models (:class:`pipeline.planning.base.RobotModel`):
:class:`MobileArm` (the arm, base fixed; may hold an object), :class:`UnladenArm` (the same
with signed distances, for a robot that holds nothing) and :class:`MobileBase` (the base
in (x, y, psi_scale · ψ), arm fixed).
"""

from __future__ import annotations

import numpy as np
import pybullet as pb

from pipeline.planning.base import Robot
from pipeline.sim import panda as P
from pipeline.sim.contacts import penetrating
from pipeline.sim.world import add_box, pose_matrix, quaternion, rot_z

PLATFORM = (0.60, 0.50, 0.30)  # full size (length along the heading, width, height), metres
PLATFORM_LIFT = 0.01  # gap between the floor and the platform's underside
MOUNT = 0.12  # the arm's base is this far ahead of the platform's centre
HAND_LINKS = frozenset({7, 8, 9, 10, 11})  # flange, hand, fingers, TCP: may touch what it holds
ARM_HEIGHT = PLATFORM_LIFT + PLATFORM[2] + 0.001  # the arm's base above the floor
#: sphere-certified models a MobilePanda keeps (:meth:`MobilePanda.remembered_model`)
MODELS_KEPT = 32


def base_transform(pose) -> np.ndarray:
    """World transform of the base frame: at the floor under the platform's centre."""
    x, y, psi = (float(v) for v in pose)
    return pose_matrix((x, y, 0.0), rot_z(psi))


def _pose_of(body: int, client: int) -> np.ndarray:
    pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    R = np.asarray(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
    return pose_matrix(pos, R)


class MobilePanda:
    """The mobile manipulator in ``client``; starts at base pose (0, 0, 0), arm at home."""

    def __init__(self, client: int, *, rgba=(0.25, 0.25, 0.3, 1.0), contacts: str = "cached"):
        self.client = client
        z = PLATFORM_LIFT + PLATFORM[2] / 2
        self.platform = add_box(client, PLATFORM, (0.0, 0.0, z), rgba=rgba, movable=True)
        self.arm = P.Panda(client, (MOUNT, 0.0, ARM_HEIGHT), contacts=contacts)
        self.fresh_contacts = self.arm.fresh_contacts
        self.body = self.arm.body
        self.pose = np.zeros(3)
        self.held: int | None = None
        self._tcp_obj = np.eye(4)  # the held object in the TCP frame
        # ... and in the base frame, for the arm's current q: made when first needed from
        # the base pose and the object's pose when the arm was set
        self._obj_at: tuple[np.ndarray, np.ndarray] | None = (self.pose, np.eye(4))
        self._base_obj_memo: np.ndarray | None = None
        self._placements: dict[bytes, tuple] = {}  # base pose -> what set_base computes
        self._models = None  # see remembered_model
        self.set_base(self.pose)

    # -- state -----------------------------------------------------------------------------
    def set_base(self, pose) -> None:
        pose = np.asarray(pose, float)
        key = pose.tobytes()
        placed = self._placements.get(key)
        if placed is None:  # the same numbers for the same pose, computed once
            T = base_transform(pose)
            placed = (T, (T @ [0.0, 0.0, PLATFORM_LIFT + PLATFORM[2] / 2, 1.0])[:3].tolist(),
                      quaternion(T[:3, :3]).tolist(), (T @ [MOUNT, 0.0, ARM_HEIGHT, 1.0])[:3],
                      float(pose[2]))
            if len(self._placements) > 256:
                self._placements.clear()
            self._placements[key] = placed
        T, position, orientation, arm_position, yaw = placed
        self.pose = pose.copy()
        pb.resetBasePositionAndOrientation(self.platform, position, orientation,
                                          physicsClientId=self.client)
        self.arm.set_base(arm_position.copy(), yaw)
        if self.held is not None:
            self._place_held(T @ self._base_obj)

    @property
    def _base_obj(self) -> np.ndarray:
        if self._base_obj_memo is None:
            pose, T_obj = self._obj_at
            self._base_obj_memo = np.linalg.inv(base_transform(pose)) @ T_obj
        return self._base_obj_memo

    def set_arm(self, q) -> None:
        self.arm.set(q)
        if self.held is not None:
            T_obj = self.tcp_transform() @ self._tcp_obj
            self._obj_at, self._base_obj_memo = (self.pose, T_obj), None
            self._place_held(T_obj)

    def tcp_transform(self) -> np.ndarray:
        state = pb.getLinkState(self.body, P.TCP_LINK, computeForwardKinematics=True,
                                physicsClientId=self.client)
        R = np.asarray(pb.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        return pose_matrix(state[4], R)

    def grasp(self, body: int, tcp_obj: np.ndarray, q=None) -> None:
        """Hold ``body`` with the TCP-to-object transform ``tcp_obj``; places it now, with
        the arm at ``q`` (None: where it is)."""
        self.held, self._tcp_obj = body, np.asarray(tcp_obj, float)
        self.set_arm(self._current_q() if q is None else q)

    def release(self) -> None:
        self.held = None

    def _current_q(self) -> np.ndarray:
        states = pb.getJointStates(self.body, P.ARM_JOINTS, physicsClientId=self.client)
        return np.array([s[0] for s in states])

    def _place_held(self, T: np.ndarray) -> None:
        pb.resetBasePositionAndOrientation(self.held, T[:3, 3].tolist(),
                                           quaternion(T[:3, :3]).tolist(),
                                           physicsClientId=self.client)

    # -- collision checks ------------------------------------------------------------------
    def _in_collision(self) -> bool:
        """Any penetration of the platform, the arm or the held object with the world (or,
        for the arm, with itself and the platform), at the state already set."""
        c = self.client
        pb.performCollisionDetection(physicsClientId=c)
        robot = (self.platform, self.body)
        if self.fresh_contacts:
            return self._penetrating(robot)
        for pt in pb.getContactPoints(bodyA=self.platform, physicsClientId=c):
            if pt[8] < 0 and pt[2] not in robot:
                return True
        for pt in pb.getContactPoints(bodyA=self.body, physicsClientId=c):
            if pt[8] < 0 and pt[3] != -1 and not (pt[2] == self.held and pt[3] in HAND_LINKS):
                return True
        if self.held is not None:
            for pt in pb.getContactPoints(bodyA=self.held, physicsClientId=c):
                if pt[8] < 0 and not (pt[2] == self.body and pt[4] in HAND_LINKS):
                    return True
        return False

    def _penetrating(self, robot) -> bool:
        """:meth:`_in_collision`'s three questions, each cached penetration confirmed
        afresh (``contacts="fresh"``)."""
        c, held = self.client, self.held
        return (penetrating(c, self.platform, lambda pt: pt[2] in robot)
                or penetrating(c, self.body, lambda pt: pt[3] == -1 or (
                    pt[2] == held and pt[3] in HAND_LINKS))
                or (held is not None and penetrating(
                    c, held, lambda pt: pt[2] == self.body and pt[4] in HAND_LINKS)))

    def arm_collides(self, q) -> bool:
        self.set_arm(q)
        return self._in_collision()

    def base_collides(self, pose) -> bool:
        self.set_base(pose)
        return self._in_collision()

    def arm_check(self, states: np.ndarray) -> tuple[bool, int]:
        """Checker for arm paths (base fixed): stops at the first colliding configuration."""
        for k, q in enumerate(states):
            if self.arm_collides(q):
                return False, k + 1
        return True, len(states)

    @property
    def shoulder(self) -> np.ndarray:
        return self.arm.shoulder

    @property
    def joint2(self) -> np.ndarray:
        return self.arm.joint2

    # -- what the sphere pre-check (pipeline.sim.fast_check) reads -------------------------
    hand_links = HAND_LINKS
    #: None, or a function a scene sets: a key that is the same only while everything that
    #: is not this robot (nor what it holds) is the same (fast_check reads it once per key)
    world_key = None

    def base_frame(self) -> np.ndarray:
        return base_transform(self.pose)

    def remembered_model(self, part: type, state: bytes, make):
        """``make()``, a sphere-certified model of this robot's ``part`` (the class of the
        robot model: an arm, whose base is fixed at ``state``, the base pose; the base, whose
        arm is fixed at ``state``, its joints), or the one it made for the same class and
        state while the scene's :attr:`world_key`, what is held and how are the same: a planning
        call then reuses what the calls before it settled (each instance's pick motions
        share one model, each grasp's base motions another).  Without a world key, a new
        model every call.  The :data:`MODELS_KEPT` most recently used are kept."""
        world = self.world_key() if callable(self.world_key) else None
        if world is None:
            return make()
        if self._models is None:
            from pipeline.sim.fast_check import Memo  # here: numba loads with fast_check

            self._models = Memo(MODELS_KEPT)
        held = None if self.held is None else (self.held, self._tcp_obj.tobytes())
        return self._models.get((part, state, world, held), make)

    @property
    def held_in_tcp(self) -> np.ndarray:
        return self._tcp_obj

    @property
    def held_in_base(self) -> np.ndarray:
        return self._base_obj

    def ik(self, position, orientation, starts, collides=None):
        """Panda.ik with this robot's check (platform and held object included), or
        ``collides``: a check with the same answers."""
        return self.arm.ik(position, orientation, starts,
                           collides=collides or self.arm_collides)

    def analytic_ik(self, position, orientation, tries: int, collides=None):
        """Panda.analytic_ik with this robot's check, or ``collides`` (as :meth:`ik`)."""
        return self.arm.analytic_ik(position, orientation, tries,
                                    collides=collides or self.arm_collides)

    def held_pose(self) -> np.ndarray:
        return _pose_of(self.held, self.client)


class MobileArm(Robot):
    """The arm of a :class:`MobilePanda` whose base stands still; its checks include the
    platform and the held object, if any."""

    description = "the mobile Panda's arm, which may hold an object,"
    lower, upper = P.LOWER, P.UPPER

    def __init__(self, robot: MobilePanda):
        self.robot = robot

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        return self.robot.arm_check(states)

    def certified(self):
        """This arm with sphere-certified checks (the ``certified`` capability), the same
        model again for the same base pose and world (:meth:`MobilePanda.remembered_model`)."""
        from pipeline.sim.fast_check import certified_mobile_arm

        r = self.robot
        return r.remembered_model(type(self), r.pose.tobytes(),
                                  lambda: certified_mobile_arm(self))


class UnladenArm(MobileArm):
    """:class:`MobileArm` of a robot that holds nothing: its signed distances are the arm
    links' (the platform counts as an obstacle)."""

    description = "the mobile Panda's empty-handed arm"

    def distance_model(self, query: float):
        return self.robot.arm.distance_model(query)

    def bounded_distance_model(self, query: float):
        return self.robot.arm.bounded_distance_model(query)


class MobileBase(Robot):
    """The base of a :class:`MobilePanda` with the arm (and anything held) fixed; states
    are (x, y, psi_scale · ψ) so that one resolution is metres in every coordinate."""

    description = "the mobile Panda's base"

    def __init__(self, robot: MobilePanda, psi_scale: float, lower, upper):
        self.robot, self.psi_scale = robot, psi_scale
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)

    def certified(self):
        """This base with sphere-certified checks (the ``certified`` capability), the same
        model again for the same arm state and world (:meth:`MobilePanda.remembered_model`)."""
        from pipeline.sim.fast_check import certified_mobile_base

        r = self.robot

        def make():
            r.set_base(r.pose)  # the held object where base checks will put it
            return certified_mobile_base(self)

        return r.remembered_model(type(self), r._current_q().tobytes(), make)

    def collides(self, s) -> bool:
        return self.robot.base_collides((s[0], s[1], s[2] / self.psi_scale))

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        for k, s in enumerate(states):
            if self.collides(s):
                return False, k + 1
        return True, len(states)

