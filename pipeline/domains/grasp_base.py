"""``grasp_base`` (paper §V-B): choose where to park a mobile Panda and how to grasp.

A Panda on a mobile base (x, y, ψ) with a box-shaped platform that collides, two fixed
tables, and per instance 20 box obstacles plus the target box at random (x, y, yaw) on the
table tops without overlaps.  Instances can be infeasible (the target boxed in or beyond
every reachable base pose).  The arm always starts at home.

A constraint θ = (base pose k, grasp g), g one of the 81 top and side grasps of grasp_arm
(9 approaches × 3 wrist rotations × 3 depths).  Feature row: (x, y, ψ, approach x, y, z,
rotation, depth).  π(ω, θ): park the base at k (the platform and the arm at home must be
collision-free), a collision-free IK solution for g's pre-grasp, then the configured planner
(RRT-Connect or TrajOpt; both check the arm, the platform and the world the same way) for
the arm from home with the base fixed; score = -(joint-space arm path length).

RAWPLANNER backtracks among three steps, as in the paper: (1) a collision-free base pose
drawn uniformly from the disc of radius ``reach_radius`` around the target, (2) grasps drawn
without replacement until one has a collision-free IK solution, (3) the arm path; a failed
path goes back to (2), and a base pose whose grasps are all used up goes back to (1).  The
extracted constraint is the base pose of (1) and the grasp of (2).  Base motion itself is
not planned (the paper assumes the base pose reachable from the start).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.domains import features as F
from pipeline.domains.base import Domain, EntryTry, Feature, RawSearch, constraint_row
from pipeline.domains.geometry import Box, sample_obstacles
from pipeline.domains.grasps import GRASP_FEATURES, Grasp, grasp_set, pregrasp_pose
from pipeline.domains.ik import solve_ik
from pipeline.domains.mobile_world import (
    OBSTACLE_RGBA,
    TARGET_RGBA,
    MobileScene,
    Table,
    TablePlacer,
    render_two_panels,
    sample_base_pose,
)
from pipeline.domains.schemas import GraspBaseConfig
from pipeline.domains.specs import parse_box, parse_obstacles, require
from pipeline.planning import PlanResult, Status, path_is_free
from pipeline.sim import panda as P
from pipeline.sim.mobile import UnladenArm

TABLES = (Table((1.0, 0.0), (0.6, 1.4), 0.40), Table((-0.1, 1.05), (1.4, 0.6), 0.40))
START_POSE = np.array([0.0, -0.2, 0.0])  # where the robot is drawn at the start
STEPS = ("base", "ik", "arm_path")
#: The instance features (GraspBaseDomain._instance_features): the target's pose on its
#: table and what is near it (gaps between box surfaces, 0: touching).
INSTANCE_FEATURES = (
    Feature("target_x", "m", "target centre x"),
    Feature("target_y", "m", "target centre y"),
    Feature("target_yaw_cos", "1", "cosine of the target's yaw"),
    Feature("target_yaw_sin", "1", "sine of the target's yaw"),
    Feature("table", "1", "the target's table: 0 the one ahead of the start (x = 1), 1 the "
                          "one to its left (y = 1.05)"),
    Feature("edge_distance", "m", "distance from the target's centre to the nearest edge "
                                  "of its table (how far the arm reaches over the table)"),
    Feature("obstacles", "1", "number of obstacles"),
    Feature("nearest_gap", "m", "gap between the target and the nearest obstacle (box "
                                f"surface to box surface; {F.GAP_CAP:g} when none is nearer)"),
    *(Feature(f"obstacles_within_{round(r * 100)}cm", "1",
              f"obstacles whose gap to the target is at most {r:g} m") for r in F.NEAR),
)
#: RAWPLANNER stops after this many base-pose draws per collision-free one it asks for
RAW_DRAWS_PER_SAMPLE = 20


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
    fixed_constraints = False
    steps = STEPS
    theta_features = (Feature("base_x", "m", "base position x"),
                      Feature("base_y", "m", "base position y"),
                      Feature("base_yaw", "rad", "base heading ψ"), *GRASP_FEATURES)
    length_units = "rad"
    length_name = "joint-space path length of the arm"
    omega_features = INSTANCE_FEATURES

    def __init__(self, config: GraspBaseConfig, planner):
        super().__init__(config, planner)
        self.grasps = [g for g in grasp_set() if g.arm == 0]
        self._grasp_index = {tuple(np.round(g.features[1:], 9)): k
                             for k, g in enumerate(self.grasps)}
        self.motion = self.planner_for(UnladenArm)
        self._scene: MobileScene | None = None


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

    def _instance_features(self, inst: GraspBaseInstance) -> np.ndarray:
        t = inst.target
        table = F.region_of(t.position, [t.area() for t in TABLES])
        return np.array([t.position[0], t.position[1], *F.yaw_features(t.yaw), table,
                         TABLES[table].edge_distance(t.position), len(inst.obstacles),
                         *F.nearby(t, inst.obstacles)])

    # -- constraints -----------------------------------------------------------------------
    def constraint(self, constraint) -> BaseGrasp:
        """θ from its feature row (x, y, ψ, approach, rotation, depth)."""
        if isinstance(constraint, BaseGrasp):
            return constraint
        row = constraint_row(constraint, self.name)
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
        """The domain's scene (one pybullet client, made on first use), loaded with
        ``inst``."""
        if self._scene is None:
            self._scene = MobileScene([t.box() for t in TABLES], self.config.contacts)
        self._scene.load(inst, _instance_boxes(inst))
        return self._scene

    def close(self) -> None:
        if self._scene is not None:
            self._scene.close()
            self._scene = None

    def _plan(self, inst: GraspBaseInstance, theta: BaseGrasp, seed: int) -> PlanResult:
        robot = self.scene(inst).robot
        try:
            return self._plan_at(robot, inst, theta, seed)
        finally:  # the next call must find the arm at home
            robot.set_arm(P.HOME)

    def _plan_at(self, robot, inst: GraspBaseInstance, theta: BaseGrasp,
                 seed: int) -> PlanResult:
        return GraspBaseTry(self, inst, theta, seed).step(robot, None)

    def _start(self, inst: GraspBaseInstance, theta: BaseGrasp,
               seed: int) -> GraspBaseTry | None:
        return GraspBaseTry(self, inst, theta, seed) if self.motion.resumable else None

    def _grasp_ik(self, robot, inst, theta: BaseGrasp, seed: int):
        """The IK step for θ's pre-grasp, the base already parked at θ's pose."""
        pos, orn = pregrasp_pose(inst.target, theta.grasp, self.config.pregrasp_offset)
        return solve_ik(robot, pos, orn, [seed, 7], self.config.ik_restarts, self.config.ik)

    def _arm_path(self, robot, goal, seed: int) -> PlanResult:
        result = self.motion.plan(UnladenArm(robot), P.HOME, goal, seed=seed)
        if not result.feasible:
            result.step = "arm_path"
        return result

    def _raw_search(self, inst: GraspBaseInstance, seed: int) -> RawSearch:
        """Base pose → grasp → arm path, with backtracking (module docstring)."""
        robot = self.scene(inst).robot
        rng = np.random.default_rng([seed, 2])
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
                    ik = self._grasp_ik(robot, inst, theta, seed + tries)
                    checks += ik.checks
                    if not ik.found:
                        plan = PlanResult(ik.status, step="ik")
                        continue
                    robot.set_arm(P.HOME)
                    plan = self._arm_path(robot, ik.q, seed + tries)
                    checks += plan.checks
                    if plan.feasible:
                        used = theta
                        break
        finally:
            robot.set_arm(P.HOME)
        return RawSearch(plan, None if used is None else used.features, tries, checks)

    # -- inspection ------------------------------------------------------------------------
    def check_limit(self) -> int:
        """The base pose's check, one per IK solution tried and the arm path's budget."""
        return 1 + self.config.ik_restarts + self.planner.max_checks

    def recheck(self, instance, constraint, plan: PlanResult) -> dict[str, bool]:
        """The arm path home → pre-grasp, the base parked at θ's pose."""
        scene = self.build_scene(instance)
        try:
            scene.robot.set_base(self.constraint(constraint).pose)
            return {"arm_path": path_is_free(plan.path, scene.robot.arm_check,
                                             self.planner.resolution)}
        finally:
            scene.close()

    def build_scene(self, instance) -> MobileScene:
        """A new scene (its own pybullet client) for inspection; close() it when done."""
        inst = self.check_instance(instance)
        scene = MobileScene([t.box() for t in TABLES], self.config.contacts)
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


class GraspBaseTry(EntryTry):
    """π(ω, θ) of grasp_base in slices: parking the base (one check) and the IK step run
    whole in the first slice (their checks count towards the allowance like the
    planner's), then the arm path is the motion planner's try, resumed slice after slice.
    Other calls may use the domain's scene between two slices: each later slice loads the
    instance again (a no-op when it is still loaded), parks the base at θ's pose again and,
    when the scene was rebuilt or reloaded, remakes the robot model the planner checks on
    (the same answers)."""

    def __init__(self, domain: GraspBaseDomain, inst: GraspBaseInstance, theta: BaseGrasp,
                 seed: int):
        super().__init__()
        self.domain, self.inst, self.theta, self.seed = domain, inst, theta, seed
        self.before_path = 0  # checks of the base and IK steps
        self.search = None  # the arm path's planning try, once IK found a goal
        self._scene_key = None

    def _slice(self, allowance):
        scene = self.domain.scene(self.inst)
        robot = scene.robot
        key = (scene, scene.loads)  # the scene object itself: a new one may reuse its id()
        try:
            if self.search is not None:
                robot.set_base(self.theta.pose)
                if key != self._scene_key:
                    self.search.rebind(UnladenArm(robot))
            self._scene_key = key
            return self.step(robot, allowance)
        finally:  # the next call must find the arm at home
            robot.set_arm(P.HOME)

    def step(self, robot, allowance: int | None) -> PlanResult | None:
        """Base and IK (first time only), then the arm path until ``allowance`` checks in
        all."""
        if self.search is None:
            robot.set_arm(P.HOME)
            if robot.base_collides(self.theta.pose):
                return PlanResult(Status.START_IN_COLLISION, checks=1, step="base")
            ik = self.domain._grasp_ik(robot, self.inst, self.theta, self.seed)
            if not ik.found:
                return PlanResult(ik.status, checks=1 + ik.checks, step="ik")
            self.before_path = 1 + ik.checks
            self.search = self.domain.motion.start(UnladenArm(robot), P.HOME, ik.q,
                                                   seed=self.seed)
        result = self.search.advance(None if allowance is None
                                     else allowance - self.before_path)
        if result is None:
            return None
        if not result.feasible:
            result.step = "arm_path"
        result.checks += self.before_path
        return result


def _instance_boxes(inst: GraspBaseInstance) -> list[tuple[Box, tuple]]:
    return [(inst.target, TARGET_RGBA)] + [(b, OBSTACLE_RGBA) for b in inst.obstacles]


__all__ = ["BaseGrasp", "GraspBaseConfig", "GraspBaseDomain"]
