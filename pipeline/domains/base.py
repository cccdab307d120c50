"""The domain API every planning domain implements (names are a contract)."""

from __future__ import annotations

import abc
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from pipeline.planning import PlannerSettings, PlanResult, Status


class InstanceError(ValueError):
    """An instance spec with a missing or malformed field."""


@dataclass(frozen=True, eq=False)
class ConstraintSet:
    """Candidate solution constraints θ: one feature row each (DOO's metric space)."""

    features: np.ndarray  # (m, p) float
    source_instance: np.ndarray  # (m,) int: the instance a constraint came from, -1 if none

    def __post_init__(self):
        if self.features.ndim != 2 or self.source_instance.shape != self.features.shape[:1]:
            raise ValueError("ConstraintSet: features must be (m, p), source_instance (m,)")

    @property
    def m(self) -> int:
        return self.features.shape[0]


@dataclass(eq=False)
class RawResult:
    """RAWPLANNER on one instance: its plan, the constraint it ended up using (a feature
    row, NaN when it failed), how many constraints it tried and its total time."""

    plan: PlanResult
    constraint: np.ndarray
    tries: int
    time: float


class Domain(abc.ABC):
    """A family of planning problems ω and their solution constraints θ.

    Subclasses set ``name``, ``config_class`` (a dataclass, the schema of
    ``conf/domain/<name>.yaml``), ``fixed_constraints`` (True when Θ is a fixed set,
    False when it is extracted from RAWPLANNER's solutions) and ``steps``.
    """

    name: ClassVar[str]
    config_class: ClassVar[type]
    fixed_constraints: ClassVar[bool]
    #: the steps of one planning call, in order; a failed PlanResult names the one that
    #: failed in ``step`` (stored as its index in the ``step`` arrays of the store)
    steps: ClassVar[tuple[str, ...]] = ()

    def __init__(self, config, planner: PlannerSettings):
        self.config = config
        self.planner = planner

    @property
    def n_features(self) -> int:
        """Length of a constraint's feature row."""
        raise NotImplementedError

    @abc.abstractmethod
    def sample_instance(self, seed: int) -> dict[str, Any]:
        """A JSON-serialisable instance spec, fully determined by ``seed``."""

    @abc.abstractmethod
    def check_instance(self, instance: dict[str, Any]) -> Any:
        """Validate a spec; return the domain's parsed form or raise InstanceError."""

    def constraints(self, extracted: ConstraintSet | None = None) -> ConstraintSet:
        """Θ̂: the fixed set (domains with ``fixed_constraints`` override this), or the
        constraints ``extracted`` from raw solutions, less the rows of failed solves."""
        if extracted is None:
            raise ValueError(f"{self.name} constraints come from RAWPLANNER's solutions: "
                             "pass the extracted ones")
        keep = np.all(np.isfinite(extracted.features), axis=1)
        return ConstraintSet(extracted.features[keep], extracted.source_instance[keep])

    @abc.abstractmethod
    def constraint(self, constraint):
        """Validate one constraint θ (as the domain accepts it); ValueError naming it if bad."""

    def plan(self, instance, constraint, seed: int = 0) -> PlanResult:
        """π(ω, θ): one planning call.

        Bad input (the spec, the constraint) raises; a failure inside the simulator or the
        planner becomes status ``error`` so that one bad call never kills a worker.
        ``time`` covers the whole call, validation included.
        """
        t0 = time.perf_counter()
        inst = self.check_instance(instance)
        theta = self.constraint(constraint)
        try:
            result = self._plan(inst, theta, int(seed))
        except Exception as exc:  # noqa: BLE001 (an outcome, not a crash)
            result = PlanResult(Status.ERROR, error=repr(exc))
        result.time = time.perf_counter() - t0
        return result

    @abc.abstractmethod
    def _plan(self, instance, constraint, seed: int) -> PlanResult:
        """The planning call proper, on a checked instance and constraint."""

    @abc.abstractmethod
    def raw_plan(self, instance, seed: int = 0) -> RawResult:
        """RAWPLANNER: the unguided planner."""

    @abc.abstractmethod
    def build_scene(self, instance):
        """A scene with ``client_id``, ``robot_ids`` and ``set_configuration(q)``."""

    @abc.abstractmethod
    def render(self, instance, plan: PlanResult | None = None, path: str | Path = "scene.png",
               constraint=None) -> Path:
        """Write a PNG of the instance (and the plan, when given); return its path."""


def require(instance: dict, key: str, kind: type | tuple[type, ...]):
    """``instance[key]``, checked to be of ``kind``; InstanceError naming the key if not."""
    if not isinstance(instance, dict):
        raise InstanceError(f"instance spec must be a JSON object, got {type(instance).__name__}")
    if key not in instance:
        raise InstanceError(f"instance spec: missing field {key!r}")
    value = instance[key]
    if isinstance(value, bool) or not isinstance(value, kind):  # no field is boolean
        raise InstanceError(f"instance spec: field {key!r} has the wrong type "
                            f"({type(value).__name__})")
    return value


def finite_rows(value, key: str, width: int) -> np.ndarray:
    """A list of ``width``-number lists, all finite, as an (k, width) array."""
    try:
        arr = np.asarray(value, dtype=float).reshape(-1, width) if len(value) else \
            np.empty((0, width))
    except (TypeError, ValueError):
        raise InstanceError(f"instance spec: field {key!r} must be a list of "
                            f"{width}-number lists") from None
    if len(arr) != len(value) or not all(math.isfinite(x) for x in arr.ravel()):
        raise InstanceError(f"instance spec: field {key!r} must be a list of finite "
                            f"{width}-number lists")
    return arr
