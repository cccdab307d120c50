"""The steps of one π call in pick_place, each a :class:`Step` that declares what it needs
from earlier steps and what it provides (fields of :class:`Progress`).  The configured
order (``step_order``) runs them until the first fails; an order that runs a step before
one it needs is refused when the domain is made."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from pipeline.domains.pick_place.world import (
    Route,
    on_goal_table,
    placed_rod,
)
from pipeline.planning import PlanResult, Status


@dataclass
class Progress:
    """What the steps of one call have found so far, and the collision checks they used."""

    checks: int = 0
    carry: np.ndarray | None = None  # the arm's carry configuration for θ's grasp
    pre: np.ndarray | None = None  # the pick IK solution (pre-grasp at the start)
    place: np.ndarray | None = None  # the place IK solution at k_b
    pick_path: np.ndarray | None = None  # arm path home → pre
    base_path: np.ndarray | None = None  # base path start → k_sg → k_b, (x, y, ψ)
    place_path: np.ndarray | None = None  # arm path carry → place


@dataclass(frozen=True)
class Step:
    """``run(d, inst, theta, seed, progress)`` (``d`` the PickPlaceDomain) fills
    ``provides`` and adds its checks to ``progress``; it returns None, or the failed
    PlanResult."""

    name: str
    needs: tuple[str, ...]
    provides: tuple[str, ...]
    run: Callable[..., PlanResult | None]


def _carry(d, inst, theta: Route, seed: int, p: Progress):
    """Cached per grasp and rod length, so its IK checks are not charged to entries."""
    p.carry, status = d.carry(inst, theta.grasp)
    return None if p.carry is not None else PlanResult(status)


def _placement(d, inst, theta: Route, seed: int, p: Progress):
    scene = d.reset(inst)
    scene.put_rod(placed_rod(inst.rod_length, theta.placement))
    p.checks += 1
    if not on_goal_table(inst.rod_length, theta.placement) or scene.rod_collides():
        return PlanResult(Status.GOAL_IN_COLLISION)
    return None


def _base_pose(d, inst, theta: Route, seed: int, p: Progress):
    d.hold(inst, theta.grasp, p.carry)
    collides = d.base_pose_collides()
    for pose, status in ((theta.subgoal, Status.START_IN_COLLISION),
                         (theta.place_pose, Status.GOAL_IN_COLLISION)):
        p.checks += 1
        if collides(pose):
            return PlanResult(status)
    return None


def _place_ik(d, inst, theta: Route, seed: int, p: Progress):
    d.reset(inst)
    d.hold(inst, theta.grasp, p.carry)
    d.robot.set_base(theta.place_pose)
    ik = d.place_ik(inst, theta, seed)
    p.place, p.checks = ik.q, p.checks + ik.checks
    return None if ik.found else PlanResult(ik.status)


def _pick_ik(d, inst, theta: Route, seed: int, p: Progress):
    d.reset(inst)
    ik = d.pick_ik(inst, theta.grasp, seed)
    p.pre, p.checks = ik.q, p.checks + ik.checks
    return None if ik.found else PlanResult(ik.status)


def _pick_path(d, inst, theta: Route, seed: int, p: Progress):
    scene = d.reset(inst)
    result = d.arm_motion.plan(scene.arm, d.home, p.pre, seed=2 * seed)
    p.pick_path = result.path
    return _charged(p, result)


def _place_path(d, inst, theta: Route, seed: int, p: Progress):
    scene = d.reset(inst)
    d.hold(inst, theta.grasp, p.carry)
    d.robot.set_base(theta.place_pose)
    result = d.arm_motion.plan(scene.arm, p.carry, p.place, seed=2 * seed + 1)
    p.place_path = result.path
    return _charged(p, result)


def _base_path(d, inst, theta: Route, seed: int, p: Progress):
    result = d.drive(inst, theta.grasp, p.carry, [d.start_pose, theta.subgoal,
                                                  theta.place_pose], seed)
    p.base_path = result.path
    return _charged(p, result)


def _charged(p: Progress, result: PlanResult) -> PlanResult | None:
    p.checks += result.checks
    return None if result.feasible else result


#: every step, in the order of the domain's ``steps`` (the store's step indices)
STEPS = {s.name: s for s in (
    Step("carry", (), ("carry",), _carry),
    Step("placement", (), (), _placement),
    Step("base_pose", ("carry",), (), _base_pose),
    Step("place_ik", ("carry",), ("place",), _place_ik),
    Step("pick_ik", (), ("pre",), _pick_ik),
    Step("pick_path", ("pre",), ("pick_path",), _pick_path),
    Step("place_path", ("carry", "place"), ("place_path",), _place_path),
    Step("base_path", ("carry",), ("base_path",), _base_path),
)}

#: the orders π can run its steps in (``step_order``): the paper's, motion by motion, where
#: a bad θ shows only late and is expensive to refute; or the cheap checks first
ORDERS = {"paper": ("pick_ik", "pick_path", "carry", "base_pose", "base_path", "placement",
                    "place_ik", "place_path"),
          "cheap_first": tuple(STEPS)}

_FIELDS = {f.name for f in fields(Progress)}


def check_order(order: tuple[str, ...]) -> None:
    """ValueError unless ``order`` runs every step once, each after those it needs."""
    if sorted(order) != sorted(STEPS):
        raise ValueError(f"pick_place step order {order} must run each of {tuple(STEPS)} once")
    have: set[str] = set()
    for name in order:
        step = STEPS[name]
        missing = [k for k in step.needs if k not in have]
        if missing:
            raise ValueError(f"pick_place step {name!r} needs {', '.join(missing)}, which "
                             "no earlier step provides")
        assert set(step.provides) <= _FIELDS
        have.update(step.provides)


def run_steps(d, inst, theta: Route, seed: int, order) -> PlanResult:
    """Run the steps in ``order``; the first that fails ends the call (its result names
    the step and carries the checks of all steps run)."""
    p = Progress()
    for name in order:
        failed = STEPS[name].run(d, inst, theta, seed, p)
        if failed is not None:
            failed.checks, failed.step = p.checks, name
            return failed
    return d.joined(p.pick_path, p.base_path, p.place_path, p.carry, theta.place_pose,
                    p.checks)
