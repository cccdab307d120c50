"""The Franka Panda in pybullet: fast collision checks and IK with seeded restarts.

A :class:`pipeline.planning.base.RobotModel` with distances (docs/architecture.md).

Collision check (the fastest method measured for this project): set all seven joints with one
``resetJointStatesMultiDof`` call, ``performCollisionDetection``, then look for contacts of
the arm with penetration (distance < 0).  Self-collision is on, with the link pairs that
touch at the home configuration or are parent and child filtered out.  The base link does
not move, so its contacts (with the stand) are ignored.  ``contacts="fresh"`` confirms every
penetration pybullet reports from its cached contact points afresh, so that the answer is
a function of the poses alone (:mod:`pipeline.sim.contacts`, docs/contacts.md).
"""

from __future__ import annotations

import numpy as np
import pybullet as pb

from pipeline.planning.base import Robot
from pipeline.sim.contacts import collides as collides_afresh
from pipeline.sim.world import yaw_quaternion

ARM_JOINTS = tuple(range(7))
FINGER_JOINTS = (9, 10)
TCP_LINK = 11  # panda_grasptarget: the point between the fingertips
HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
LOWER = np.array([-2.9671, -1.8326, -2.9671, -3.1416, -2.9671, -0.0873, -2.9671])
UPPER = np.array([2.9671, 1.8326, 2.9671, 0.0, 2.9671, 3.8223, 2.9671])
REACH = 0.855  # from the shoulder (joint 2) to the TCP at full stretch, metres
SHOULDER_HEIGHT = 0.333
#: IK's tolerances: a solution's TCP within these of the pose asked for (metres, radians)
IK_POS_TOL, IK_ANG_TOL = 0.005, 0.05
#: The wrist point (panda_link6's origin, where the axes of joints 5 and 6 meet) seen from
#: the TCP: whatever joint 7 does, it lies on a circle of radius WRIST_RADIUS about the TCP's
#: z axis, WRIST_BACK behind the TCP (0.107 m flange + 0.105 m hand; 0.088 m: link 7's
#: offset).  And it is never further than WRIST_REACH from joint 2's origin (the shoulder
#: joint): the URDF puts it at fixed distances hypot(0.316, 0.0825) from there to the elbow
#: (joint 4) and hypot(0.384, 0.0825) from the elbow, so no configuration, within the
#: limits or not, stretches it further than their sum.  tests/test_wrist_reach.py checks all
#: three numbers against pybullet's forward kinematics.
WRIST_BACK, WRIST_RADIUS = 0.212, 0.088
WRIST_REACH = float(np.hypot(0.316, 0.0825) + np.hypot(0.384, 0.0825))


class Panda(Robot):
    """One Panda arm in ``client``; fingers held open."""

    description = "a fixed Panda arm"
    lower, upper = LOWER, UPPER
    #: None, or a function a scene sets: a key that is the same only while everything that
    #: is not this arm is the same (the sphere pre-check reads the world once per key)
    world_key = None
    _certified: tuple | None = None  # (world key, certified model)
    _bounded: tuple | None = None  # (world key and more, bounded distance model)

    def __init__(self, client: int, base_position, *, finger_opening: float = 0.04,
                 contacts: str = "cached"):
        self.client = client
        #: ``domain.contacts`` (its schema checks the value): "fresh" confirms every cached
        #: penetration anew at each check
        self.fresh_contacts = contacts == "fresh"
        self.base_position = np.asarray(base_position, float)
        self.base_yaw = 0.0
        self.body = pb.loadURDF("franka_panda/panda.urdf", basePosition=list(self.base_position),
                                useFixedBase=True, flags=pb.URDF_USE_SELF_COLLISION,
                                physicsClientId=client)
        for j in FINGER_JOINTS:
            pb.resetJointState(self.body, j, finger_opening, physicsClientId=client)
        self.finger_positions = (finger_opening,) * len(FINGER_JOINTS)
        self.set(HOME)
        self._joint2: tuple = (None, None)
        self._filter_self_pairs()
        self.q = HOME.copy()

    @property
    def shoulder(self) -> np.ndarray:
        """The point REACH is measured from.  On a base moved by :meth:`set_base` (a mobile
        robot's) it is 5 cm above joint 2 (pybullet places the base's inertial frame there,
        not its link frame); kept so, as IK's reach check decides stored entries."""
        return self.base_position + np.array([0.0, 0.0, SHOULDER_HEIGHT])

    @property
    def joint2(self) -> np.ndarray:
        """Joint 2's origin where pybullet has the arm now (no joint moves it), read once
        per base pose: the point :func:`wrist_out_of_reach` measures from."""
        key = (self.base_position.tobytes(), self.base_yaw)
        if self._joint2[0] != key:
            at = pb.getLinkState(self.body, 1, computeForwardKinematics=True,
                                 physicsClientId=self.client)[4]
            self._joint2 = (key, np.array(at))
        return self._joint2[1]

    def set_base(self, position, yaw: float = 0.0) -> None:
        """Move the arm's base (a mobile robot carries it around)."""
        self.base_position = np.asarray(position, float)
        self.base_yaw = float(yaw)
        pb.resetBasePositionAndOrientation(self.body, [float(v) for v in position],
                                          yaw_quaternion(yaw), physicsClientId=self.client)

    def _filter_self_pairs(self) -> None:
        c = self.client
        n = pb.getNumJoints(self.body, physicsClientId=c)
        parents = {j: pb.getJointInfo(self.body, j, physicsClientId=c)[16] for j in range(n)}
        pairs = {tuple(sorted((j, p))) for j, p in parents.items()}
        pb.performCollisionDetection(physicsClientId=c)
        for pt in pb.getContactPoints(bodyA=self.body, bodyB=self.body, physicsClientId=c):
            pairs.add(tuple(sorted((pt[3], pt[4]))))
        # the hand and both fingers touch each other whatever the arm does
        pairs |= {(8, 9), (8, 10), (9, 10), (7, 9), (7, 10), (6, 8)}
        self.ignored_pairs = frozenset(pairs)  # the sphere pre-check skips them too
        for a, b in pairs:
            pb.setCollisionFilterPair(self.body, self.body, a, b, 0, physicsClientId=c)

    def set(self, q) -> None:
        pb.resetJointStatesMultiDof(self.body, ARM_JOINTS,
                                    np.asarray(q, float).reshape(-1, 1).tolist(),
                                    physicsClientId=self.client)

    def collides_at(self, q) -> bool:
        self.set(q)
        if self.fresh_contacts:
            return collides_afresh(self.client, self.body, _on_mount)
        pb.performCollisionDetection(physicsClientId=self.client)
        for pt in pb.getContactPoints(bodyA=self.body, physicsClientId=self.client):
            if pt[8] < 0 and pt[3] != -1:
                return True
        return False

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        """The planner's checker: stops at the first colliding configuration."""
        for k, q in enumerate(states):
            if self.collides_at(q):
                return False, k + 1
        return True, len(states)

    def obstacles(self) -> list[int]:
        """Every other body in the client (furniture, boxes, the other arm)."""
        c = self.client
        ids = (pb.getBodyUniqueId(i, physicsClientId=c) for i in
               range(pb.getNumBodies(physicsClientId=c)))
        return [b for b in ids if b != self.body]

    def distance_model(self, query: float):
        """Signed distances to every other body in the client as it is now (the robot
        model's ``distances`` capability): ``q -> distances(q, bodies, query)``."""
        bodies = self.obstacles()
        return lambda q: self.distances(q, bodies, query)

    def certified(self):
        """This arm with sphere-certified checks (the ``certified`` capability); the same
        model while the scene's :attr:`world_key` is (it remembers what it settled)."""
        from pipeline.sim.fast_check import certified_panda

        key = self.world_key() if callable(self.world_key) else None
        if key is None:
            return certified_panda(self)
        if self._certified is None or self._certified[0] != key:
            self._certified = (key, certified_panda(self))
        return self._certified[1]

    def bounded_distance_model(self, query: float):
        """:meth:`distance_model` asking pybullet only about bodies that may be within
        ``query`` (the ``bounded_distances`` capability; the same numbers).  The same
        model while the scene's :attr:`world_key`, the query, the base and the fingers are
        (it reads the bodies and their poses when made: about 2 ms, once per TrajOpt call
        before)."""
        from pipeline.sim.fast_distance import BoundedDistances

        key = self.world_key() if callable(self.world_key) else None
        if key is None:
            return BoundedDistances(self, query)
        key = (key, float(query), self.base_position.tobytes(), self.base_yaw,
               self.finger_positions)
        if self._bounded is None or self._bounded[0] != key:
            self._bounded = (key, BoundedDistances(self, query))
        return self._bounded[1]

    def distances(self, q, bodies, query: float) -> tuple[np.ndarray, np.ndarray]:
        """Signed distances (k,) of the arm's links to ``bodies`` closer than ``query`` at
        ``q``, and their gradients (k, 7): the contact normal (from the obstacle towards
        the arm) times the positional Jacobian of the link at its closest point."""
        c = self.client
        self.set(q)
        points = [pt for b in bodies for pt in pb.getClosestPoints(
            self.body, b, query, physicsClientId=c) if pt[3] != -1]
        if not points:
            return np.zeros(0), np.zeros((0, 7))
        joints = [*map(float, q), *self.finger_positions]
        zeros = [0.0] * len(joints)
        d = np.empty(len(points))
        g = np.empty((len(points), 7))
        frames: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # link -> (com, rotation) at q
        for k, pt in enumerate(points):
            link, on_arm, normal = pt[3], np.asarray(pt[5]), np.asarray(pt[7])
            if link not in frames:
                com, orn = pb.getLinkState(self.body, link, computeForwardKinematics=True,
                                           physicsClientId=c)[:2]
                frames[link] = (np.asarray(com),
                                np.asarray(pb.getMatrixFromQuaternion(orn)).reshape(3, 3))
            com, rot = frames[link]
            local = rot.T @ (on_arm - com)
            linear, _ = pb.calculateJacobian(self.body, link, local.tolist(), joints, zeros,
                                             zeros, physicsClientId=c)
            d[k] = pt[8]
            g[k] = normal @ np.asarray(linear)[:, :7]
        return d, g

    def tcp_pose(self, q) -> tuple[np.ndarray, np.ndarray]:
        self.set(q)
        state = pb.getLinkState(self.body, TCP_LINK, computeForwardKinematics=True,
                                physicsClientId=self.client)
        return np.array(state[4]), np.array(state[5])

    def ik(self, position, orientation, starts, pos_tol: float = IK_POS_TOL,
           ang_tol: float = IK_ANG_TOL, collides=None) -> tuple[np.ndarray | None, int, bool]:
        """(a collision-free joint solution reaching the TCP pose or None, the collision
        checks used, whether any solution reached the pose).  One damped IK run from each
        configuration ``starts`` yields (an iterable, drawn from only as far as needed),
        until one gives a collision-free solution.  ``collides(q)`` is the check (default:
        this arm's own)."""
        collides = collides or self.collides_at
        checks = 0
        target, turn = list(position), list(orientation)
        for start in starts:
            self.set(start)
            sol = pb.calculateInverseKinematics(
                self.body, TCP_LINK, target, turn, lowerLimits=_LOWER, upperLimits=_UPPER,
                jointRanges=_RANGES, restPoses=list(start), jointDamping=_DAMPING,
                maxNumIterations=50, residualThreshold=1e-5, physicsClientId=self.client)
            q = np.array(sol[:7])
            if ((q < LOWER) | (q > UPPER)).any():
                continue
            pos, orn = self.tcp_pose(q)
            if np.linalg.norm(pos - position) > pos_tol or _angle(orn, orientation) > ang_tol:
                continue
            checks += 1
            if not collides(q):
                return q, checks, True
        return None, checks, checks > 0

    def analytic_ik(self, position, orientation, tries: int,
                    collides=None) -> tuple[np.ndarray | None, int, bool]:
        """What :meth:`ik` returns, from frankik's closed-form solutions instead of damped
        IK: at most ``tries`` of them collision-checked (:mod:`pipeline.sim.analytic_ik`)."""
        from pipeline.sim import analytic_ik

        return analytic_ik.solve(self, position, orientation, tries,
                                 collides or self.collides_at)


def wrist_out_of_reach(shoulder, position, orientation, pos_tol: float = IK_POS_TOL,
                       ang_tol: float = IK_ANG_TOL) -> bool:
    """True when no configuration at all (any joint values) puts the TCP within ``pos_tol``
    and ``ang_tol`` of ``position``/``orientation`` (x, y, z, w), for an arm whose joint 2
    is at ``shoulder`` (:attr:`Panda.joint2`): then every IK, damped or analytic, finds
    nothing it accepts.

    Why it is safe: a configuration whose TCP is within the tolerances has its wrist point
    within pos_tol + 2 sin(ang_tol / 2) |w| of the pose's wrist circle (w: the wrist point in
    the TCP's frame, the same vector for both, since it depends on joint 7 only), and its
    wrist point within WRIST_REACH of the shoulder; so a circle further than their sum (and
    a millimetre for rounding) from the shoulder cannot be met.  Cheap: a few flops, against
    about 1.2 ms for damped IK's restarts on a pose none of them reaches."""
    axis = np.array(pb.getMatrixFromQuaternion(list(orientation))[2::3])  # the TCP's z axis
    centre = np.asarray(position, float) - WRIST_BACK * axis
    v = np.asarray(shoulder, float) - centre
    along = float(v @ axis)
    across = float(np.linalg.norm(v - along * axis))
    gap = float(np.hypot(along, across - WRIST_RADIUS))  # the shoulder to the nearest point
    slack = pos_tol + 2.0 * np.sin(ang_tol / 2.0) * float(np.hypot(WRIST_BACK, WRIST_RADIUS))
    return gap > WRIST_REACH + slack + 1e-3


def _on_mount(pt) -> bool:
    """A contact of the arm's base link (with the stand it is mounted on): not a collision."""
    return pt[3] == -1


def ik_starts(rng_seed, restarts: int):
    """The starts of IK's restarts: home, then :func:`random_starts` (``restarts - 1`` of
    them)."""
    if restarts < 1:
        return
    yield HOME
    yield from random_starts(rng_seed, restarts - 1)


def random_starts(rng_seed, count: int):
    """``count`` configurations drawn uniformly within the limits from
    ``numpy.random.default_rng(rng_seed)``, made at the first draw (making a Generator costs
    more than many IK calls that succeed from home)."""
    if count > 0:
        rng = np.random.default_rng(rng_seed)
        for _ in range(count):
            yield rng.uniform(LOWER, UPPER)


_LOWER, _UPPER, _RANGES = list(LOWER), list(UPPER), list(UPPER - LOWER)
_DAMPING = [0.005] * 9


def _angle(q1, q2) -> float:
    """Angle between two unit quaternions (x, y, z, w), radians."""
    d = abs(float(np.dot(q1, q2)))
    return 2.0 * float(np.arccos(min(1.0, d)))
