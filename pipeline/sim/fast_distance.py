"""Signed distances for TrajOpt with pybullet asked only about bodies that may be close.

A Panda's distance model (:meth:`pipeline.sim.panda.Panda.distances`) asks pybullet for the
closest points between the arm and *every* other body of the client at every
configuration, although at a given configuration only one or two bodies are within the
query distance: in grasp_arm and grasp_base that is 17 to 25 ``getClosestPoints`` calls per
configuration, most of a TrajOpt call's time.

:func:`bounded` gives the same model with a cheap test in front (compiled,
:func:`near_bodies`), which bounds the distance of each of the arm's moving links from each
body from below.  The arm's conservative sphere model (:func:`pipeline.sim.spheres.
panda_spheres`: every point of a link's collision hull lies in one of its spheres, whose
radii carry ``fast_check.MARGIN`` for pybullet's collision margin) gives one bound: from a
sphere to a box body, the distance from the centre to the box less the radius; to another
Panda, the distance between the two Pandas' spheres.  For a box, the link's hull
(:func:`pipeline.sim.spheres.panda_hulls`, the vertices pybullet collides) gives another:
how far the hull lies beyond one of the box's faces, a separating direction of two convex
sets (the spheres of the first link above the arm's mount are loose: it is 9 cm above a
mobile robot's platform, its spheres come within 6 cm).  A body whose bound exceeds the query
distance by ``SAFETY`` for every link has no point closer than the query (pybullet reports
none for it), so only the other bodies are asked, in their original order, by the Panda's
own ``distances``: the distances and gradients are the same, bit for bit, as those of the
full model (tests/test_trajopt.py compares them).  A configuration with no body in reach
is not even set in pybullet.  Bodies that are neither a box nor a Panda are always asked.
The arm's base link is left out of the bound, as the full model leaves out its points.

The world is read when :func:`bounded` is called and assumed fixed while the model is used
(one model per planning call, made once the scene is set, as ``fast_check.certified``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from pipeline.sim import collide, fast_check, spheres

#: the digests of the files whose compiled functions the kernel here calls, as
#: :data:`pipeline.sim.compiled_rrt.LINKED` (why: tests/test_kernel_cache.py)
LINKED = {"collide.py": "5388238a9e82e474"}

#: how far beyond the query distance (metres) a body's lower bound must be for the body to
#: be left out: far above pybullet's collision margin (its distances are up to 0.9 mm below
#: the hulls'; the spheres carry it already, the hulls' separations do not) and the
#: kinematics' rounding (1e-7 m)
SAFETY = 0.01


@njit(cache=True)
def near_bodies(frames, link_frame, link_lo, link_hi, link_c, link_r, sph_c, sph_r, hull_lo,
                hull_hi, hull_v, box_c, box_R, box_h, obs_c, obs_r, grp_lo, grp_hi, grp_c,
                grp_r, body_lo, body_hi, reach, out):  # pragma: no cover (compiled)
    """out[n, b]: may the robot at ``frames[n]`` come within ``reach`` of body b?

    The robot is links l riding on frames link_frame[l], each covered by the spheres
    sph_c[link_lo[l]:link_hi[l]] (in that frame; radii sph_r), which all lie in the
    sphere link_c[l], link_r[l] (a box that sphere is out of reach of is out of reach
    of every sphere of the link: their own tests are left out), and, where hull_lo[l] <
    hull_hi[l], the convex hull of the vertices hull_v[hull_lo[l]:hull_hi[l]] (in that
    frame).  Boxes b < len(box_c) (centre box_c[b], axes the columns of box_R[b], half
    extents box_h[b]): a link is out of reach when its spheres are, or when its hull lies
    more than ``reach`` beyond one of the box's faces (a separating direction bounds the
    distance of two convex sets from below).  Sphere bodies p at column len(box_c) + p:
    the groups body_lo[p]:body_hi[p] (group g: spheres obs_c[grp_lo[g]:grp_hi[g]], radii
    obs_r, inside the bounding sphere grp_c[g], grp_r[g])."""
    n_box = box_c.shape[0]
    n_link = link_lo.shape[0]
    centres = np.empty((sph_c.shape[0], 3))
    bounds = np.empty((n_link, 3))
    hull = np.empty((hull_v.shape[0], 3))
    placed = np.zeros(n_link, dtype=np.bool_)
    for n in range(frames.shape[0]):
        for s_link in range(n_link):
            F = frames[n, link_frame[s_link]]
            placed[s_link] = False
            for s in range(link_lo[s_link], link_hi[s_link]):
                for i in range(3):
                    centres[s, i] = (F[i, 0] * sph_c[s, 0] + F[i, 1] * sph_c[s, 1]
                                     + F[i, 2] * sph_c[s, 2] + F[i, 3])
            collide._apply(F, link_c[s_link], bounds[s_link])
        for b in range(n_box):
            out[n, b] = False
            for lk in range(n_link):
                if not collide._sphere_box(bounds[lk], reach + link_r[lk], box_c[b], box_R[b],
                                           box_h[b]):
                    continue  # every sphere of the link is out of reach
                touches = False
                for s in range(link_lo[lk], link_hi[lk]):
                    gap = 0.0
                    for j in range(3):
                        local = 0.0
                        for i in range(3):
                            local += (centres[s, i] - box_c[b, i]) * box_R[b, i, j]
                        over = abs(local) - box_h[b, j]
                        if over > 0.0:
                            gap += over * over
                    limit = reach + sph_r[s]
                    if gap <= limit * limit:
                        touches = True
                        break
                if not touches:
                    continue
                if hull_lo[lk] < hull_hi[lk]:
                    if not placed[lk]:  # the hull's vertices in the world, once
                        F = frames[n, link_frame[lk]]
                        for v in range(hull_lo[lk], hull_hi[lk]):
                            for i in range(3):
                                hull[v, i] = (F[i, 0] * hull_v[v, 0] + F[i, 1] * hull_v[v, 1]
                                              + F[i, 2] * hull_v[v, 2] + F[i, 3])
                        placed[lk] = True
                    apart = False
                    for j in range(3):
                        lo, hi = np.inf, -np.inf
                        for v in range(hull_lo[lk], hull_hi[lk]):
                            t = 0.0
                            for i in range(3):
                                t += (hull[v, i] - box_c[b, i]) * box_R[b, i, j]
                            lo = min(lo, t)
                            hi = max(hi, t)
                        if lo - box_h[b, j] > reach or -box_h[b, j] - hi > reach:
                            apart = True
                            break
                    if apart:
                        continue
                out[n, b] = True
                break
        for p in range(body_lo.shape[0]):
            hit = False
            for s in range(sph_c.shape[0]):
                for g in range(body_lo[p], body_hi[p]):
                    dx = centres[s, 0] - grp_c[g, 0]
                    dy = centres[s, 1] - grp_c[g, 1]
                    dz = centres[s, 2] - grp_c[g, 2]
                    limit = reach + sph_r[s] + grp_r[g]
                    if dx * dx + dy * dy + dz * dz > limit * limit:
                        continue  # the whole group is out of reach
                    for m in range(grp_lo[g], grp_hi[g]):
                        dx = centres[s, 0] - obs_c[m, 0]
                        dy = centres[s, 1] - obs_c[m, 1]
                        dz = centres[s, 2] - obs_c[m, 2]
                        limit = reach + sph_r[s] + obs_r[m]
                        if dx * dx + dy * dy + dz * dz <= limit * limit:
                            hit = True
                            break
                    if hit:
                        break
                if hit:
                    break
            out[n, n_box + p] = hit


_COMPILED = False


def compile_kernel() -> None:
    """Load (or compile, the first time) :func:`near_bodies` once per process, before a
    planning call's wall-clock cap starts."""
    global _COMPILED
    if not _COMPILED:
        one, ints = np.zeros(1, np.int64), np.ones(1, np.int64)
        near_bodies(np.zeros((1, 8, 3, 4)), one, one, ints, np.zeros((1, 3)), np.ones(1),
                    np.zeros((1, 3)), np.zeros(1), one, ints, np.zeros((1, 3)), np.zeros((1, 3)),
                    np.zeros((1, 3, 3)),
                    np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1), one, ints,
                    np.zeros((1, 3)), np.ones(1), one, ints, 0.0, np.zeros((1, 2), np.bool_))
        _COMPILED = True


#: what a link's bounding sphere (:func:`_bounding_spheres`) adds to its radius (metres):
#: far above the rounding of the kernel's arithmetic, so that a box it shows out of reach
#: is out of reach of each sphere as the kernel computes it
BOUND_SLACK = 1e-9


def _bounding_spheres(model, links) -> tuple[np.ndarray, np.ndarray]:
    """(L, 3) centres and (L,) radii, in each link's frame, of spheres holding every
    sphere of the links ``links`` of the sphere model ``model``."""
    centres, radii = [], []
    for link in links:
        c, r = model.centres[model.links == link], model.radii[model.links == link]
        mid = 0.5 * (c.min(axis=0) + c.max(axis=0))
        centres.append(mid)
        radii.append(float((np.linalg.norm(c - mid, axis=1) + r).max()) + BOUND_SLACK)
    return np.array(centres, float).reshape(-1, 3), np.array(radii, float)


class BoundedDistances:
    """``contacts(q) -> (d, g)`` as ``panda.distance_model(query)`` gives them, and
    :meth:`many` for several configurations at once (one compiled bound test for all)."""

    def __init__(self, panda, query: float):
        compile_kernel()
        self.panda, self.query = panda, float(query)
        c = panda.client
        self.bodies = panda.obstacles()
        self._base = np.ascontiguousarray(fast_check.base_link_frame(c, panda.body)[:3])
        self._origins = np.ascontiguousarray(spheres.panda_chain().origins[:7, :3])
        model = spheres.panda_spheres(fast_check.MARGIN,
                                      fingers=float(panda.finger_positions[0]))
        hulls = spheres.panda_hulls(fingers=float(panda.finger_positions[0]))
        links = [k for k in spheres.LINKS if k != -1]  # the base link's points are no contacts
        counts = [int((model.links == k).sum()) for k in links]
        sizes = [len(hulls[k]) for k in links]
        lo, hlo = np.cumsum([0] + counts), np.cumsum([0] + sizes)
        keep = np.concatenate([np.flatnonzero(model.links == k) for k in links])
        bound_c, bound_r = _bounding_spheres(model, links)
        self._robot = (np.array([spheres.FRAME_OF_LINK[k] for k in links], dtype=np.int64),
                       lo[:-1].astype(np.int64), lo[1:].astype(np.int64), bound_c, bound_r,
                       np.ascontiguousarray(model.centres[keep]),
                       np.ascontiguousarray(model.radii[keep]),
                       hlo[:-1].astype(np.int64), hlo[1:].astype(np.int64),
                       np.ascontiguousarray(np.concatenate([hulls[k] for k in links])))
        boxes, others, always = [], [], []
        for k, body in enumerate(self.bodies):
            box = fast_check._box_of(c, body)
            if box is not None:
                boxes.append((k, box[0], box[1]))
            elif fast_check._is_panda(c, body):
                others.append((k, *fast_check._panda_obstacle(
                    tuple(fast_check.arm_state(c, body)),
                    tuple(fast_check.base_link_frame(c, body)[:3].ravel()))))
            else:
                always.append(k)
        # other Pandas: their spheres, in groups (one per link) with bounding spheres
        first = np.cumsum([0] + [len(o[2]) for o in others])
        parts = [(lo + f, hi + f, gc, gr) for o, f in zip(others, first[:-1], strict=True)
                 for lo, hi, gc, gr in o[3]]
        groups = np.cumsum([0] + [len(o[3]) for o in others])
        self._world = (np.array([b[1][:3, 3] for b in boxes]).reshape(-1, 3),
                       np.ascontiguousarray(np.array([b[1][:3, :3] for b in boxes])
                                            .reshape(-1, 3, 3)),
                       np.array([b[2] for b in boxes], float).reshape(-1, 3),
                       np.concatenate([np.zeros((0, 3))] + [o[1] for o in others]),
                       np.concatenate([np.zeros(0)] + [o[2] for o in others]),
                       np.array([g[0] for g in parts], dtype=np.int64),
                       np.array([g[1] for g in parts], dtype=np.int64),
                       np.array([g[2] for g in parts], float).reshape(-1, 3),
                       np.array([g[3] for g in parts], float),
                       groups[:-1].astype(np.int64), groups[1:].astype(np.int64))
        #: column of the kernel's answer -> index into ``bodies``
        self._columns = np.array([b[0] for b in boxes] + [o[0] for o in others],
                                 dtype=np.int64)
        self._always = np.array(always, dtype=np.int64)

    def close_mask(self, states: np.ndarray) -> np.ndarray:
        """(N, bodies): may the body be within the query distance (plus SAFETY) of the arm
        (its base link left out) at the configuration?  False ones are certainly not."""
        states = np.ascontiguousarray(np.atleast_2d(states), dtype=float)
        frames = np.empty((len(states), 8, 3, 4))
        collide.arm_frames(states, self._base, self._origins, frames)
        near = np.empty((len(states), len(self._columns)), dtype=np.bool_)
        near_bodies(frames, *self._robot, *self._world, self.query + SAFETY, near)
        out = np.zeros((len(states), len(self.bodies)), dtype=bool)
        out[:, self._columns] = near
        out[:, self._always] = True
        return out

    def many(self, states: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """``[self(q) for q in states]``, the bodies sorted out for all rows at once."""
        empty = (np.zeros(0), np.zeros((0, 7)))
        mask = self.close_mask(states)
        bodies = np.array(self.bodies, dtype=np.int64)
        return [self.panda.distances(q, bodies[row].tolist(), self.query) if any_near
                else empty for q, row, any_near in zip(states, mask, mask.any(axis=1),
                                                       strict=True)]

    def __call__(self, q) -> tuple[np.ndarray, np.ndarray]:
        return self.many(np.asarray(q, float)[None])[0]


def bounded(model, query: float):
    """``model.distance_model(query)`` with pybullet asked only about bodies that may be
    within ``query`` (module docstring): the model's ``bounded_distance_model`` (a Panda's,
    or an empty-handed mobile arm's, is a :class:`BoundedDistances`), or its own distance
    model for robots that have none."""
    make = getattr(model, "bounded_distance_model", None)
    return make(query) if callable(make) else model.distance_model(query)
