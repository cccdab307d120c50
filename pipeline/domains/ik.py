"""The IK step every arm domain runs: reach check → IK (``domain.ik``: damped with seeded
restarts, or analytic) → the goal configuration, or the status that says why there is
none."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.domains.schemas import IK_METHODS
from pipeline.planning import Status
from pipeline.sim.panda import REACH, ik_starts, random_starts, wrist_out_of_reach


@dataclass(frozen=True)
class IKOutcome:
    q: np.ndarray | None  # a collision-free solution, or None
    checks: int  # collision checks of candidate solutions
    status: Status  # OK, NO_IK (none reached the pose) or GOAL_IN_COLLISION (all collided)
    #: a random start was drawn: another seed may give another outcome (else the outcome
    #: is a function of the pose, the scene and the check)
    seeded: bool = False

    @property
    def found(self) -> bool:
        return self.q is not None


#: the values of ``domain.ik``
METHODS = IK_METHODS


def solve_ik(arm, position, orientation, rng_seed, restarts: int,
             method: str = "damped", collides=None) -> IKOutcome:
    """A collision-free configuration of ``arm`` (anything with ``shoulder``, ``joint2``,
    ``ik`` and ``analytic_ik``: a Panda, a MobilePanda) with its TCP at
    ``position``/``orientation``.

    ``method="damped"``: pybullet's damped IK from ``restarts`` starts; the random ones
    draw from ``numpy.random.default_rng(rng_seed)``, made only when a restart needs it
    (:func:`pipeline.sim.panda.ik_starts`).  ``method="analytic"``: frankik's closed-form
    solutions, at most ``restarts`` of them collision-checked, chosen from the pose alone
    (:mod:`pipeline.sim.analytic_ik`; ``rng_seed`` is not used).

    Beyond REACH of the shoulder, NO_IK without a single IK call; the same where the wrist
    cannot be brought near enough to the shoulder for any configuration to reach the pose
    within IK's tolerances (:func:`pipeline.sim.panda.wrist_out_of_reach`: the outcome
    every IK would end with, found without running it).  Otherwise NO_IK when no restart
    reached the pose, GOAL_IN_COLLISION when every one that did collides.  ``collides(q)``:
    the collision check of a solution (None: the arm's own, pybullet's).  The outcome says
    whether a random start was drawn (``seeded``).
    """
    if np.linalg.norm(np.asarray(position) - arm.shoulder) > REACH:
        return IKOutcome(None, 0, Status.NO_IK)
    if wrist_out_of_reach(arm.joint2, position, orientation):
        return IKOutcome(None, 0, Status.NO_IK)
    seeded = False
    if method == "damped":  # Panda.ik's loop over ik_starts, in two parts: home, the others
        q, checks, reached = arm.ik(position, orientation, ik_starts(rng_seed, min(restarts, 1)),
                                    collides=collides)
        if q is None and restarts > 1:
            seeded = True
            q, more, again = arm.ik(position, orientation, random_starts(rng_seed, restarts - 1),
                                    collides=collides)
            checks, reached = checks + more, reached or again
    elif method == "analytic":
        q, checks, reached = arm.analytic_ik(position, orientation, restarts,
                                             collides=collides)
    else:
        raise ValueError(f"IK method must be one of {', '.join(METHODS)}, got {method!r}")
    if q is not None:
        return IKOutcome(q, checks, Status.OK, seeded)
    return IKOutcome(None, checks, Status.GOAL_IN_COLLISION if reached else Status.NO_IK,
                     seeded)


def settles_by_spheres(planner, fresh_contacts: bool) -> bool:
    """Whether a step before ``planner``'s call may check on the planner's sphere
    pre-check (``planner.collision=spheres``) instead of asking pybullet: only where
    pybullet's answers are a function of the configuration (fresh contacts), since under
    cached contacts a check left out could change a later answer (docs/contacts.md)."""
    return fresh_contacts and getattr(planner.settings, "collision", "exact") == "spheres"


def planner_check(planner, model, fresh_contacts: bool):
    """IK's check of a solution on ``model`` (a robot model) as ``planner`` checks it: its
    sphere pre-check with pybullet's answers under ``planner.collision=spheres``, where
    pybullet's answers are a function of the configuration (fresh contacts).  The
    planner's later call on the same model then reuses what IK settled.  None (the arm's
    own pybullet check) where a check left out could change a later answer (cached
    contacts, docs/contacts.md) or with ``collision=exact``.  The model is made when IK
    first has a solution to check."""
    if not settles_by_spheres(planner, fresh_contacts):
        return None
    made = []

    def collides(q) -> bool:
        if not made:
            made.append(planner.check_model(model))
        return not made[0].check(np.asarray(q, float)[None])[0]
    return collides
