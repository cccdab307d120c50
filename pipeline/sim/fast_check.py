"""Sphere-certified collision checking: the exact checker's answers, most of them without
pybullet.

A checker here has the exact checker's contract, ``check(states) -> (ok, used)``: it
checks the rows in order, stops at the first colliding one and says how many it
checked.  It first runs the compiled pre-check (:mod:`pipeline.sim.collide`) on all rows
at once.  The robot's spheres cover its collision geometry, so a row the pre-check clears
is collision-free for pybullet too; the other rows are confirmed with the exact check, in
order, and the first confirmed collision ends the call.  A row where a box the robot
carries (its platform, a held object) or a sphere inside one of its link hulls reaches
``PROOF_DEPTH`` into a box of the world needs no confirmation: the robot's real geometry
holds that box or sphere, so that row is a proven collision.  Hence the answer *and the
count* equal the exact checker's: planners take the same branches and find the same
paths, and stored entries replay under either setting.

The world is read from the pybullet client when a checker is made (boxes as oriented
boxes, other Pandas as spheres at their joint states) and assumed fixed while it is used:
make one checker per planning call, after the scene is set.  A world with anything else
in it (a mesh, an unknown robot) is not certified: every row goes to the exact check.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from pipeline.planning.base import Robot
from pipeline.sim import collide, spheres, wrist

#: extra radius (metres) of the robot's spheres and of other robots' spheres: pybullet
#: collides meshes as their convex hulls grown by its collision margin (1 mm; measured
#: distances are up to 0.9 mm below the hulls'), plus rounding
MARGIN = 0.0025
#: extra clearance (metres) on the boxes that ride on the robot (platform, held object)
BOX_MARGIN = 0.0025
#: how deep a robot box must reach into a world box for the pair to be a proven collision
#: (pybullet's box-against-box contacts are exact; this leaves room for rounding)
PROOF_DEPTH = 0.001
#: base motions: parts of the robot at least this far apart stay apart (pybullet's
#: distances of rigidly moved parts agree far below this)
INTERNAL_CLEARANCE = 1e-4


def _matrices(quaternions: np.ndarray) -> np.ndarray:
    """Rotation matrices (K, 3, 3) of unit quaternions (K, 4), pybullet's (x, y, z, w)."""
    x, y, z, w = quaternions.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], 1)


def _frame(position, orientation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(pb.getMatrixFromQuaternion(orientation)).reshape(3, 3)
    T[:3, 3] = position
    return T


def base_link_frame(client: int, body: int) -> np.ndarray:
    """The URDF frame of ``body``'s base link (pybullet reports its inertial frame)."""
    com = _frame(*pb.getBasePositionAndOrientation(body, physicsClientId=client))
    inertial = _frame(*pb.getDynamicsInfo(body, -1, physicsClientId=client)[3:5])
    return com @ np.linalg.inv(inertial)


def _box_of(client: int, body: int):
    """(4 × 4 pose, half extents) of a single-box body, or None for anything else."""
    if pb.getNumJoints(body, physicsClientId=client):
        return None
    shapes = pb.getCollisionShapeData(body, -1, physicsClientId=client)
    if len(shapes) != 1 or shapes[0][2] != pb.GEOM_BOX:
        return None
    _, _, _, extents, _, pos, orn = shapes[0]
    T = _frame(*pb.getBasePositionAndOrientation(body, physicsClientId=client)) @ _frame(pos, orn)
    return T, np.asarray(extents, float) / 2


def _is_panda(client: int, body: int) -> bool:
    name = pb.getBodyInfo(body, physicsClientId=client)[0]
    return name == spheres.panda_chain().base_name.encode()


def arm_state(client: int, body: int) -> np.ndarray:
    states = pb.getJointStates(body, range(7), physicsClientId=client)
    return np.array([s[0] for s in states])


@dataclass
class World:
    """What the robot can hit: boxes and spheres, in world coordinates."""

    box_c: np.ndarray
    box_R: np.ndarray
    box_h: np.ndarray
    sph_c: np.ndarray
    sph_r: np.ndarray
    bodies: list  # the body of each box
    og_lo: np.ndarray | None = None  # sphere groups (one per link of another robot):
    og_hi: np.ndarray | None = None  # obs spheres og_lo[k]:og_hi[k], with a bounding
    og_c: np.ndarray | None = None  # sphere (og_c, og_r)
    og_r: np.ndarray | None = None

    def __post_init__(self):
        self.box_r = np.linalg.norm(self.box_h, axis=1)
        if self.og_lo is None:  # one group per sphere
            n = len(self.sph_r)
            self.og_lo, self.og_hi = np.arange(n), np.arange(1, n + 1)
            self.og_c, self.og_r = self.sph_c.copy(), self.sph_r.copy()

    @classmethod
    def read(cls, client: int, skip) -> World | None:
        """Every body of ``client`` but those in ``skip``; None when one is neither a box
        nor a Panda."""
        boxes, halves, bodies, centres, radii = [], [], [], [np.zeros((0, 3))], [np.zeros(0)]
        groups = []
        for i in range(pb.getNumBodies(physicsClientId=client)):
            body = pb.getBodyUniqueId(i, physicsClientId=client)
            if body in skip:
                continue
            shapes = pb.getCollisionShapeData(body, -1, physicsClientId=client)
            if (len(shapes) == 1 and shapes[0][2] == pb.GEOM_BOX
                    and not pb.getNumJoints(body, physicsClientId=client)):
                boxes.append((*pb.getBasePositionAndOrientation(body, physicsClientId=client),
                              shapes[0][5], shapes[0][6]))
                halves.append(shapes[0][3])
                bodies.append(body)
            elif _is_panda(client, body):
                c, r, parts = _panda_obstacle(tuple(arm_state(client, body)),
                                              tuple(base_link_frame(client, body)[:3].ravel()))
                first = sum(len(r) for r in radii)
                groups += [(first + lo, first + hi, gc, gr) for lo, hi, gc, gr in parts]
                centres.append(c)
                radii.append(r)
            else:
                return None
        R = _matrices(np.array([b[1] for b in boxes]).reshape(-1, 4))
        t = np.array([b[0] for b in boxes], float).reshape(-1, 3)
        for k, (_, _, pos, orn) in enumerate(boxes):  # shapes off their body's frame
            if any(pos) or tuple(orn) != (0.0, 0.0, 0.0, 1.0):
                T = _frame(*boxes[k][:2]) @ _frame(pos, orn)
                R[k], t[k] = T[:3, :3], T[:3, 3]
        return cls(t, R, np.array(halves, float).reshape(-1, 3) / 2, np.concatenate(centres),
                   np.concatenate(radii), bodies,
                   np.array([g[0] for g in groups], dtype=np.int64),
                   np.array([g[1] for g in groups], dtype=np.int64),
                   np.array([g[2] for g in groups]).reshape(-1, 3),
                   np.array([g[3] for g in groups]))


@functools.lru_cache(maxsize=16)
def _panda_obstacle(q: tuple, base: tuple):
    """Another Panda (joint state ``q``, base link frame ``base``: 3 × 4, flattened) as
    obstacle spheres: (centres, radii, per link (first, end, bounding centre and
    radius)).  Remembered: the other arm of a scene stands still between planning calls."""
    model = spheres.panda_spheres(MARGIN)
    frame = np.vstack([np.reshape(base, (3, 4)), [0.0, 0.0, 0.0, 1.0]])
    c = model.world(_arm_frames_fn(frame)(np.array([q])))[0]
    parts = []
    for link in spheres.LINKS:
        idx = np.flatnonzero(model.links == link)
        parts.append((idx[0], idx[-1] + 1, *_bounding(c[idx], model.radii[idx])))
    return c, model.radii, tuple(parts)


def _bounding(centres: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, float]:
    """A sphere holding the spheres (centres, radii)."""
    centre = (centres.min(axis=0) + centres.max(axis=0)) / 2
    return centre, float(np.max(np.linalg.norm(centres - centre, axis=1) + radii))


@dataclass
class SphereRobot:
    """Sphere groups (each on one frame) and boxes (each on one frame) of a robot."""

    grp_frame: np.ndarray
    grp_c: np.ndarray
    grp_r: np.ndarray
    grp_lo: np.ndarray
    grp_hi: np.ndarray
    grp_world: np.ndarray
    sph_c: np.ndarray
    sph_r: np.ndarray
    pair_a: np.ndarray
    pair_b: np.ndarray
    rbox_frame: np.ndarray
    rbox_T: np.ndarray
    rbox_h: np.ndarray
    rbox_pair_b: np.ndarray  # robot box rbox_pair_b[k] is tested against group
    rbox_pair_g: np.ndarray  # rbox_pair_g[k]
    rbox_solid: np.ndarray  # the robot boxes' true half extents (rbox_h has the margin)
    in_frame: np.ndarray  # inner spheres (inside the collision hulls): frame,
    in_c: np.ndarray  # centre in that frame,
    in_r: np.ndarray  # radius

    def __post_init__(self):
        self.rbox_r = np.linalg.norm(self.rbox_h, axis=1)

    @classmethod
    def build(cls, groups, pairs=(), boxes=(), box_pairs=(), inner=None) -> SphereRobot:
        """``groups``: (frame, centres (K, 3), radii (K,), tested against the world);
        ``pairs``: group index pairs tested against each other; ``boxes``: (frame,
        4 × 4 pose in it, true half extents; tested with BOX_MARGIN added);
        ``box_pairs``: (box, group) tested against each other; ``inner``: (frames,
        centres, radii) of spheres inside the robot's collision geometry, or None."""
        groups = list(groups) or [(0, np.zeros((1, 3)), np.array([-1.0]), False)]
        lo = np.cumsum([0] + [len(g[2]) for g in groups])
        bounds = [_bounding(c, r) for _, c, r, _ in groups]
        gc, gr = [b[0] for b in bounds], [b[1] for b in bounds]
        pa = np.array([p[0] for p in pairs], dtype=np.int64)
        pbb = np.array([p[1] for p in pairs], dtype=np.int64)
        return cls(np.array([g[0] for g in groups], dtype=np.int64), np.array(gc),
                   np.array(gr), lo[:-1].astype(np.int64), lo[1:].astype(np.int64),
                   np.array([g[3] for g in groups], dtype=np.bool_),
                   np.concatenate([g[1] for g in groups]), np.concatenate([g[2] for g in groups]),
                   pa, pbb, np.array([b[0] for b in boxes], dtype=np.int64),
                   np.array([b[1][:3] for b in boxes]).reshape(-1, 3, 4),
                   np.array([b[2] for b in boxes]).reshape(-1, 3) + BOX_MARGIN,
                   np.array([p[0] for p in box_pairs], dtype=np.int64),
                   np.array([p[1] for p in box_pairs], dtype=np.int64),
                   np.array([b[2] for b in boxes], float).reshape(-1, 3),
                   *_inner_arrays(inner))

    def first(self, frames: np.ndarray, world: World, start: int = 0,
              pre: np.ndarray | None = None) -> int:
        """The first row >= ``start`` of ``frames`` (N, F, 3, 4) that may collide (or
        marked in ``pre``), N when none may."""
        if pre is None:
            pre = np.zeros(len(frames), dtype=np.bool_)
        return int(collide.first_uncertain(
            frames, start, pre, self.grp_frame, self.grp_c, self.grp_r, self.grp_lo,
            self.grp_hi, self.grp_world, self.sph_c, self.sph_r, self.pair_a, self.pair_b,
            self.rbox_frame, self.rbox_T, self.rbox_h, self.rbox_r, self.rbox_pair_b,
            self.rbox_pair_g,
            world.box_c, world.box_R, world.box_h, world.box_r, world.og_c, world.og_r,
            world.og_lo, world.og_hi, world.sph_c, world.sph_r))

    def surely_hits(self, frames: np.ndarray, n: int, world: World) -> bool:
        """Does row n of ``frames`` certainly collide (a robot box or an inner sphere deep
        in a world box)?"""
        if not len(world.box_c):
            return False
        boxes = (world.box_c, world.box_R, world.box_h, world.box_r, PROOF_DEPTH)
        return bool(
            (len(self.in_r) and collide.sphere_hit(frames, n, self.in_frame, self.in_c,
                                                   self.in_r, *boxes))
            or (len(self.rbox_solid) and collide.box_hit(
                frames, n, self.rbox_frame, self.rbox_T, self.rbox_solid, *boxes)))

    def uncertain(self, frames: np.ndarray, world: World,
                  pre: np.ndarray | None = None) -> np.ndarray:
        """(N,) whether each row may collide."""
        out = np.zeros(len(frames), dtype=bool)
        k = self.first(frames, world, 0, pre)
        while k < len(frames):
            out[k] = True
            k = self.first(frames, world, k + 1, pre)
        return out


def _inner_arrays(inner) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if inner is None:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0)
    frames, centres, radii = inner
    return (np.asarray(frames, dtype=np.int64), np.asarray(centres, float).reshape(-1, 3),
            np.asarray(radii, float))


def panda_inner():
    """The Panda's inner spheres (:func:`pipeline.sim.spheres.panda_inner_spheres`) as
    SphereRobot.build's ``inner``."""
    model = spheres.panda_inner_spheres()
    return model.frames, model.centres, model.radii


def panda_groups(model: spheres.SphereModel, frame_of=None):
    """One group per link: (frame, centres, radii, world?) and the group index of each
    link.  The base link's contacts are not collisions for the exact check (it stands on
    its mount), so its group is not tested against the world."""
    groups, index = [], {}
    for link in spheres.LINKS:
        m = model.links == link
        frame = spheres.FRAME_OF_LINK[link] if frame_of is None else frame_of
        index[link] = len(groups)
        groups.append((frame, model.centres[m], model.radii[m], link != -1))
    return groups, index


def self_pairs(index: dict, ignored) -> list[tuple[int, int]]:
    """Group pairs of the links pybullet checks against each other (all pairs but the
    ``ignored`` ones, which the arm filters)."""
    links = sorted(index)
    return [(index[a], index[b]) for i, a in enumerate(links) for b in links[i + 1:]
            if (a, b) not in ignored and (b, a) not in ignored]


class SphereChecker:
    """``check(states) -> (ok, used)`` with the exact checker's answers (module docstring).

    ``frames(states)`` gives the robot's frames per row; ``exact(row)`` is the exact
    check of one row (True: collides); ``certified`` False sends every row to ``exact``.
    """

    def __init__(self, robot: SphereRobot | None, world: World | None, frames: Callable,
                 exact: Callable[[np.ndarray], bool], certified: bool = True,
                 also: Callable[[np.ndarray], np.ndarray] | None = None):
        self.robot, self.world, self.frames, self.exact = robot, world, frames, exact
        self.certified = certified and robot is not None and world is not None
        self.also = also  # more rows to send to ``exact`` (say, the wrist table's)
        self.stats = {"rows": 0, "exact": 0, "proved": 0}

    def _pre(self, states: np.ndarray) -> np.ndarray:
        if self.also is None:
            return np.zeros(len(states), dtype=np.bool_)
        return self.also(states)

    def uncertain(self, states: np.ndarray) -> np.ndarray:
        """(N,) whether each row needs the exact check."""
        if not self.certified:
            return np.ones(len(states), dtype=bool)
        states = np.ascontiguousarray(states, float)
        return self.robot.uncertain(self.frames(states), self.world, self._pre(states))

    def __call__(self, states: np.ndarray) -> tuple[bool, int]:
        states = np.atleast_2d(states)
        n = len(states)
        self.stats["rows"] += n
        if not self.certified:
            for k in range(n):
                self.stats["exact"] += 1
                if self.exact(states[k]):
                    return False, k + 1
            return True, n
        states = np.ascontiguousarray(states, float)
        frames, pre = self.frames(states), self._pre(states)
        k = self.robot.first(frames, self.world, 0, pre)
        while k < n:
            if self.robot.surely_hits(frames, k, self.world):
                self.stats["proved"] += 1
                return False, k + 1
            self.stats["exact"] += 1
            if self.exact(states[k]):
                return False, k + 1
            k = self.robot.first(frames, self.world, k + 1, pre)
        return True, n


def _arm_frames_fn(base: np.ndarray):
    base34 = np.ascontiguousarray(base[:3])
    origins = np.ascontiguousarray(spheres.panda_chain().origins[:7, :3])

    def frames(states):
        out = np.empty((len(states), 8, 3, 4))
        collide.arm_frames(states, base34, origins, out)
        return out
    return frames


def _held_box(client: int, held: int, rel: np.ndarray, frame: int):
    """The box body ``held`` whose pose in robot frame ``frame`` is ``rel`` (4 × 4), as a
    robot box (frame, pose, half extents), or None when it is not one box."""
    if pb.getNumJoints(held, physicsClientId=client):
        return None
    shapes = pb.getCollisionShapeData(held, -1, physicsClientId=client)
    if len(shapes) != 1 or shapes[0][2] != pb.GEOM_BOX:
        return None
    T = rel @ _frame(shapes[0][5], shapes[0][6])
    return frame, T, np.asarray(shapes[0][3], float) / 2


def wrist_table(ignored_pairs) -> wrist.WristTable:
    from pipeline.sim import panda as P

    return wrist.wrist_table(frozenset(ignored_pairs), P.LOWER[5], P.UPPER[5], P.LOWER[6],
                             P.UPPER[6])


@functools.lru_cache(maxsize=8)
def _panda_parts(ignored: frozenset):
    """(groups, group index of each link, self pairs) of a Panda whose filtered link pairs
    are ``ignored``; the wrist's own pairs are left to :mod:`pipeline.sim.wrist`."""
    groups, index = panda_groups(spheres.panda_spheres(MARGIN))
    return tuple(groups), index, tuple(self_pairs(index, set(ignored) | set(wrist.PAIRS)))


@functools.lru_cache(maxsize=8)
def _panda_robot(ignored: frozenset) -> SphereRobot:
    groups, _, pairs = _panda_parts(ignored)
    return SphereRobot.build(groups, pairs, inner=panda_inner())


def _arm_robot(client: int, arm_body: int, ignored_pairs, held, hand_links):
    """(Robot of the arm and its held box, frames function, whether the held box could be
    modelled).  ``held``: None or (body, its pose in the frame of link 6, 4 × 4)."""
    ignored = frozenset(ignored_pairs)
    frames = _arm_frames_fn(base_link_frame(client, arm_body))
    if held is None:
        return _panda_robot(ignored), frames, True
    groups, index, pairs = _panda_parts(ignored)
    box = _held_box(client, held[0], held[1], spheres.FRAME_OF_LINK[6])
    if box is None:
        return None, frames, False
    arm_links = [(0, index[link]) for link in index if link not in hand_links]
    return (SphereRobot.build(groups, pairs, boxes=[box], box_pairs=arm_links,
                              inner=panda_inner()), frames, True)


def arm_checker(client: int, arm_body: int, ignored_pairs, exact, *, held=None,
                hand_links=frozenset(), fixed_robot=()) -> SphereChecker:
    """Checker for arm motions with the base fixed.

    ``ignored_pairs``: the arm's link pairs pybullet does not check; ``held``: (body, pose
    in the frame of link 6) of a box carried rigidly by the hand (its contacts with
    ``hand_links`` are the grasp); ``fixed_robot``: bodies of the same robot that do not
    move (a platform): the arm and the held box must not touch them, and they must not
    touch the world.
    """
    robot, frames, ok = _arm_robot(client, arm_body, ignored_pairs, held, hand_links)
    world = World.read(client, {arm_body} | ({held[0]} if held is not None else set()))
    certified = ok and world is not None
    if certified and fixed_robot:
        # a fixed part of the robot is a box of the world, and must not touch the rest of
        # the world (pybullet would report a collision for every row): asked once, exactly
        robot_bodies = {arm_body, *fixed_robot} | ({held[0]} if held is not None else set())
        certified = all(body in world.bodies for body in fixed_robot) and not any(
            _touches_world(client, body, robot_bodies) for body in fixed_robot)
    table = wrist_table(ignored_pairs)
    return SphereChecker(robot, world, frames, exact, certified, also=table.uncertain)


def base_checker(client: int, arm_body: int, platform: int, base_pose: np.ndarray,
                 psi_scale: float, exact, internal_free: bool, *, held=None) -> SphereChecker:
    """Checker for base motions (x, y, psi_scale · ψ) of a mobile arm, arm fixed.

    ``base_pose`` is the base's current 4 × 4 transform (its frame: on the floor under the
    platform's centre); the arm and the platform keep their poses in it.  ``held``: None or
    (body, pose in the base frame) of the carried box.  Contacts within the robot do not
    change while the base moves: ``internal_free`` says the caller ruled them out at the
    current state (else every row goes to ``exact``).
    """
    box = _box_of(client, platform)
    if not internal_free or box is None:
        return SphereChecker(None, None, None, exact, certified=False)
    to_base = np.linalg.inv(base_pose)
    model = spheres.panda_spheres(MARGIN)
    arm = spheres.arm_frames(arm_state(client, arm_body)[None], base_link_frame(client, arm_body))
    centres = model.world(arm)[0] @ to_base[:3, :3].T + to_base[:3, 3]
    groups = [(0, centres[model.links == link], model.radii[model.links == link], link != -1)
              for link in spheres.LINKS]
    boxes = [(0, to_base @ box[0], box[1])]
    if held is not None:
        box = _held_box(client, held[0], held[1], 0)
        if box is None:
            return SphereChecker(None, None, None, exact, certified=False)
        boxes.append(box)
    robot = SphereRobot.build(groups, boxes=boxes)
    world = World.read(client, {arm_body, platform} | ({held[0]} if held is not None else set()))

    def base_frames(states):
        out = np.empty((len(states), 1, 3, 4))
        collide.planar_frames(states, psi_scale, out)
        return out
    return SphereChecker(robot, world, base_frames, exact)


def _touches_world(client: int, body: int, robot_bodies) -> bool:
    pb.performCollisionDetection(physicsClientId=client)
    return any(p[8] < 0 and p[2] not in robot_bodies
               for p in pb.getContactPoints(bodyA=body, physicsClientId=client))


def internal_clearance(robot) -> float:
    """The smallest distance between parts of a MobilePanda that pybullet checks against
    each other (arm links, platform, held object), at its current state; pybullet's own
    query, since these parts are often closer than spheres can resolve."""
    c, arm, plat, held = robot.client, robot.body, robot.platform, robot.held
    ignored = robot.arm.ignored_pairs
    out = np.inf
    for p in pb.getClosestPoints(arm, arm, 0.05, physicsClientId=c):
        if p[3] != p[4] and (p[3], p[4]) not in ignored and (p[4], p[3]) not in ignored:
            out = min(out, p[8])
    for p in pb.getClosestPoints(arm, plat, 0.05, physicsClientId=c):
        if p[3] != -1:
            out = min(out, p[8])
    if held is not None:
        for other in (arm, plat):
            for p in pb.getClosestPoints(held, other, 0.05, physicsClientId=c):
                if not (other == arm and p[4] in robot.hand_links):
                    out = min(out, p[8])
    return out


class CertifiedRobot(Robot):
    """A robot model whose ``check`` is a :class:`SphereChecker` of ``model``'s (same
    answers and counts); the rest of the model is ``model``'s."""

    def __init__(self, model, checker: SphereChecker):
        self.model, self.checker = model, checker
        self.lower, self.upper = model.lower, model.upper
        self.description = model.description

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        return self.checker(states)

    def __getattr__(self, name):  # optional capabilities (distance_model) are the model's
        return getattr(self.model, name)


def certified(model):
    """``model`` (a robot model) with sphere-certified checks, or ``model`` itself when it
    is not one this module knows.  Call it when a planning call starts: the world is read
    now."""
    from pipeline.sim.mobile import MobileArm, MobileBase
    from pipeline.sim.panda import Panda

    if isinstance(model, Panda):
        checker = arm_checker(model.client, model.body, model.ignored_pairs, model.collides_at)
    elif isinstance(model, MobileArm):
        r = model.robot
        checker = arm_checker(r.client, r.body, r.arm.ignored_pairs, r.arm_collides,
                              held=_held(r, hand=True), hand_links=r.hand_links,
                              fixed_robot=(r.platform,))
    elif isinstance(model, MobileBase):
        r = model.robot
        r.set_base(r.pose)  # the held object where base checks will put it
        checker = base_checker(r.client, r.body, r.platform, r.base_frame(), model.psi_scale,
                               model.collides, internal_clearance(r) > INTERNAL_CLEARANCE,
                               held=_held(r, hand=False))
    else:
        return model
    return CertifiedRobot(model, checker)


def _held(robot, hand: bool):
    """(body, pose in the frame of link 6 (``hand``) or of the base) of what a MobilePanda
    holds; None when it holds nothing."""
    if robot.held is None:
        return None
    if hand:
        return robot.held, spheres.fixed_offsets()[spheres.TCP_LINK] @ robot.held_in_tcp
    return robot.held, robot.held_in_base
