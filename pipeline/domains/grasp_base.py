"""``grasp_base`` (paper §V-B): choose where to park a mobile Panda and how to grasp.

A Panda on a mobile base (x, y, ψ) with a box-shaped platform that collides, two fixed
tables, and per instance 20 box obstacles plus the target box at random (x, y, yaw) on the
table tops without overlaps.  Instances can be infeasible (the target boxed in or beyond
every reachable base pose).  The arm always starts at home.

A constraint θ = (base pose k, grasp g), g one of the 81 top and side grasps of grasp_arm
(9 approaches × 3 wrist rotations × 3 depths).  Feature row: (x, y, ψ, approach x, y, z,
rotation, depth).  π(ω, θ): park the base at k (the platform and the arm at home must be
collision-free), a collision-free IK solution for g's pre-grasp, then RRT-Connect (or
TrajOpt) for the arm from home with the base fixed; score = -(joint-space arm path length).

RAWPLANNER backtracks among three steps, as in the paper: (1) a collision-free base pose
drawn uniformly from the disc of radius ``reach_radius`` around the target, (2) grasps drawn
without replacement until one has a collision-free IK solution, (3) the arm path; a failed
path goes back to (2), and a base pose whose grasps are all used up goes back to (1).  The
extracted constraint is the base pose of (1) and the grasp of (2).  Base motion itself is
not planned (the paper assumes the base pose reachable from the start).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.domains.base import Domain, RawResult, require
from pipeline.domains.grasp_arm import (
    Box,
    Grasp,
    grasp_set,
    parse_box,
    parse_obstacles,
    pregrasp_pose,
    sample_obstacles,
)
from pipeline.domains.mobile_world import (
    OBSTACLE_RGBA,
    TARGET_RGBA,
    MobileScene,
    Table,
    TablePlacer,
    render_two_panels,
    sample_base_pose,
)
from pipeline.planning import PlanResult, RRTConnect, Status
from pipeline.planning.trajopt import trajopt_plan
from pipeline.sim import panda as P

TABLES = (Table((1.0, 0.0), (0.6, 1.4), 0.40), Table((-0.1, 1.05), (1.4, 0.6), 0.40))
START_POSE = np.array([0.0, -0.2, 0.0])  # where the robot is drawn at the start
STEPS = ("base", "ik", "arm_path")
#: RAWPLANNER stops after this many base-pose draws per collision-free one it asks for
RAW_DRAWS_PER_SAMPLE = 20


@dataclass
class GraspBaseConfig:
    """Schema of ``conf/domain/grasp_base.yaml``."""

    name: str = "grasp_base"
    obstacles: int = 20
    obstacle_size: list[float] = field(default_factory=lambda: [0.04, 0.10])  # edge, metres
    obstacle_height: list[float] = field(default_factory=lambda: [0.06, 0.25])
    target_size: list[float] = field(default_factory=lambda: [0.04, 0.04, 0.12])
    reach_radius: float = P.REACH  # RAWPLANNER's base-pose disc around the target, metres
    pregrasp_offset: float = 0.10
    ik_restarts: int = 10
    raw_base_samples: int = 40  # collision-free base poses RAWPLANNER tries before giving up


@dataclass(frozen=True)
class GraspBaseInstance:
    seed: int
    target: Box
    obstacles: tuple[Box, ...]


@dataclass(frozen=True)
class BaseGrasp:
    """θ: a base pose and a grasp of the target."""

    pose: np.ndarray  # (x, y, ψ)
    grasp: Grasp

    @property
    def features(self) -> np.ndarray:
        return np.concatenate([self.pose, self.grasp.features[1:]])


class GraspBaseDomain(Domain):
    name = "grasp_base"
    config_class = GraspBaseConfig
    fixed_constraints = False
    steps = STEPS

    def __init__(self, config: GraspBaseConfig, planner):
        super().__init__(config, planner)
        c = config
        if c.obstacles < 0 or c.ik_restarts < 1 or c.pregrasp_offset < 0:
            raise ValueError("domain: need obstacles >= 0, ik_restarts >= 1 and "
                             "pregrasp_offset >= 0")
        if not c.reach_radius > 0 or c.raw_base_samples < 1:
            raise ValueError("domain: need reach_radius > 0 and raw_base_samples >= 1")
        self.grasps = [g for g in grasp_set() if g.arm == 0]
        self._grasp_index = {tuple(np.round(g.features[1:], 9)): k
                             for k, g in enumerate(self.grasps)}
        self.rrt = RRTConnect(P.LOWER, P.UPPER, planner)
        self._scene: MobileScene | None = None

    @property
    def n_features(self) -> int:
        return 8

    # -- instances -------------------------------------------------------------------------
    def sample_instance(self, seed: int) -> dict:
        c = self.config
        rng = np.random.default_rng(int(seed))
        placer = TablePlacer(rng, list(TABLES))
        target = placer.place(np.asarray(c.target_size, float))
        obstacles = sample_obstacles(rng, c.obstacles, c.obstacle_size, c.obstacle_height,
                                     placer.place)
        return {"domain": self.name, "seed": int(seed), "target": target,
                "obstacles": obstacles}

    def check_instance(self, instance) -> GraspBaseInstance:
        if isinstance(instance, GraspBaseInstance):
            return instance
        seed = require(instance, "seed", int)
        target = parse_box(require(instance, "target", dict), "target")
        return GraspBaseInstance(seed, target, parse_obstacles(instance))

    # -- constraints -----------------------------------------------------------------------
    def constraint(self, constraint) -> BaseGrasp:
        """θ from its feature row (x, y, ψ, approach, rotation, depth)."""
        if isinstance(constraint, BaseGrasp):
            return constraint
        row = np.asarray(constraint, float)
        index = None
        if row.shape == (8,) and np.all(np.isfinite(row)):
            index = self._grasp_index.get(tuple(np.round(row[3:], 9)))
        if index is None:
            raise ValueError(f"grasp_base constraint {constraint!r} is not a feature row "
                             "(x, y, psi, approach x, y, z, rotation, depth) of one of the "
                             "81 grasps")
        return BaseGrasp(row[:3].copy(), self.grasps[index])

    # -- planning --------------------------------------------------------------------------
    def scene(self, inst: GraspBaseInstance) -> MobileScene:
        """The process's cached scene, loaded with ``inst``."""
        if self._scene is None:
            self._scene = MobileScene([t.box() for t in TABLES])
        self._scene.load(inst, _instance_boxes(inst))
        return self._scene

    def _plan(self, inst: GraspBaseInstance, theta: BaseGrasp, seed: int) -> PlanResult:
        robot = self.scene(inst).robot
        try:
            return self._plan_at(robot, inst, theta, seed)
        finally:  # the next call must find the arm at home
            robot.set_arm(P.HOME)

    def _plan_at(self, robot, inst: GraspBaseInstance, theta: BaseGrasp,
                 seed: int) -> PlanResult:
        robot.set_arm(P.HOME)
        if robot.base_collides(theta.pose):
            return PlanResult(Status.START_IN_COLLISION, checks=1, step="base")
        goal, checks, status = self._grasp_ik(inst, theta, seed)
        if goal is None:
            return PlanResult(status, checks=1 + checks, step="ik")
        result = self._arm_path(robot, goal, seed)
        result.checks += 1 + checks
        return result

    def _grasp_ik(self, inst, theta: BaseGrasp, seed: int):
        """(collision-free pre-grasp configuration or None, checks, failure status), with
        the base already parked at θ's pose."""
        robot = self._scene.robot
        pos, orn = pregrasp_pose(inst.target, theta.grasp, self.config.pregrasp_offset)
        if np.linalg.norm(pos - robot.arm.shoulder) > P.REACH:  # no IK can exist
            return None, 0, Status.NO_IK
        goal, checks, reached = robot.ik(pos, orn, np.random.default_rng([seed, 7]),
                                         self.config.ik_restarts)
        return goal, checks, (Status.GOAL_IN_COLLISION if reached else Status.NO_IK)

    def _arm_path(self, robot, goal, seed: int) -> PlanResult:
        if self.planner.name == "trajopt":
            result = trajopt_plan(robot.arm, P.HOME, goal, self.planner)
        else:
            result = self.rrt.plan(P.HOME, goal, self.rrt.budget(robot.arm_check), seed=seed)
        if not result.feasible:
            result.step = "arm_path"
        return result

    def raw_plan(self, instance, seed: int = 0) -> RawResult:
        """RAWPLANNER: base pose → grasp → arm path, with backtracking (module docstring)."""
        t0 = time.perf_counter()
        inst = self.check_instance(instance)
        robot = self.scene(inst).robot
        rng = np.random.default_rng([int(seed), 2])
        centre = np.asarray(inst.target.position[:2])
        checks, tries, free, draws = 0, 0, 0, 0
        plan, used = PlanResult(Status.START_IN_COLLISION, step="base"), None
        max_draws = RAW_DRAWS_PER_SAMPLE * self.config.raw_base_samples
        try:
            while used is None and free < self.config.raw_base_samples and draws < max_draws:
                pose = sample_base_pose(rng, centre, self.config.reach_radius)
                robot.set_arm(P.HOME)
                checks, draws = checks + 1, draws + 1
                if robot.base_collides(pose):
                    continue
                free += 1
                for g in rng.permutation(len(self.grasps)):
                    theta = BaseGrasp(pose, self.grasps[int(g)])
                    tries += 1
                    goal, ik_checks, status = self._grasp_ik(inst, theta, seed + tries)
                    checks += ik_checks
                    if goal is None:
                        plan = PlanResult(status, step="ik")
                        continue
                    robot.set_arm(P.HOME)
                    plan = self._arm_path(robot, goal, seed + tries)
                    checks += plan.checks
                    if plan.feasible:
                        used = theta
                        break
        finally:
            robot.set_arm(P.HOME)
        plan.checks, plan.time = checks, time.perf_counter() - t0
        row = used.features if used is not None else np.full(8, np.nan)
        return RawResult(plan=plan, constraint=row, tries=tries, time=plan.time)

    # -- inspection ------------------------------------------------------------------------
    def build_scene(self, instance) -> MobileScene:
        """A new scene (its own pybullet client) for inspection; close() it when done."""
        inst = self.check_instance(instance)
        scene = MobileScene([t.box() for t in TABLES])
        scene.load(inst, _instance_boxes(inst))
        scene.robot.set_base(START_POSE)
        return scene

    def render(self, instance, plan: PlanResult | None = None, path="grasp_base.png",
               constraint=None) -> Path:
        """Camera view of the robot at θ's base pose (at the pre-grasp when ``plan`` is
        feasible) and a floor plan with the start and θ's footprints."""
        inst = self.check_instance(instance)
        scene = self.build_scene(inst)
        poses = [(START_POSE, "0.4", "start")]
        try:
            if constraint is not None:
                theta = self.constraint(constraint)
                scene.robot.set_base(theta.pose)
                poses.append((theta.pose, "tab:green", "θ base pose"))
                if plan is not None and plan.feasible:
                    scene.robot.set_arm(plan.path[-1])
            status = "" if plan is None else f", {plan.status.name.lower()}" + (
                f" at {plan.step}" if plan.step else "")
            return render_two_panels(
                scene, f"grasp_base instance {inst.seed}{status}", path,
                eye=(-1.3, -1.7, 2.3), target=(0.5, 0.4, 0.3),
                furniture=[t.box() for t in TABLES], boxes=_instance_boxes(inst),
                poses=poses, base_path=None, extent=(-1.2, 2.0, -1.2, 1.8))
        finally:
            scene.close()


def _instance_boxes(inst: GraspBaseInstance) -> list[tuple[Box, tuple]]:
    return [(inst.target, TARGET_RGBA)] + [(b, OBSTACLE_RGBA) for b in inst.obstacles]


__all__ = ["BaseGrasp", "GraspBaseConfig", "GraspBaseDomain"]
