"""What one planning call π(ω, θ) returns."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np


class Status(enum.IntEnum):
    """Outcome of one planning call; stored in Zarr as its integer code."""

    OK = 0
    NO_IK = 1
    GOAL_IN_COLLISION = 2  # the configuration the constraint asks for collides
    START_IN_COLLISION = 3
    BUDGET_EXHAUSTED = 4  # the collision-check budget ran out before a path was found
    TIMEOUT = 5  # the wall-clock safety net fired (the only machine-dependent outcome)
    ERROR = 6  # the simulator or planner raised; the message is in PlanResult.error
    SKIPPED = 7  # the no-op planner: nothing was planned
    NOT_CONVERGED = 8  # trajopt: in collision, still inside the margin when iterations ran out
    PATH_IN_COLLISION = 9  # trajopt: clear of the margin where it looked (waypoints and
    #                        segment midpoints), but in collision under the dense re-check

    @classmethod
    def names(cls) -> list[str]:
        return [s.name.lower() for s in cls]


@dataclass(eq=False)
class PlanResult:
    """One planning call: ``feasible`` iff ``status`` is OK; score = -length."""

    status: Status
    path: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    length: float = float("nan")
    checks: int = 0
    time: float = 0.0
    error: str = ""
    step: str = ""  # the domain's step that failed (Domain.steps); "" when none or feasible
    #: named parts of ``path`` for plans made of several motions (pick_place), in order
    segments: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def feasible(self) -> bool:
        return self.status is Status.OK

    @property
    def score(self) -> float:
        return -self.length if self.feasible else float("nan")


def path_length(path: np.ndarray) -> float:
    """Euclidean length of a piecewise-linear path through configuration space."""
    path = np.asarray(path, float)
    if len(path) < 2:
        return 0.0
    step = path[1:] - path[:-1]  # np.linalg.norm(np.diff(path, axis=0), axis=1), the same
    return float(np.sqrt(np.add.reduce(step * step, axis=1)).sum())  # numbers, less overhead
