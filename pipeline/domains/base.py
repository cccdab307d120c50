"""The domain API every planning domain implements (names are a contract; see
docs/architecture.md)."""

from __future__ import annotations

import abc
import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from pipeline.domains.specs import InstanceError, finite_rows, require
from pipeline.planning import PlannerSettings, PlanResult, Status
from pipeline.planning.registry import make_planner, plans_nothing
from pipeline.planning.resumable import PlanningTry, WholeTry

__all__ = ["ConstraintSet", "Domain", "EntryTry", "Feature", "InstanceError", "RawResult",
           "RawSearch", "constraint_row", "finite_rows", "require"]


@dataclass(frozen=True)
class Feature:
    """One entry of a constraint's feature row (the store's ``feature`` coordinate) or of
    an instance's (``instance_feature``), with its UDUNITS units ("1": a number without
    units)."""

    name: str
    units: str
    description: str


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


@dataclass(eq=False)
class RawSearch:
    """What a domain's RAWPLANNER search found: the last plan, the feature row of the
    constraint it used (None when it failed), constraints tried, checks in all."""

    plan: PlanResult
    constraint: np.ndarray | None
    tries: int
    checks: int


class Domain(abc.ABC):
    """A family of planning problems ω and their solution constraints θ.

    Subclasses set ``name``, ``fixed_constraints`` (True when Θ is a fixed set,
    False when it is extracted from RAWPLANNER's solutions), ``steps``, ``theta_features``
    and ``length_units``, and get their planners from :meth:`planner_for` (never by the
    planner's name).  A domain's config schema (a dataclass) is declared apart, in a module
    that loads no simulator, and names the subclass (:mod:`pipeline.domains`).
    """

    name: ClassVar[str]
    fixed_constraints: ClassVar[bool]
    #: the steps of one planning call, in order; a failed PlanResult names the one that
    #: failed in ``step`` (stored as its index in the ``step`` arrays of the store)
    steps: ClassVar[tuple[str, ...]] = ()
    #: what each entry of a constraint's feature row is (the store's ``feature`` coordinate)
    theta_features: ClassVar[tuple[Feature, ...]]
    #: what each entry of an instance's feature vector is (:meth:`instance_features`; the
    #: store's ``instance_feature`` coordinate); none by default
    omega_features: ClassVar[tuple[Feature, ...]] = ()
    #: UDUNITS units of a path length (and so of a score, its negative)
    length_units: ClassVar[str]
    #: what a path length measures, for the store's ``long_name`` of ``length``
    length_name: ClassVar[str] = "path length"

    def __init__(self, config, planner: PlannerSettings):
        self.config = config
        self.planner = planner
        #: the planner plans nothing: every π call is "skipped" (RAWPLANNER still plans)
        self.skips_plans = plans_nothing(planner)

    def planner_for(self, robot, **settings):
        """The configured planner for ``robot`` (a robot model class), with ``settings``
        overriding the planner's; refused with one message if the robot lacks what the
        planner needs."""
        chosen = dataclasses.replace(self.planner, **settings) if settings else self.planner
        return make_planner(chosen, robot)

    @property
    def n_features(self) -> int:
        """Length of a constraint's feature row."""
        return len(self.theta_features)

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

    @property
    def n_instance_features(self) -> int:
        """Length of an instance's feature vector (0: the domain declares none)."""
        return len(self.omega_features)

    def instance_features(self, instance) -> np.ndarray:
        """(q,) float64: the features ``omega_features`` names, of an instance (a spec or a
        checked one), a deterministic function of the spec (no simulator, no randomness):
        what a selector may learn from besides the scores.  ValueError if the domain's
        :meth:`_instance_features` gives other than q finite numbers."""
        inst = self.check_instance(instance)
        if not self.omega_features:
            return np.zeros(0)
        values = np.asarray(self._instance_features(inst), dtype=np.float64)
        if values.shape != (self.n_instance_features,) or not np.all(np.isfinite(values)):
            raise ValueError(f"{self.name}: instance features must be "
                             f"{self.n_instance_features} finite numbers, got {values!r}")
        return values

    def instance_feature_rows(self, specs) -> np.ndarray:
        """(n, q) the features of instances given as specs (dicts or their JSON text, as
        the store holds them)."""
        return np.stack([self.instance_features(json.loads(s) if isinstance(s, str) else s)
                         for s in specs]).reshape(len(specs), self.n_instance_features)

    def _instance_features(self, instance) -> np.ndarray:
        """The features of a checked instance (a domain that declares ``omega_features``
        computes them here)."""
        raise NotImplementedError(f"{self.name} declares instance features but does not "
                                  "compute them")

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
        if self.skips_plans:
            result = PlanResult(Status.SKIPPED)
        else:
            result = self.attempt(inst, theta, int(seed))
        result.time = time.perf_counter() - t0
        return result

    def start_try(self, instance, constraint, seed: int = 0) -> PlanningTry:
        """π(ω, θ) as a try (:mod:`pipeline.planning.resumable`): ``advance(allowance)``
        goes on until the call has used ``allowance`` checks in all (the ``checks`` its
        result reports), and the result is :meth:`plan`'s however the checks are sliced.

        (Not ``start``: that name is the planar domain's start configuration.)  Bad input
        raises here, as in :meth:`plan`.  A domain whose call can pause returns
        its own try from :meth:`_start`; this default cannot pause and makes the whole
        call in the first advance, whatever the allowance.
        """
        inst = self.check_instance(instance)
        theta = self.constraint(constraint)
        entry = None if self.skips_plans else self._start(inst, theta, int(seed))
        if entry is None:
            return WholeTry(lambda: self.plan(instance, constraint, seed))
        return entry

    def _start(self, instance, constraint, seed: int) -> EntryTry | None:
        """The domain's resumable try of π on a checked instance and constraint, or None
        (the whole call in the first advance)."""
        return None

    def attempt(self, inst, theta, seed: int) -> PlanResult:
        """π on a checked instance and constraint, a raised failure turned into ``error``
        (RAWPLANNER's searches call this)."""
        try:
            return self._plan(inst, theta, seed)
        except Exception as exc:  # noqa: BLE001 (an outcome, not a crash)
            return PlanResult(Status.ERROR, error=repr(exc))

    @abc.abstractmethod
    def _plan(self, instance, constraint, seed: int) -> PlanResult:
        """The planning call proper, on a checked instance and constraint."""

    def raw_plan(self, instance, seed: int = 0) -> RawResult:
        """RAWPLANNER: the unguided planner (the domain's :meth:`_raw_search`), its time
        and checks in all, and the constraint it used as a feature row (NaN if none)."""
        t0 = time.perf_counter()
        inst = self.check_instance(instance)
        found = self._raw_search(inst, int(seed))
        plan = found.plan
        plan.checks, plan.time = found.checks, time.perf_counter() - t0
        row = (np.full(self.n_features, np.nan) if found.constraint is None
               else np.asarray(found.constraint, float))
        return RawResult(plan=plan, constraint=row, tries=found.tries, time=plan.time)

    @abc.abstractmethod
    def _raw_search(self, instance, seed: int) -> RawSearch:
        """RAWPLANNER's search on a checked instance."""

    @abc.abstractmethod
    def recheck(self, instance, constraint, plan: PlanResult) -> dict[str, bool]:
        """Re-check each motion of a feasible ``plan`` of π(instance, constraint) in a fresh
        scene with the domain's exact robot model, every state at the resolution it was
        planned at (:func:`pipeline.planning.path_is_free`): {motion: free}, plus any
        other condition a solution must meet.  The contract suite's check that a planner
        returns collision-free paths, independent of the checks the planner made."""

    def check_limit(self) -> int:
        """The most collision checks one planning call may report: one budget of
        ``planner.max_checks`` shared by the call's motions (a domain whose steps check
        more, such as IK solutions or further budgets, says how many)."""
        return self.planner.max_checks

    @abc.abstractmethod
    def build_scene(self, instance):
        """A scene with ``client_id``, ``robot_ids`` and ``set_configuration(q)``; the
        caller closes it (``close()``) when it has one."""

    @abc.abstractmethod
    def render(self, instance, plan: PlanResult | None = None, path: str | Path = "scene.png",
               constraint=None) -> Path:
        """Write a PNG of the instance (and the plan, when given); return its path."""

    def close(self) -> None:
        """Release simulator clients this domain holds (its cached scene); it may be used
        again afterwards (a new client is made then)."""
        return None


class EntryTry(PlanningTry):
    """A domain's resumable π call (:meth:`Domain._start`): a raised failure becomes status
    ``error``, as in :meth:`Domain.attempt`.  Subclasses implement :meth:`_slice`."""

    def _advance(self, allowance, now) -> PlanResult | None:
        try:
            return self._slice(allowance)
        except Exception as exc:  # noqa: BLE001 (an outcome, not a crash)
            return PlanResult(Status.ERROR, error=repr(exc))

    @abc.abstractmethod
    def _slice(self, allowance: int | None) -> PlanResult | None:
        """Go on until ``allowance`` checks in all (None: to the end); None when paused."""


def constraint_row(constraint, domain: str) -> np.ndarray:
    """``constraint`` as a float array; ValueError naming the constraint if it is not
    numbers (the domain then checks its shape and values)."""
    try:
        return np.asarray(constraint, float)
    except (TypeError, ValueError):
        raise ValueError(f"{domain} constraint {constraint!r} is not a row of numbers") from None
