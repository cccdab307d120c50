"""RAWPLANNER for pick_place: the paper's six steps with backtracking (see the package
docstring).  Grasps without replacement until one has a pick IK and a pick path (1-2); a
collision-free placement on the goal table (3); k_b from the disc around it, collision-free
with the rod carried (4); a base path start → k_b (5); the place IK and path (6).  A failure
in 4-6 draws a new k_b, then a new placement, then a new grasp."""

from __future__ import annotations

import numpy as np

from pipeline.domains.base import RawSearch
from pipeline.domains.mobile_world import sample_base_pose
from pipeline.domains.pick_place.world import (
    GOAL_TABLE,
    START_POSE,
    Route,
    in_rooms,
    on_goal_table,
    placed_rod,
    subgoal_on,
)
from pipeline.planning import PlanResult, Status


def raw_search(d, inst, seed: int) -> RawSearch:
    """The search, for ``d`` a PickPlaceDomain whose scene is loaded with ``inst``."""
    c = d.config
    rng = np.random.default_rng([seed, 2])
    checks, tries = 0, 0
    plan = PlanResult(Status.NO_IK, step="pick_ik")
    for gi in rng.permutation(len(d.grasps))[: c.raw_grasps]:
        g = d.grasps[int(gi)]
        tries += 1
        scene = d.reset(inst)
        carry, status = d.carry(inst, g)
        if carry is None:
            plan = PlanResult(status, step="carry")
            continue
        ik = d.pick_ik(inst, g, seed + tries)
        checks += ik.checks
        if not ik.found:
            plan = PlanResult(ik.status, step="pick_ik")
            continue
        pick = d.arm_motion.plan(scene.arm, d.home, ik.q, seed=seed + tries)
        checks += pick.checks
        if not pick.feasible:
            plan = _failed(pick, "pick_path")
            continue
        for _ in range(c.raw_placements):
            placement, n = _sample_placement(d, inst, rng)
            checks += n
            if placement is None:
                plan = PlanResult(Status.GOAL_IN_COLLISION, step="placement")
                continue
            found, plan, n, tries = _place(d, inst, g, carry, pick.path, placement, rng, seed,
                                           tries)
            checks += n
            if found is not None:
                return RawSearch(plan, found.features, tries, checks)
    return RawSearch(plan, None, tries, checks)


def _place(d, inst, g, carry, pick_path, placement, rng, seed, tries):
    """Steps 4-6 for one grasp and placement: (Route or None, plan, checks, tries)."""
    c, robot = d.config, d.robot
    checks, plan, free, draws = 0, PlanResult(Status.GOAL_IN_COLLISION, step="base_pose"), 0, 0
    collides = None  # the base pose check, made once the rod is held (one grasp, one carry)
    stand = _Standing(d, inst, g, carry)
    while free < c.raw_base_samples and draws < 20 * c.raw_base_samples:
        pose = sample_base_pose(rng, placement[:2], c.reach_radius)
        draws, checks = draws + 1, checks + 1
        stand.hold()
        if not in_rooms(pose):
            continue
        if collides is None:  # pybullet's answers, by geometry where it can
            stand.update()
            collides = d.base_pose_collides(prepare=stand.update)
        hit = collides(pose)
        # the robot stays at the pose, as after pybullet's check: the place IK is solved
        # there, and the placements drawn next are checked with the robot standing there
        stand.move(pose)
        if hit:
            continue
        stand.update()
        free, tries = free + 1, tries + 1
        theta = Route(g, placement, pose, START_POSE)
        ik = d.place_ik(inst, theta, seed + tries)
        checks += ik.checks
        if not ik.found:
            plan = PlanResult(ik.status, step="place_ik")
            continue
        drive = d.drive(inst, g, carry, [START_POSE, pose], seed + tries)
        checks += drive.checks
        if not drive.feasible:
            plan = _failed(drive, "base_path")
            continue
        d.hold(inst, g, carry)
        robot.set_base(pose)
        put = d.arm_motion.plan(d.scene_of().arm, carry, ik.q, seed=seed + tries)
        checks += put.checks
        if not put.feasible:
            plan = _failed(put, "place_path")
            continue
        plan = d.joined(pick_path, drive.path, put.path, carry, pose, 0)
        return Route(g, placement, pose, subgoal_on(drive.path)), plan, checks, tries
    stand.update()
    return None, plan, checks, tries


class _Standing:
    """The rod held in the carry configuration and the base moved to each pose drawn, as
    :func:`_place` does them, put off while nothing asks pybullet: most poses drawn are
    refuted by the base model's geometry, and moving the robot there (the rod placed from
    the arm's kinematics, then carried along) cost more than the rest of RAWPLANNER.  Where
    the robot stands decides later answers (the place IK, pybullet's checks of the next
    placements), so :meth:`update` makes pybullet's state exactly what doing each step
    would have made it: the last hold done where the robot stood, then the last move (a
    hold's outcome depends only on the base pose and the carry; a move's on the hold
    before it and the pose)."""

    def __init__(self, d, inst, g, carry):
        self.d, self.inst, self.g, self.carry = d, inst, g, carry
        #: None: pybullet is up to date; else (base pose of the last hold, pose moved to
        #: after it or None)
        self.pending = None
        self.held_at = None

    def hold(self) -> None:
        if self.pending is None:
            self.d.hold(self.inst, self.g, self.carry)
            self.held_at = self.d.robot.pose.copy()
        else:
            held_at, moved_to = self.pending
            self.held_at = held_at if moved_to is None else moved_to
            self.pending = (self.held_at, None)

    def move(self, pose) -> None:
        self.pending = (self.held_at, np.asarray(pose, float).copy())

    def update(self) -> None:
        """pybullet's state brought to what the steps put off would have made it."""
        if self.pending is None:
            return
        held_at, moved_to = self.pending
        self.pending = None
        robot = self.d.robot
        robot.set_base(held_at)
        self.d.hold(self.inst, self.g, self.carry)
        if moved_to is not None:
            robot.set_base(moved_to)


def _sample_placement(d, inst, rng, draws: int = 30):
    """A collision-free rod pose (x, y, yaw) on the goal table, or None; and the draws."""
    t = GOAL_TABLE
    scene = d.scene_of()
    for k in range(1, draws + 1):
        yaw = rng.uniform(-np.pi, np.pi)
        xy = rng.uniform(np.subtract(t.centre, np.divide(t.size, 2)),
                         np.add(t.centre, np.divide(t.size, 2)))
        placement = np.round(np.array([xy[0], xy[1], yaw]), 6)
        if not on_goal_table(inst.rod_length, placement):
            continue
        scene.put_rod(placed_rod(inst.rod_length, placement))
        if not scene.rod_collides():
            return placement, k
    return None, draws


def _failed(result: PlanResult, step: str) -> PlanResult:
    result.step = step
    return result
