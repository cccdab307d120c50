"""Analytic Panda IK (``domain.ik=analytic``) through the ``frankik`` package.

Why: pybullet's damped IK is iterative.  Each restart costs about 0.5 ms and a pose that
no restart reaches costs every restart, so in grasp_arm IK was 44 % of an entry.  With
joint 7 fixed the Panda's other six joints have closed-form solutions (frankik, after He
and Liu 2021): every solution on a grid of joint-7 angles costs tens of microseconds, and a
pose without any is known as such at once.  The solutions differ from the damped IK's, so
D differs too: the setting is part of a store's identity (pipeline.configs.LATER_KEYS).

What :func:`solve` does with them:

* frame: frankik solves for the flange (panda_link8) in the arm's base-link frame; the
  domains give the TCP (panda_grasptarget, 0.105 m past the flange, turned -45° about z)
  in the world.  frankik's own hand offset is 0.1034 m, so it is not used: the target is
  ``inv(base link) · T_tcp · inv(flange → TCP of the URDF)``.
* candidates: every solution on frankik's joint-7 grid (fixed: laid around HOME's joint 7),
  within the URDF's joint limits, ordered by their distance to HOME (the start of every
  arm path), the grid's order breaking ties.  The order depends on the pose alone, never on
  a seed or a process, so the same entry gets the same solution anywhere.
* tries: at most ``tries`` of them are collision-checked (``ik_restarts``: the damped
  path's restarts), in that order, skipping a candidate within ``SPREAD`` rad (every joint)
  of one already found colliding: its neighbours on the grid nearly always collide too.
* each candidate is confirmed with pybullet's own forward kinematics (``pos_tol``,
  ``ang_tol``: the damped path's tolerances) before it is checked, so a returned
  configuration satisfies the pose exactly as the damped path's do.

The outcome has the damped path's meaning: (a collision-free solution or None, the
collision checks used, whether any solution reached the pose).
"""

from __future__ import annotations

import functools

import numpy as np
import pybullet as pb

from pipeline.sim import panda as P
from pipeline.sim.transforms import pose_matrix

#: frankik's joint-7 grid: SAMPLES angles over SAMPLE_DEGREES around HOME's joint 7
SAMPLES = 60
SAMPLE_DEGREES = 330.0
#: a collision-checked candidate's neighbours closer than this (rad, every joint) are skipped
SPREAD = 0.3


@functools.cache
def _flange_to_tcp_inverse() -> np.ndarray:
    """inv(flange → TCP) of the URDF the simulator loads."""
    from pipeline.sim import spheres

    offsets = spheres.fixed_offsets()
    return np.linalg.inv(np.linalg.inv(offsets[7]) @ offsets[P.TCP_LINK])


def _solutions(flange: np.ndarray) -> np.ndarray:
    """Every solution (k, 7) frankik finds for the flange pose ``flange`` (base-link frame),
    within the URDF's limits, nearest to HOME first."""
    import frankik

    sols = frankik.ik_sample_q7(flange, P.HOME, sample_size=SAMPLES,
                                sample_interval=SAMPLE_DEGREES, full_ik=True)
    if not len(sols):
        return np.zeros((0, 7))
    Q = np.asarray(sols, float).reshape(len(sols), 7)
    Q = Q[np.isfinite(Q).all(axis=1) & (Q >= P.LOWER).all(axis=1) & (Q <= P.UPPER).all(axis=1)]
    order = np.argsort(np.linalg.norm(Q - P.HOME, axis=1), kind="stable")
    return Q[order]


def candidates(panda, position, orientation) -> np.ndarray:
    """The candidate solutions (k, 7) of ``panda`` (a :class:`pipeline.sim.panda.Panda`
    where it stands now) for the TCP at ``position``/``orientation`` (x, y, z, w), in the
    order :func:`solve` tries them."""
    R = np.asarray(pb.getMatrixFromQuaternion(list(orientation))).reshape(3, 3)
    tcp = pose_matrix(position, R)
    return _solutions(_base_inverse(panda.client, panda.body) @ tcp @ _flange_to_tcp_inverse())


def _base_inverse(client: int, body: int) -> np.ndarray:
    """inv(the arm's base-link frame) where the arm stands now (a mobile base moves it),
    remembered per pose: pybullet reports the base's inertial frame, and the URDF frame is
    that times inv(the inertial offset), :func:`pipeline.sim.fast_check.base_link_frame`."""
    key = (client, body, *pb.getBasePositionAndOrientation(body, physicsClientId=client))
    inverse = _BASES.get(key)
    if inverse is None:
        from pipeline.sim.fast_check import base_link_frame

        if len(_BASES) > 256:
            _BASES.clear()
        inverse = _BASES[key] = np.linalg.inv(base_link_frame(client, body))
    return inverse


_BASES: dict[tuple, np.ndarray] = {}


def solve(panda, position, orientation, tries: int, collides,
          pos_tol: float = P.IK_POS_TOL,
          ang_tol: float = P.IK_ANG_TOL) -> tuple[np.ndarray | None, int, bool]:
    """(a collision-free solution reaching the pose or None, collision checks used, whether
    any solution reached it); ``collides(q)`` is the check (module docstring)."""
    Q = candidates(panda, position, orientation)
    free = np.ones(len(Q), dtype=bool)  # not yet tried nor near a colliding one
    checks = 0
    while checks < tries and free.any():
        k = int(np.argmax(free))
        q, free[k] = Q[k], False
        pos, orn = panda.tcp_pose(q)
        if np.linalg.norm(pos - position) > pos_tol or P._angle(orn, orientation) > ang_tol:
            continue
        checks += 1
        if not collides(q):
            return q, checks, True
        free &= np.abs(Q - q).max(axis=1) >= SPREAD
    return None, checks, checks > 0
