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
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from pipeline.planning.base import Robot, check_order, interpolate
from pipeline.sim import collide, compiled_rrt, contacts, spheres, wrist

#: extra radius (metres) of the robot's spheres and of other robots' spheres: pybullet
#: collides meshes as their convex hulls grown by its collision margin (1 mm; measured
#: distances are up to 0.9 mm below the hulls'), plus rounding
MARGIN = 0.0025
#: extra clearance (metres) on the boxes that ride on the robot (platform, held object)
BOX_MARGIN = 0.0025
#: how deep a robot box must reach into a world box for the pair to be a proven collision
#: (pybullet's box-against-box contacts are exact; this leaves room for rounding)
PROOF_DEPTH = 0.001
#: where spheres touch, the covered geometry decides (:func:`pipeline.sim.collide._apart`):
#: a link's convex hull must be this far from a world box (the spheres' own margin: pybullet
#: collides a hull grown by its 1 mm margin), from a box the robot carries (1 mm more for the
#: box's pose, which pybullet places from its own kinematics) and from another link's hull
#: (both links' margins); a box the robot carries must be this far from a world box along
#: a face normal (pybullet tests box against box exactly, face axes with no tolerance;
#: this leaves room for its kinematics, which agree with :mod:`pipeline.sim.spheres` to
#: about 1e-7 m)
HULL_GAP = MARGIN
CARRIED_GAP = MARGIN + 0.001
BOX_GAP = 1e-4
GAPS = np.array([HULL_GAP, CARRIED_GAP, 2 * HULL_GAP, BOX_GAP])
#: base motions: parts of the robot at least this far apart stay apart (pybullet's
#: distances of rigidly moved parts agree far below this)
INTERNAL_CLEARANCE = 1e-4


_NO_CELLS = np.ones((1, 1), dtype=np.int8)


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
    og_hull: np.ndarray | None = None  # the convex hull of what group k's spheres cover:
    og_hlo: np.ndarray | None = None  # og_hull[og_hlo[k]:og_hhi[k]] (world coordinates;
    og_hhi: np.ndarray | None = None  # an empty range: none known), and spheres inside
    oin_c: np.ndarray | None = None  # it: oin_c[og_ilo[k]:og_ihi[k]], oin_r[...]
    oin_r: np.ndarray | None = None
    og_ilo: np.ndarray | None = None
    og_ihi: np.ndarray | None = None

    def __post_init__(self):
        self.box_r = np.linalg.norm(self.box_h, axis=1)
        self.box_e = np.ascontiguousarray(np.einsum("bij,bj->bi", np.abs(self.box_R),
                                                    self.box_h))  # axis-aligned extents
        self._pack = None
        if self.og_lo is None:  # one group per sphere
            n = len(self.sph_r)
            self.og_lo, self.og_hi = np.arange(n), np.arange(1, n + 1)
            self.og_c, self.og_r = self.sph_c.copy(), self.sph_r.copy()
        if self.og_hull is None:  # no hulls
            self.og_hull = np.zeros((0, 3))
            self.og_hlo = self.og_hhi = np.zeros(len(self.og_lo), dtype=np.int64)
        if self.oin_c is None:  # no inner spheres
            self.oin_c, self.oin_r = np.zeros((0, 3)), np.zeros(0)
            self.og_ilo = self.og_ihi = np.zeros(len(self.og_lo), dtype=np.int64)
        # one sphere holding every group's (a first test for them all; none: radius -inf)
        self.og_all = np.array([0.0, 0.0, 0.0, -np.inf])
        if len(self.og_r):
            centre, radius = _bounding(self.og_c, self.og_r)
            self.og_all = np.array([*centre, radius])

    @classmethod
    def read(cls, client: int, skip, only=None, hulls: bool = True) -> World | None:
        """Every body of ``client`` but those in ``skip`` (or the bodies ``only``); None
        when one is neither a box nor a Panda.  ``hulls``: with another Panda's link hulls
        and the spheres inside them (:data:`og_hull`, :data:`oin_c`), which let the scan
        clear rows and prove collisions without asking pybullet; only where pybullet's
        answers do not depend on what it was asked before (docs/contacts.md): under
        cached contacts a check left out could change a later one."""
        boxes, halves, bodies, centres, radii = [], [], [], [np.zeros((0, 3))], [np.zeros(0)]
        groups, vertices, inner = [], [np.zeros((0, 3))], [(np.zeros((0, 3)), np.zeros(0))]
        if only is None:
            only = [pb.getBodyUniqueId(i, physicsClientId=client)
                    for i in range(pb.getNumBodies(physicsClientId=client))]
        for body in only:
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
                if hulls:
                    verts, ends, ic, ir, iends = _panda_obstacle_solids(
                        tuple(arm_state(client, body)),
                        tuple(base_link_frame(client, body)[:3].ravel()))
                    at, iat = sum(len(h) for h in vertices), sum(len(r) for _, r in inner)
                    vertices.append(verts)
                    inner.append((ic, ir))
                else:
                    at = iat = 0
                    ends = iends = [(0, 0)] * len(parts)
                groups[-len(parts):] = [
                    (*g, at + lo, at + hi, iat + ilo, iat + ihi)
                    for g, (lo, hi), (ilo, ihi) in zip(groups[-len(parts):], ends, iends,
                                                       strict=True)]
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
                   np.array([g[3] for g in groups]), np.concatenate(vertices),
                   np.array([g[4] for g in groups], dtype=np.int64),
                   np.array([g[5] for g in groups], dtype=np.int64),
                   np.concatenate([c for c, _ in inner]), np.concatenate([r for _, r in inner]),
                   np.array([g[6] for g in groups], dtype=np.int64),
                   np.array([g[7] for g in groups], dtype=np.int64))


    def packed(self) -> tuple:
        """The world's arrays as :func:`pipeline.sim.collide.pack` lays them out (once)."""
        if self._pack is None:
            self._pack = collide.pack(dict(
                box_c=self.box_c, box_R=self.box_R, box_h=self.box_h, box_r=self.box_r,
                box_e=self.box_e, og_c=self.og_c, og_r=self.og_r, og_lo=self.og_lo,
                og_hi=self.og_hi, obs_c=self.sph_c, obs_r=self.sph_r, og_hlo=self.og_hlo,
                og_hhi=self.og_hhi, og_hull=self.og_hull, og_ilo=self.og_ilo,
                og_ihi=self.og_ihi, oin_c=self.oin_c, oin_r=self.oin_r, og_all=self.og_all),
                collide.WORLD_PACK)
        return self._pack

    def join(self, other: World) -> World | None:
        """This world and ``other``'s boxes (None when ``other`` has spheres too)."""
        if len(other.sph_r):
            return None
        return World(np.concatenate([self.box_c, other.box_c]),
                     np.concatenate([self.box_R, other.box_R]),
                     np.concatenate([self.box_h, other.box_h]), self.sph_c, self.sph_r,
                     self.bodies + other.bodies, self.og_lo, self.og_hi, self.og_c, self.og_r,
                     self.og_hull, self.og_hlo, self.og_hhi, self.oin_c, self.oin_r,
                     self.og_ilo, self.og_ihi)


class Memo:
    """A small least-recently-used memo: ``get(key, make)`` is the value kept for ``key``,
    or ``make()``, kept; beyond ``size`` keys the least recently used goes."""

    def __init__(self, size: int):
        self.size, self.items = size, OrderedDict()

    def get(self, key, make):
        if key in self.items:
            self.items.move_to_end(key)
            return self.items[key]
        value = self.items[key] = make()
        while len(self.items) > self.size:
            self.items.popitem(last=False)
        return value


#: worlds read under a scene's ``world_key`` (what is not the robot, as it stands), the
#: robot models made from a robot's state, and the internal clearances measured for them
_WORLDS, _ROBOTS, _CLEARANCES = Memo(64), Memo(512), Memo(512)


def _key_of(array, digits: int = 9) -> bytes:
    """A memo key for an array of poses or joint values: rounded, so that the same state
    reached along two ways gives one key (nothing here needs better than 1e-9 m or rad:
    every test keeps a margin of at least 1e-4 m)."""
    return np.round(np.asarray(array, float), digits).tobytes()


def read_world(client: int, skip, key=None, moving=(), hulls: bool = True) -> World | None:
    """:meth:`World.read` of every body but ``skip``.  With a ``key`` (a scene's promise:
    the same key, the same bodies at the same poses, apart from ``skip`` and ``moving``),
    the world is read once per key; the bodies ``moving`` (parts of the robot that the
    world must include, such as a platform standing still under a moving arm) are read
    every time.  ``hulls``: see :meth:`World.read`."""
    if key is None:
        return World.read(client, skip, hulls=hulls)
    static_key = (client, frozenset(skip) | frozenset(moving), key, hulls)
    static = _WORLDS.get(static_key, lambda: World.read(client, set(skip) | set(moving),
                                                        hulls=hulls))
    if static is None or not moving:
        return static

    def joined():
        more = World.read(client, (), only=moving)
        return None if more is None else static.join(more)
    return _WORLDS.get((static_key, _poses(client, moving)), joined)


def _poses(client: int, bodies) -> tuple:
    """Where ``bodies`` are (part of a memo key)."""
    return tuple(pb.getBasePositionAndOrientation(b, physicsClientId=client) for b in bodies)


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


@functools.lru_cache(maxsize=16)
def _panda_obstacle_solids(q: tuple, base: tuple) -> tuple:
    """The links' collision hulls (:func:`pipeline.sim.spheres.panda_hulls`) and inner
    spheres (:func:`pipeline.sim.spheres.panda_inner_spheres`) of the Panda of
    :func:`_panda_obstacle`, in world coordinates: (hull vertices, per link of
    ``spheres.LINKS`` the (first, end) of its own, sphere centres, radii, per link the
    (first, end) of its spheres)."""
    frame = np.vstack([np.reshape(base, (3, 4)), [0.0, 0.0, 0.0, 1.0]])
    frames = _arm_frames_fn(frame)(np.array([q]))[0]
    hulls, model = spheres.panda_hulls(), spheres.panda_inner_spheres()
    verts, ends, centres, radii, iends = [], [], [], [], []
    for link in spheres.LINKS:
        F = frames[spheres.FRAME_OF_LINK[link]]
        first = sum(len(v) for v in verts)
        verts.append(hulls[link] @ F[:, :3].T + F[:, 3])
        ends.append((first, first + len(verts[-1])))
        mine = np.flatnonzero(model.links == link)
        first = sum(len(r) for r in radii)
        centres.append(model.centres[mine] @ F[:, :3].T + F[:, 3])
        radii.append(model.radii[mine])
        iends.append((first, first + len(mine)))
    return (np.ascontiguousarray(np.concatenate(verts)), tuple(ends),
            np.ascontiguousarray(np.concatenate(centres)), np.concatenate(radii), tuple(iends))


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
    hull: np.ndarray = None  # hull vertices of group g: hull[grp_hlo[g]:grp_hhi[g]],
    grp_hlo: np.ndarray = None  # in the group's frame (an empty range: no hull known)
    grp_hhi: np.ndarray = None
    #: (frame, centre, radius) of a sphere holding the robot, and the radii of spheres with
    #: the same centre that hold each group and each robot box; None: no such bounds
    root: tuple = None
    in_rbox: np.ndarray = None  # (inner sphere, robot box): a proof of collision if deep

    def __post_init__(self):
        self.rbox_r = np.linalg.norm(self.rbox_h, axis=1)
        if self.hull is None:
            self.hull = np.zeros((0, 3))
            self.grp_hlo = self.grp_hhi = np.zeros(len(self.grp_r), dtype=np.int64)
        if self.root is None:
            self.root = _root([0] * len(self.grp_r), [None] * len(self.rbox_T), None)
        self.root_frame = int(self.root[0])
        self.root_c = np.asarray(self.root[1], float)
        self.root_r = float(self.root[2])
        self.grp_reach = np.asarray(self.root[3], float)
        self.rbox_reach = np.asarray(self.root[4], float)
        if self.in_rbox is None:
            self.in_rbox = np.zeros((len(self.in_r), len(self.rbox_T)), dtype=np.bool_)
        # 0 or 1, as :func:`collide.pack` gives it to the scan: one compiled specialization
        self.in_rbox = np.asarray(self.in_rbox, dtype=np.int64)
        self._pack: tuple | None = None

    @classmethod
    def build(cls, groups, pairs=(), boxes=(), box_pairs=(), inner=None, hulls=None,
              reach=None) -> SphereRobot:
        """``groups``: (frame, centres (K, 3), radii (K,), tested against the world);
        ``pairs``: group index pairs tested against each other; ``boxes``: (frame,
        4 × 4 pose in it, true half extents; tested with BOX_MARGIN added);
        ``box_pairs``: (box, group) tested against each other; ``inner``: (frames,
        centres, radii) of spheres inside the robot's collision geometry, or None;
        ``hulls``: per group, the vertices (H, 3) of the convex hull its spheres cover, in
        its frame, or None; ``reach``: per frame, how far from the origin of frame 0 that
        frame's origin can be (the robot's parts then lie in a sphere around it; None: no
        such bound)."""
        hull_arrays = _hull_arrays(hulls, len(groups))
        groups = list(groups) or [(0, np.zeros((1, 3)), np.array([-1.0]), False)]
        sizes = [len(g[2]) for g in groups]
        if not min(sizes):
            raise ValueError("SphereRobot.build: every group needs at least one sphere")
        lo = np.cumsum([0] + sizes)
        centres = np.concatenate([g[1] for g in groups])
        radii = np.concatenate([g[2] for g in groups])
        gc, gr = _group_bounds(centres, radii, lo)
        root = _root([g[0] for g in groups], boxes, reach, (centres, radii, lo))
        # parts riding on one frame keep their distance: a pair whose spheres are apart now
        # is apart in every configuration, and the scan need not test it (its answer would
        # be "apart" row after row); the proofs still see every pair (``_inner_vs_boxes``)
        pairs = [p for p in pairs if not _rigidly_apart(groups[p[0]], groups[p[1]])]
        scanned_box_pairs = [p for p in box_pairs
                             if not _box_rigidly_apart(boxes[p[0]], groups[p[1]])]
        pa = np.array([p[0] for p in pairs], dtype=np.int64)
        pbb = np.array([p[1] for p in pairs], dtype=np.int64)
        return cls(np.array([g[0] for g in groups], dtype=np.int64), np.array(gc),
                   np.array(gr), lo[:-1].astype(np.int64), lo[1:].astype(np.int64),
                   np.array([g[3] for g in groups], dtype=np.bool_), centres, radii,
                   pa, pbb, np.array([b[0] for b in boxes], dtype=np.int64),
                   np.array([b[1][:3] for b in boxes]).reshape(-1, 3, 4),
                   np.array([b[2] for b in boxes]).reshape(-1, 3) + BOX_MARGIN,
                   np.array([p[0] for p in scanned_box_pairs], dtype=np.int64),
                   np.array([p[1] for p in scanned_box_pairs], dtype=np.int64),
                   np.array([b[2] for b in boxes], float).reshape(-1, 3),
                   *_inner_arrays(inner), *hull_arrays, root,
                   _inner_vs_boxes(inner, boxes, box_pairs))

    def first(self, frames: np.ndarray, world: World, start: int = 0,
              pre: np.ndarray | None = None, wrist_pairs: np.ndarray | None = None) -> int:
        """The first row >= ``start`` of ``frames`` (N, F, 3, 4) that may collide (or
        marked in ``pre``: with ``wrist_pairs``, a row the wrist table doubts, which these
        pairs shown apart clear; :func:`pipeline.sim.collide.first_uncertain`), N when
        none may."""
        if pre is None:
            pre = np.zeros(len(frames), dtype=np.bool_)
        return int(collide.first_uncertain(frames, start, pre, self.packed(world),
                                           wrist_pairs))

    def packed(self, world: World) -> tuple:
        """The robot's and ``world``'s arrays as :func:`pipeline.sim.collide.pack` lays
        them out for the compiled scan, then the root frame and radius and the proof depth
        (each packed once)."""
        if self._pack is None:
            values = {name: getattr(self, name) for name, _, _ in collide.ROBOT_PACK
                      if name != "gaps"}
            self._pack = collide.pack({**values, "gaps": GAPS}, collide.ROBOT_PACK)
        return (*self._pack, *world.packed(), self.root_frame, self.root_r, PROOF_DEPTH)

    def surely_hits(self, frames: np.ndarray, n: int, world: World) -> bool:
        """Does row n of ``frames`` certainly collide (a robot box or an inner sphere deep
        in a world box, or an inner sphere deep in a box the robot carries, where the
        two are tested against each other)?"""
        if self.in_rbox.any() and collide.inner_hit_rbox(
                frames, n, self.in_frame, self.in_c, self.in_r, self.in_rbox, self.rbox_frame,
                self.rbox_T, self.rbox_solid, PROOF_DEPTH):
            return True
        if not len(world.box_c):
            return self._hits_robot(frames, n, world)
        boxes = (world.box_c, world.box_R, world.box_h, world.box_r, PROOF_DEPTH)
        return bool(
            (len(self.rbox_solid) and collide.box_hit(
                frames, n, self.rbox_frame, self.rbox_T, self.rbox_solid, *boxes))
            or (len(self.in_r) and collide.sphere_hit(frames, n, self.in_frame, self.in_c,
                                                      self.in_r, *boxes))
            or self._hits_robot(frames, n, world))

    def _hits_robot(self, frames: np.ndarray, n: int, world: World) -> bool:
        """Whether an inner sphere lies PROOF_DEPTH deep in one of another robot's inner
        spheres (:meth:`World.read`): a proven collision."""
        return bool(len(world.oin_r) and len(self.in_r) and collide.inner_hit_spheres(
            frames, n, self.in_frame, self.in_c, self.in_r, world.og_c, world.og_r,
            world.og_ilo, world.og_ihi, world.oin_c, world.oin_r, PROOF_DEPTH))

    def uncertain(self, frames: np.ndarray, world: World, pre: np.ndarray | None = None,
                  wrist_pairs: np.ndarray | None = None) -> np.ndarray:
        """(N,) whether each row may collide (:meth:`first`'s arguments)."""
        out = np.zeros(len(frames), dtype=bool)
        k = self.first(frames, world, 0, pre, wrist_pairs)
        while k < len(frames):
            out[k] = True
            k = self.first(frames, world, k + 1, pre, wrist_pairs)
        return out


#: how far apart (metres) two parts on one frame must be for :meth:`SphereRobot.build` to
#: leave their pair out of the scan (far above the rounding of placing them in the world)
RIGID_GAP = 1e-6


def _rigidly_apart(a, b) -> bool:
    """Are groups ``a`` and ``b`` (frame, centres, radii, ...) on one frame, with no
    sphere of one touching a sphere of the other?"""
    if a[0] != b[0] or not len(a[2]) or not len(b[2]):
        return False
    ca, cb = np.asarray(a[1], float), np.asarray(b[1], float)
    gaps = (np.linalg.norm(ca[:, None] - cb[None], axis=2)
            - np.asarray(a[2])[:, None] - np.asarray(b[2])[None])
    return bool(gaps.min() > RIGID_GAP)


def _box_rigidly_apart(box, group) -> bool:
    """Are robot box ``box`` (frame, 4 × 4 pose, true half extents) and ``group`` on one
    frame, with no sphere of the group reaching the box grown by BOX_MARGIN (the scan's
    test)?"""
    frame, T, half = box
    if frame != group[0] or not len(group[2]):
        return False
    T = np.asarray(T, float)
    local = np.abs((np.asarray(group[1], float) - T[:3, 3]) @ T[:3, :3])  # in the box's axes
    outside = np.maximum(local - (np.asarray(half, float) + BOX_MARGIN), 0.0)
    return bool((np.linalg.norm(outside, axis=1) - np.asarray(group[2])).min() > RIGID_GAP)


def _hull_arrays(hulls, count: int):
    """(vertices, first, end) of the groups' hulls (``hulls``: per group an (H, 3) array
    or None), or Nones (no hulls) when ``hulls`` is None."""
    if hulls is None:
        return None, None, None
    sizes = [0 if h is None else len(h) for h in hulls]
    lo = np.cumsum([0] + sizes).astype(np.int64)
    verts = [np.asarray(h, float).reshape(-1, 3) for h in hulls if h is not None]
    return (np.ascontiguousarray(np.concatenate(verts) if verts else np.zeros((0, 3))),
            lo[:-1].copy(), lo[1:].copy())


def _group_bounds(centres: np.ndarray, radii: np.ndarray,
                  lo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_bounding` of every group at once (the same operations on the same numbers,
    ``tests/test_fast_collision.py``): group g is centres[lo[g]:lo[g + 1]], radii
    likewise, none of them empty."""
    starts = lo[:-1]
    centre = (np.minimum.reduceat(centres, starts, axis=0)
              + np.maximum.reduceat(centres, starts, axis=0)) / 2
    d = centres - np.repeat(centre, np.diff(lo), axis=0)
    return centre, np.maximum.reduceat(np.sqrt(np.add.reduce(d * d, axis=1)) + radii, starts)


def _root(frames, boxes, reach, stacked=None) -> tuple:
    """A sphere around the origin of frame 0 that holds every group's spheres and every
    robot box (with its margin) in every configuration, given ``reach`` (per frame, a
    bound on how far its origin is from frame 0's).  ``frames``: each group's frame;
    ``stacked`` (needed with a ``reach``): the groups' centres and radii concatenated and
    where each group starts (``lo``), none of them empty."""
    if reach is None:
        return (0, np.zeros(3), np.inf, np.full(len(frames), np.inf),
                np.full(len(boxes), np.inf))
    centres, radii, lo = stacked  # each group's farthest point from frame 0's origin:
    extent = np.sqrt(np.add.reduce(centres * centres, axis=1)) + radii
    grp = (np.asarray(reach, float)[np.asarray(frames, dtype=np.int64)]
           + np.maximum.reduceat(extent, lo[:-1]))
    box = np.zeros(len(boxes))
    for b, (frame, T, half) in enumerate(boxes):
        box[b] = reach[frame] + float(np.linalg.norm(np.asarray(T)[:3, 3])
                                      + np.linalg.norm(np.asarray(half) + BOX_MARGIN))
    grp, box = grp + 1e-6, box + 1e-6
    return 0, np.zeros(3), float(max(grp.max(initial=0.0), box.max(initial=0.0))), grp, box


def _inner_arrays(inner) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if inner is None:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0)
    frames, centres, radii = inner[:3]
    # a copy: the sphere model's frames are read-only, and numba compiles a kernel once
    # more for a read-only array (compile_kernels' arrays are writable)
    return (np.array(frames, dtype=np.int64), np.asarray(centres, float).reshape(-1, 3),
            np.asarray(radii, float))


def _inner_vs_boxes(inner, boxes, box_pairs) -> np.ndarray:
    """(inner spheres, robot boxes): is the pair tested for a proven collision?  Those of
    the groups paired with the box (``inner`` with the group of each sphere)."""
    n = 0 if inner is None else len(inner[2])
    out = np.zeros((n, len(boxes)), dtype=np.bool_)
    if inner is not None and len(inner) > 3:
        for b, g in box_pairs:
            out[np.asarray(inner[3]) == g, b] = True
    return out


def panda_inner():
    """The Panda's inner spheres (:func:`pipeline.sim.spheres.panda_inner_spheres`) as
    SphereRobot.build's ``inner``, with the group of each (:func:`panda_groups`' order)."""
    model = spheres.panda_inner_spheres()
    groups = np.array([spheres.LINKS.index(int(link)) for link in model.links], dtype=np.int64)
    return model.frames, model.centres, model.radii, groups


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
    ``remember``: the exact check's answer is a function of the row (fresh contacts,
    docs/contacts.md), so a row asked again is answered from memory (OMPL checks the start
    and goal the planning call checked already).
    """

    def __init__(self, robot: SphereRobot | None, world: World | None, frames: Callable,
                 exact: Callable[[np.ndarray], bool], certified: bool = True,
                 also: Callable[[np.ndarray], np.ndarray] | None = None, motion=None,
                 remember: bool = False):
        self.robot, self.world, self.frames, self.exact = robot, world, frames, exact
        self.certified = certified and robot is not None and world is not None
        self.also = also  # more rows to send to ``exact`` (say, the wrist table's)
        self.stats = {"rows": 0, "exact": 0, "proved": 0, "remembered": 0}
        #: the exact answers by row (``remember``), or None
        self._asked: dict[bytes, bool] | None = {} if remember else None
        #: how :meth:`motion` makes a motion's frames without making its states:
        #: ("arm", base link frame 3 × 4, chain origins, wrist table) or ("base", psi_scale)
        self._motion = motion if self.certified else None
        #: the groups of the wrist pairs whose hulls may clear a row the wrist table (then
        #: ``also``) doubts, or None: only under fresh contacts, as ``remember``
        #: (:func:`_wrist_groups`)
        self._wrist = (_wrist_groups(motion[3].pairs) if remember and self._motion is not None
                       and motion[0] == "arm" else None)
        self._args = None
        #: motions (a, b, resolution) refuted without asking pybullet (geometry, or its
        #: answers remembered under ``remember``): the first row in check order that is
        #: not cleared is a proven collision (``motion``'s rows)
        self._refuted: dict[tuple, int] = {}
        #: single configurations decided by geometry alone (cleared, or a proven
        #: collision): asked again (about one in six in pick_place), the same answer
        self._settled: dict[bytes, bool] = {}

    def _pre(self, states: np.ndarray) -> np.ndarray:
        if self.also is None:
            return np.zeros(len(states), dtype=np.bool_)
        return self.also(states)

    def uncertain(self, states: np.ndarray) -> np.ndarray:
        """(N,) whether each row needs the exact check."""
        if not self.certified:
            return np.ones(len(states), dtype=bool)
        states = np.ascontiguousarray(states, float)
        return self.robot.uncertain(self.frames(states), self.world, self._pre(states),
                                    self._wrist)

    def __call__(self, states: np.ndarray) -> tuple[bool, int]:
        states = np.atleast_2d(states)
        n = len(states)
        if n == 1 and self._motion is not None:
            return self._one(states[0])
        self.stats["rows"] += n
        if not self.certified:
            for k in range(n):
                self.stats["exact"] += 1
                if self.exact(states[k]):
                    return False, k + 1
            return True, n
        states = np.ascontiguousarray(states, float)
        frames, pre = self.frames(states), self._pre(states)
        k = self.robot.first(frames, self.world, 0, pre, self._wrist)
        while k < n:
            if self.robot.surely_hits(frames, k, self.world):
                self.stats["proved"] += 1
                return False, k + 1
            if self._ask(states[k]):
                return False, k + 1
            k = self.robot.first(frames, self.world, k + 1, pre, self._wrist)
        return True, n

    def motion(self, a: np.ndarray, b: np.ndarray, resolution: float,
               limit: int) -> tuple[bool, int]:
        """:meth:`pipeline.planning.base.Robot.check_motion` with this checker: the same
        states in the same order, the same answer and count, but the motion's states are
        never made (:func:`pipeline.sim.collide.edge_first` makes their frames), only
        those the exact check must see, each exactly as ``interpolate`` makes it."""
        if self._motion is None:
            states = interpolate(a, b, resolution)
            ok, used = self(states[check_order(len(states))][:limit])
            return ok and used >= len(states), used
        a = np.ascontiguousarray(a, dtype=float)
        b = np.ascontiguousarray(b, dtype=float)
        key = (a.tobytes(), b.tobytes(), resolution)
        refuted = self._refuted.get(key)
        if refuted is not None:
            return self._refuted_again(refuted, limit)
        exact_before = self.stats["exact"]
        kind, psi, step, table, chain, packed, memo = self.scan_args()
        cells = table.state if table is not None else _NO_CELLS
        steps, k, proved = collide.edge_first(a, b, resolution, limit, 0, kind, psi, step,
                                              cells, chain, packed, memo)
        m = min(steps, limit)
        self.stats["rows"] += m
        while k < m:
            if k < 0:  # a wrist cell never computed: compute the cells of the rows left
                k = -1 - k
                self.wrist_cells(a, b, steps, k, m)
                cells = table.state
                steps, k, proved = collide.edge_first(a, b, resolution, limit, k, kind, psi,
                                                      step, cells, chain, packed, memo)
                continue
            if proved:
                self.stats["proved"] += 1
                if self.stats["exact"] == exact_before:
                    self._refuted[key] = k + 1
                return False, k + 1
            if self._ask(self.row(a, b, steps, k)):
                return False, k + 1
            steps, k, proved = collide.edge_first(a, b, resolution, limit, k + 1, kind, psi,
                                                  step, cells, chain, packed, memo)
        return m >= steps, m

    @staticmethod
    def row(a: np.ndarray, b: np.ndarray, steps: int, k: int) -> np.ndarray:
        """The configuration at position k (check order) of the motion a→b of ``steps``
        states, as ``interpolate`` makes it: a + t (b - a), t = (row + 1) / steps."""
        return a + (int(check_order(steps)[k]) + 1) / steps * (b - a)

    def wrist_cells(self, a: np.ndarray, b: np.ndarray, steps: int, start: int,
                    m: int) -> None:
        """Compute the wrist table's cells of positions ``start`` … m - 1 of the motion
        a→b (a scan met a cell never computed)."""
        order = check_order(steps)[start:m]
        self._motion[3].uncertain(a + ((order + 1) / steps)[:, None] * (b - a))

    def scan_args(self) -> tuple:
        """What the compiled scan takes besides a motion (:meth:`_motion_args`, made once
        per checker); for a checker that scans motions."""
        if self._args is None:
            self._args = self._motion_args()
        return self._args

    def _refuted_again(self, rows: int, limit: int) -> tuple[bool, int]:
        """:meth:`motion` of a motion it refuted before by geometry alone, its first
        ``rows - 1`` rows cleared by the pre-check and row ``rows - 1`` a proven collision:
        the same rows give the same answers (no pybullet check was involved, so nothing
        that depends on what pybullet checked before), and a smaller ``limit`` stops the
        scan among the cleared rows.  (Shortcutting draws the same blocked pair of
        waypoints again and again.)"""
        used = min(rows, limit)
        self.stats["rows"] += used
        self.stats["proved"] += used == rows
        return False, used

    def _one(self, state: np.ndarray) -> tuple[bool, int]:
        """One configuration, as ``self(state[None])`` answers and counts it: the motion
        state→state (its only configuration is ``state``) in one compiled call."""
        self.stats["rows"] += 1
        free = self.settle(state)
        if free is not None:
            self.stats["proved"] += not free
            return free, 1
        return (False, 1) if self._ask(state) else (True, 1)

    def settle(self, state: np.ndarray) -> bool | None:
        """Whether one configuration is free (True) or collides (False) where geometry
        alone decides (the scan clears it, or proves a collision), None where only the
        exact check can tell, and for a checker that does not scan motions.  Counts
        nothing; the answer is kept for the configuration (asked again, about one in six
        in pick_place, the same answer)."""
        if self._motion is None:
            return None
        q = np.ascontiguousarray(state, dtype=float)
        key = q.tobytes()
        settled = self._settled.get(key)
        if settled is not None:
            return settled
        kind, psi, step, table, chain, packed, memo = self.scan_args()
        cells = table.state if table is not None else _NO_CELLS
        _, k, proved = collide.edge_first(q, q, 1.0, 1, 0, kind, psi, step, cells, chain,
                                          packed, memo)
        if k < 0:  # a wrist cell never computed
            table.uncertain(q[None])
            _, k, proved = collide.edge_first(q, q, 1.0, 1, 0, kind, psi, step, table.state,
                                              chain, packed, memo)
        if k >= 1 or proved:
            self._settled[key] = k >= 1
            return k >= 1
        return None

    def _ask(self, q: np.ndarray) -> bool:
        """The exact check of row q (True: collides), counted, or its answer from memory
        (``remember``)."""
        if self._asked is None:
            self.stats["exact"] += 1
            return bool(self.exact(q))
        key = np.ascontiguousarray(q, dtype=float).tobytes()
        answer = self._asked.get(key)
        if answer is None:
            self.stats["exact"] += 1
            answer = self._asked[key] = bool(self.exact(q))
        else:
            self.stats["remembered"] += 1
        return answer

    def _motion_args(self) -> tuple:
        """(kind, psi_scale, wrist grid step, wrist table, chain, packed arrays, memo) of
        :func:`pipeline.sim.collide.edge_first` (the memo is this checker's own: its
        robot and world are fixed)."""
        kind = self._motion
        packed = self.robot.packed(self.world)
        memo = collide.near_memo((len(self.robot.grp_r), len(self.robot.rbox_T)),
                                 len(self.world.box_c))
        if kind[0] == "arm":
            table = kind[3]
            chain = (np.ascontiguousarray(kind[1], dtype=float),
                     np.ascontiguousarray(kind[2], dtype=float),
                     np.ascontiguousarray(table.lower, dtype=float),
                     collide.NO_CHAIN[3] if self._wrist is None else self._wrist)
            return 0, 1.0, wrist.STEP, table, chain, packed, memo
        return 1, float(kind[1]), 1.0, None, collide.NO_CHAIN, packed, memo


def _arm_frames_fn(base: np.ndarray):
    base34 = np.ascontiguousarray(base[:3])
    origins = np.ascontiguousarray(spheres.panda_chain().origins[:7, :3])

    def frames(states):
        out = np.empty((len(states), 8, 3, 4))
        collide.arm_frames(states, base34, origins, out)
        return out
    frames.base34, frames.origins = base34, origins
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
    """(groups, group index of each link, self pairs, hulls of the groups) of a Panda whose
    filtered link pairs are ``ignored``; the wrist's own pairs are left to
    :mod:`pipeline.sim.wrist`."""
    groups, index = panda_groups(spheres.panda_spheres(MARGIN))
    hulls = spheres.panda_hulls()
    return (tuple(groups), index, tuple(self_pairs(index, set(ignored) | set(wrist.PAIRS))),
            tuple(hulls[link] for link in spheres.LINKS))


@functools.lru_cache(maxsize=8)
def _panda_robot(ignored: frozenset) -> SphereRobot:
    groups, _, pairs, hulls = _panda_parts(ignored)
    return SphereRobot.build(groups, pairs, inner=panda_inner(), hulls=hulls,
                             reach=spheres.frame_reach())


def _arm_robot(client: int, arm_body: int, ignored_pairs, held, hand_links):
    """(Robot of the arm and its held box, frames function, whether the held box could be
    modelled).  ``held``: None or (body, its pose in the frame of link 6, 4 × 4)."""
    ignored = frozenset(ignored_pairs)
    frames = _ROBOTS.get(("frames", client, arm_body, _poses(client, (arm_body,))),
                         lambda: _arm_frames_fn(base_link_frame(client, arm_body)))
    if held is None:
        return _panda_robot(ignored), frames, True
    box = _held_box(client, held[0], held[1], spheres.FRAME_OF_LINK[6])
    if box is None:
        return None, frames, False

    def make():
        groups, index, pairs, hulls = _panda_parts(ignored)
        arm_links = [(0, index[link]) for link in index if link not in hand_links]
        return SphereRobot.build(groups, pairs, boxes=[box], box_pairs=arm_links,
                                 inner=panda_inner(), hulls=hulls, reach=spheres.frame_reach())
    key = ("arm", ignored, frozenset(hand_links), box[0], _key_of(box[1]), _key_of(box[2]))
    return _ROBOTS.get(key, make), frames, True


def arm_checker(client: int, arm_body: int, ignored_pairs, exact, *, held=None,
                hand_links=frozenset(), fixed_robot=(), world_key=None,
                fresh_contacts: bool = False) -> SphereChecker:
    """Checker for arm motions with the base fixed.

    ``ignored_pairs``: the arm's link pairs pybullet does not check; ``held``: (body, pose
    in the frame of link 6) of a box carried rigidly by the hand (its contacts with
    ``hand_links`` are the grasp); ``fixed_robot``: bodies of the same robot that do not
    move (a platform): the arm and the held box must not touch them, and they must not
    touch the world (asked of pybullet's contacts; ``fresh_contacts``: each cached
    penetration confirmed afresh, as the robot's own checks do; then also another
    Panda's link hulls clear rows, :meth:`World.read`).  ``world_key``: see
    :func:`read_world`.
    """
    robot, frames, ok = _arm_robot(client, arm_body, ignored_pairs, held, hand_links)
    world = read_world(client, {arm_body} | ({held[0]} if held is not None else set()),
                       world_key, moving=tuple(fixed_robot), hulls=fresh_contacts)
    certified = ok and world is not None
    if certified and fixed_robot:
        # a fixed part of the robot is a box of the world, and must not touch the rest of
        # the world (pybullet would report a collision for every row): asked once, exactly
        # (once per world and place of those parts, under a scene's world key)
        robot_bodies = {arm_body, *fixed_robot} | ({held[0]} if held is not None else set())

        def apart() -> bool:
            return all(body in world.bodies for body in fixed_robot) and not any(
                _touches_world(client, body, robot_bodies, fresh_contacts)
                for body in fixed_robot)
        certified = apart() if world_key is None else _WORLDS.get(
            ("apart", client, world_key, frozenset(robot_bodies), _poses(client, fixed_robot),
             fresh_contacts), apart)
    table = wrist_table(ignored_pairs)
    return SphereChecker(robot, world, frames, exact, certified, also=table.uncertain,
                         motion=("arm", frames.base34, frames.origins, table),
                         remember=fresh_contacts)


def _wrist_groups(pairs: tuple) -> np.ndarray:
    """(P, 2) the groups (:func:`panda_groups`' order) of the wrist table's link pairs,
    whose hulls shown apart clear a configuration the table is in doubt about (the
    scan's ``wrist_pairs``).  Only under fresh contacts (:meth:`World.read`'s reason)."""
    return np.array([[spheres.LINKS.index(a), spheres.LINKS.index(b)] for a, b in pairs],
                    dtype=np.int64).reshape(-1, 2)


def base_checker(client: int, arm_body: int, platform: int, base_pose: np.ndarray,
                 psi_scale: float, exact, internal_free: bool, *, held=None,
                 held_key=None, world_key=None, fresh_contacts: bool = False) -> SphereChecker:
    """Checker for base motions (x, y, psi_scale · ψ) of a mobile arm, arm fixed.

    ``base_pose`` is the base's current 4 × 4 transform (its frame: on the floor under the
    platform's centre); the arm and the platform keep their poses in it.  ``held``: None or
    (body, pose in the base frame) of the carried box.  Contacts within the robot do not
    change while the base moves: ``internal_free`` says the caller ruled them out at the
    current state (else every row goes to ``exact``).  ``held_key``: None, or what fixes
    the carried box's pose exactly (its pose in the hand, with the arm's state): the
    robot model is remembered under it rather than under ``held``'s pose, which pybullet's
    kinematics give only to about 1e-7 m, a little differently at every base pose (so
    every planning call would build the model again; the margins of :data:`GAPS` are
    three orders above that).  ``world_key``: see :func:`read_world`.
    ``fresh_contacts``: the exact check confirms each cached penetration afresh (its
    answers are remembered, :class:`SphereChecker`).
    """
    if not internal_free:
        return SphereChecker(None, None, None, exact, certified=False)
    q = arm_state(client, arm_body)
    key = ("base", client, arm_body, platform, _key_of(q),
           None if held is None else (_shape_key(client, held[0]),
                                      _key_of(held[1]) if held_key is None else held_key))
    robot = _ROBOTS.get(key, lambda: _base_robot(client, arm_body, platform, base_pose, q,
                                                  held))
    if robot is None:
        return SphereChecker(None, None, None, exact, certified=False)
    world = read_world(client, {arm_body, platform} | ({held[0]} if held is not None else set()),
                       world_key)

    def base_frames(states):
        out = np.empty((len(states), 1, 3, 4))
        collide.planar_frames(states, psi_scale, out)
        return out
    return SphereChecker(robot, world, base_frames, exact, motion=("base", psi_scale),
                         remember=fresh_contacts)


@functools.lru_cache(maxsize=1)
def _base_parts():
    """What :func:`_base_robot` takes from the Panda's models, made once: the sphere
    model and its rows of each link (``spheres.LINKS``' order), the inner spheres and the
    group of each, the links' hulls and the chain's joint origins (as the scan takes
    them)."""
    model = spheres.panda_spheres(MARGIN)
    rows = [np.flatnonzero(model.links == link) for link in spheres.LINKS]
    inner = spheres.panda_inner_spheres()
    inner_groups = np.array([spheres.LINKS.index(int(k)) for k in inner.links])
    hulls = spheres.panda_hulls()
    origins = np.ascontiguousarray(spheres.panda_chain().origins[:7, :3])
    return model, rows, inner, inner_groups, [hulls[link] for link in spheres.LINKS], origins


def _base_robot(client: int, arm_body: int, platform: int, base_pose: np.ndarray, q,
                held) -> SphereRobot | None:
    """The robot of :func:`base_checker` in its base frame (None: not modelled).  The
    arm's frames are made in the base frame directly (compiled, as the scan makes them)."""
    box = _box_of(client, platform)
    if box is None:
        return None
    to_base = np.linalg.inv(base_pose)
    model, rows, inner_model, inner_groups, link_hulls, origins = _base_parts()
    arm = np.empty((1, 8, 3, 4))
    collide.arm_frames(np.asarray(q, float)[None],
                       np.ascontiguousarray((to_base @ base_link_frame(client, arm_body))[:3]),
                       origins, arm)
    centres = model.world(arm)[0]
    groups = [(0, centres[r], model.radii[r], link != -1)
              for link, r in zip(spheres.LINKS, rows, strict=True)]
    hulls = []
    for link, hull in zip(spheres.LINKS, link_hulls, strict=True):
        F = arm[0, spheres.FRAME_OF_LINK[link]]  # hull vertices ride on the spheres' frames
        hulls.append(hull @ F[:, :3].T + F[:, 3])
    boxes = [(0, to_base @ box[0], box[1])]
    if held is not None:
        box = _held_box(client, held[0], held[1], 0)
        if box is None:
            return None
        boxes.append(box)
    # the inner spheres ride on the base frame too: one deep in a world box proves a
    # collision of the arm (their links' contacts are collisions for the exact check)
    inner = (np.zeros(len(inner_groups), dtype=np.int64), inner_model.world(arm)[0],
             inner_model.radii, inner_groups)
    return SphereRobot.build(groups, boxes=boxes, inner=inner, hulls=hulls, reach=np.zeros(1))


def _touches_world(client: int, body: int, robot_bodies, fresh: bool = False) -> bool:
    if fresh:
        return contacts.collides(client, body, lambda p: p[2] in robot_bodies)
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
    """A robot model whose ``check`` and ``check_motion`` are a :class:`SphereChecker` of
    ``model``'s (same answers and counts); the rest of the model is ``model``'s."""

    def __init__(self, model, checker: SphereChecker):
        self.model, self.checker = model, checker
        self.lower, self.upper = model.lower, model.upper
        self.description = model.description
        # the checker's own methods, bound here: a planning call makes tens of thousands
        # of checks, and each call through the methods below costs a Python frame more
        self.check = checker.__call__
        if type(model).check_motion is Robot.check_motion:
            self.check_motion = checker.motion

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        return self.checker(states)

    def check_motion(self, a, b, resolution: float, limit: int) -> tuple[bool, int]:
        if type(self.model).check_motion is not Robot.check_motion:
            return super().check_motion(a, b, resolution, limit)  # the model's own order
        return self.checker.motion(a, b, resolution, limit)

    def certified(self) -> CertifiedRobot:
        return self  # already

    def rrt_connect_search(self, lower, upper, start, goal, budget, reach: float,
                           resolution: float, first_seed: int):
        """OMPL's RRT-Connect compiled with this checker's scan for one planning call
        (:class:`pipeline.sim.compiled_rrt.CompiledRRTConnect`, the same search and
        answers), or None where this robot's checks are not the scan's."""
        if not compiled_rrt.applies(self):
            return None
        return compiled_rrt.CompiledRRTConnect(lower, upper, start, goal, budget, reach,
                                               resolution, first_seed)

    def shortcut_search(self, path, budget, pairs, resolution: float, attempts: int):
        """:func:`pipeline.planning.shortcut.shortcut` compiled with this checker's scan
        (:func:`pipeline.sim.compiled_rrt.shortcut`, the same pairs, checks and path), or
        None where this robot's checks are not the scan's."""
        if not compiled_rrt.applies(self):
            return None
        return compiled_rrt.shortcut(path, budget, pairs, resolution, attempts)

    def __getattr__(self, name):  # optional capabilities (distance_model) are the model's
        return getattr(self.model, name)


_COMPILED = False


def compile_kernels() -> None:
    """Load (or, the first time after an install or a change, compile) the compiled
    kernels this module calls, with the argument types it calls them with, once per
    process.  :func:`certified` calls it before a planning call's budget starts its
    wall-clock cap, so that compiling (tens of seconds with a cold numba cache) can never
    turn an entry into "timeout"."""
    global _COMPILED
    if _COMPILED:
        return
    robot = SphereRobot.build([(0, np.zeros((1, 3)), np.array([0.01]), True)],
                              boxes=[(0, np.eye(4), np.full(3, 0.01))], box_pairs=[(0, 0)],
                              inner=(np.zeros(1, np.int64), np.zeros((1, 3)), np.array([0.005]),
                                     np.zeros(1, np.int64)),
                              hulls=[np.zeros((4, 3))], reach=np.zeros(8))
    world = World(np.array([[0.0, 0.0, 0.0]]), np.eye(3)[None], np.full((1, 3), 0.1),
                  np.zeros((0, 3)), np.zeros(0), [-1])
    frames = _arm_frames_fn(np.eye(4))(np.zeros((2, 7)))
    robot.first(frames, world, 0, np.zeros(2, dtype=np.bool_))
    robot.surely_hits(frames, 0, world)  # stops at its first proof: the other two as well
    boxes = (world.box_c, world.box_R, world.box_h, world.box_r, PROOF_DEPTH)
    collide.box_hit(frames, 0, robot.rbox_frame, robot.rbox_T, robot.rbox_solid, *boxes)
    collide.sphere_hit(frames, 0, robot.in_frame, robot.in_c, robot.in_r, *boxes)
    collide.inner_hit_spheres(frames, 0, robot.in_frame, robot.in_c, robot.in_r, world.og_c,
                              world.og_r, world.og_ilo, world.og_ihi, world.oin_c, world.oin_r,
                              PROOF_DEPTH)
    collide.planar_frames(np.zeros((1, 3)), 1.0, np.empty((1, 1, 3, 4)))
    collide.wrist_cells(np.zeros((1, 7)), np.zeros(2), wrist.STEP, np.ones((2, 2), np.int8),
                        np.empty(1, dtype=np.bool_))
    compiled_rrt.warm_up(SphereChecker(robot, world, lambda states: None, lambda q: False,
                                       motion=("base", 1.0)))
    _COMPILED = True


def certified(model):
    """``model`` (a robot model) with sphere-certified checks: its own ``certified()``
    (the robot model's capability, built by one of the functions below), or ``model``
    itself when it has none.  Call it when a planning call starts: the world is read
    now."""
    make = getattr(model, "certified", None)
    return make() if callable(make) else model


def certified_panda(model) -> CertifiedRobot:
    """A fixed Panda's (:class:`pipeline.sim.panda.Panda`) sphere-certified model."""
    compile_kernels()
    return CertifiedRobot(model, arm_checker(model.client, model.body, model.ignored_pairs,
                                             model.collides_at, world_key=_world_key(model),
                                             fresh_contacts=model.fresh_contacts))


def certified_mobile_arm(model) -> CertifiedRobot:
    """A mobile Panda's arm's (:class:`pipeline.sim.mobile.MobileArm`)."""
    compile_kernels()
    r = model.robot
    return CertifiedRobot(model, arm_checker(
        r.client, r.body, r.arm.ignored_pairs, r.arm_collides, held=_held(r, hand=True),
        hand_links=r.hand_links, fixed_robot=(r.platform,), world_key=_world_key(r),
        fresh_contacts=r.fresh_contacts))


def certified_mobile_base(model) -> CertifiedRobot:
    """A mobile Panda's base's (:class:`pipeline.sim.mobile.MobileBase`)."""
    compile_kernels()
    r = model.robot  # MobileBase.certified put its held object where base checks will
    return CertifiedRobot(model, base_checker(
        r.client, r.body, r.platform, r.base_frame(), model.psi_scale, model.collides,
        _internal_free(r), held=_held(r, hand=False),
        held_key=None if r.held is None else ("in hand", _key_of(r.held_in_tcp)),
        world_key=_world_key(r), fresh_contacts=r.fresh_contacts))


def _shape_key(client: int, body: int) -> tuple:
    """What a body's collision shapes are (not where): part of a memo key."""
    return tuple((shape[1], shape[2], tuple(shape[3]), shape[4], tuple(shape[5]),
                  tuple(shape[6])) for shape in pb.getCollisionShapeData(
                      body, -1, physicsClientId=client))


def _world_key(robot):
    """The scene's key for what is not the robot (``robot.world_key()``), or None."""
    key = getattr(robot, "world_key", None)
    return key() if callable(key) else None


def _internal_free(robot) -> bool:
    """:func:`internal_clearance` > INTERNAL_CLEARANCE, measured once per arm state and
    held object's pose in the hand (what the parts' distances depend on)."""
    q = arm_state(robot.client, robot.body)
    key = (robot.client, robot.body, robot.platform, _key_of(q),
           None if robot.held is None else (_shape_key(robot.client, robot.held),
                                            _key_of(robot.held_in_tcp)))
    return _CLEARANCES.get(key, lambda: internal_clearance(robot) > INTERNAL_CLEARANCE)


def _held(robot, hand: bool):
    """(body, pose in the frame of link 6 (``hand``) or of the base) of what a MobilePanda
    holds; None when it holds nothing."""
    if robot.held is None:
        return None
    if hand:
        return robot.held, spheres.fixed_offsets()[spheres.TCP_LINK] @ robot.held_in_tcp
    return robot.held, robot.held_in_base
