"""The IK step every arm domain runs: reach check → IK with seeded restarts → the goal
configuration, or the status that says why there is none."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.planning import Status
from pipeline.sim.panda import REACH, ik_starts


@dataclass(frozen=True)
class IKOutcome:
    q: np.ndarray | None  # a collision-free solution, or None
    checks: int  # collision checks of candidate solutions
    status: Status  # OK, NO_IK (none reached the pose) or GOAL_IN_COLLISION (all collided)

    @property
    def found(self) -> bool:
        return self.q is not None


def solve_ik(arm, position, orientation, rng_seed, restarts: int) -> IKOutcome:
    """A collision-free configuration of ``arm`` (anything with ``shoulder`` and ``ik``:
    a Panda, a MobilePanda's) with its TCP at ``position``/``orientation``; the random
    restarts draw from ``numpy.random.default_rng(rng_seed)``, made only when a restart
    needs it (:func:`pipeline.sim.panda.ik_starts`).

    Beyond REACH of the shoulder no solution can exist: NO_IK without a single IK call.
    Otherwise NO_IK when no restart reached the pose, GOAL_IN_COLLISION when every one that
    did collides.
    """
    if np.linalg.norm(np.asarray(position) - arm.shoulder) > REACH:
        return IKOutcome(None, 0, Status.NO_IK)
    q, checks, reached = arm.ik(position, orientation, ik_starts(rng_seed, restarts))
    if q is not None:
        return IKOutcome(q, checks, Status.OK)
    return IKOutcome(None, checks, Status.GOAL_IN_COLLISION if reached else Status.NO_IK)
