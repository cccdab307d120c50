"""``pick_place`` (paper §V-C): carry a long rod from one room into the next.

Two rooms side by side, split by a wall at x = 0 with a door of ``door_width`` in it.  The
mobile Panda (:mod:`pipeline.sim.mobile`) starts at the same pose in the first room, facing
a table with a rod (one of ``rod_lengths``) lying on it at a fixed pose.  Per instance,
``obstacles`` boxes lie at random, half on that table and half on the goal table in the
second room.

A constraint θ = (grasp g, placement o, pre-place base pose k_b, subgoal base pose k_sg).
The 81 grasps: 9 positions along the rod × 3 wrist rotations × 3 approach tilts about the
rod's axis.  While driving, the arm holds the rod along the heading at a fixed carry point
above the platform (the carry configuration depends on g only).  π(ω, θ), each step named
in a failed result's ``step``:

``carry``       IK for the carry configuration (cached per grasp and rod length)
``placement``   the rod at o on the goal table is collision-free
``base_pose``   k_sg and k_b are collision-free with the rod carried
``place_ik``    IK at k_b for putting the rod down at o, rod in hand
``pick_ik``     IK at the start for g's pre-grasp (10 cm back along the approach)
``pick_path``   arm path home → pre-grasp, base at the start
``place_path``  arm path carry → place at k_b, the rod collision-checked in the hand
``base_path``   base path start → k_sg → k_b in (x, y, ψ), arm in carry, rod checked

``step_order: paper`` (the default) runs them motion by motion as the paper's π does:
pick_ik, pick_path, carry, base_pose, base_path, placement, place_ik, place_path, so that a
θ whose placement is blocked is refuted only after the pick and the drive, the expensive
refutations the paper describes; ``cheap_first`` runs them in the order listed above
(same outcome, feasible or not, with far cheaper refutations).  Grasping,
lifting and stowing the rod in the carry configuration are not planned (the paper's π
plans the same three motions).  Score = -(base path length + ``arm_weight`` × arm path
lengths): base length in the metric sqrt(dx² + dy² + (``psi_scale`` · dψ)²), metres; arm
lengths in radians of joint space.  ψ does not wrap around (a turn from π to -π goes the
long way); base states are (x, y, psi_scale · ψ) so the planner's per-coordinate
resolution is metres everywhere.

RAWPLANNER follows the paper's six steps with backtracking: grasps without replacement
until one has a pick IK and a pick path (1-2); a collision-free placement on the goal table
(3); k_b from the disc of radius ``reach_radius`` around o, collision-free with the rod
carried (4); a base path start → k_b (5); the place IK and path (6).  A failure in 4-6
draws a new k_b, then a new placement, then a new grasp.  The extracted k_sg is where the base
path crosses x = -``SUBGOAL_GAP``, in front of the door.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from pipeline.domains.base import Domain, RawSearch
from pipeline.domains.geometry import Box, rectangle, sample_obstacles
from pipeline.domains.grasps import hand_orientation
from pipeline.domains.ik import solve_ik
from pipeline.domains.mobile_world import (
    OBSTACLE_RGBA,
    MobileScene,
    Table,
    TablePlacer,
    render_two_panels,
    sample_base_pose,
)
from pipeline.domains.schemas import PickPlaceConfig
from pipeline.domains.specs import InstanceError, parse_obstacles, require
from pipeline.planning import PlanResult, Status, path_is_free, path_length
from pipeline.sim import panda as P
from pipeline.sim.mobile import MobileArm, MobileBase, base_transform
from pipeline.sim.world import add_box, pose_matrix, quaternion, rot_z

ROD_RGBA = (0.1, 0.1, 0.1, 1.0)
ROD_SECTION = 0.04  # the rod's square cross-section, metres
WALL_THICKNESS = 0.10
WALL_HEIGHT = 1.5
ROOMS = (-3.0, 3.0, -1.6, 1.6)  # x0, x1, y0, y1 of both rooms together
START_TABLE = Table((-1.9, -1.15), (1.2, 0.6), 0.40)
GOAL_TABLE = Table((2.1, 0.0), (0.8, 2.4), 0.40)
ROD_START = (-1.9, -1.05)  # centre (x, y) of the rod on the start table, along x
START_POSE = np.array([-1.9, -0.35, -np.pi / 2])  # facing the start table
PARK_POSE = np.array([0.0, -4.0, 0.0])  # outside the rooms: where carry IK is solved
SUBGOAL_GAP = 0.6  # metres in front of the wall where k_sg is taken from a raw solution
CARRY_TCP = np.array([0.55, 0.0, 1.0])  # the TCP while driving, in the base frame
STEPS = ("carry", "placement", "base_pose", "place_ik", "pick_ik", "pick_path",
         "place_path", "base_path")
#: the orders π can run its steps in (``step_order``): the paper's, motion by motion, where
#: a bad θ shows only late and is expensive to refute; or the cheap checks first
ORDERS = {"paper": ("pick_ik", "pick_path", "carry", "base_pose", "base_path", "placement",
                    "place_ik", "place_path"),
          "cheap_first": STEPS}
FRACTIONS = np.linspace(-0.8, 0.8, 9)  # grasp position along the rod, × half-length
ANGLES = (-np.pi / 6, 0.0, np.pi / 6)


@dataclass(frozen=True)
class RodGrasp:
    fraction: float  # TCP position along the rod, × half-length, from its centre
    rotation: float  # wrist rotation about the approach, from across the rod
    tilt: float  # approach tilt about the rod's axis, from straight down

    @property
    def features(self) -> np.ndarray:
        return np.array([self.fraction, self.rotation, self.tilt])

    def rod_tcp(self, length: float) -> np.ndarray:
        """The TCP in the rod's frame (x along the rod, z up): on the rod's axis, its z
        along the approach; at rotation 0 its x is along the rod, so the fingers close
        across it."""
        approach = rot_x(self.tilt) @ np.array([0.0, 0.0, -1.0])
        return pose_matrix((self.fraction * length / 2, 0.0, 0.0),
                           hand_orientation(approach, self.rotation))


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rod_grasps() -> list[RodGrasp]:
    return [RodGrasp(round(float(f), 9), a, t) for f in FRACTIONS for a in ANGLES for t in ANGLES]


@dataclass(frozen=True)
class PickPlaceInstance:
    seed: int
    rod_length: float
    obstacles: tuple[Box, ...]


@dataclass(frozen=True)
class Route:
    """θ: grasp, placement (x, y, yaw), pre-place base pose, subgoal base pose."""

    grasp: RodGrasp
    placement: np.ndarray
    place_pose: np.ndarray
    subgoal: np.ndarray

    @property
    def features(self) -> np.ndarray:
        return np.concatenate([self.grasp.features, self.placement, self.place_pose,
                               self.subgoal])


def rod_box(length: float, x: float, y: float, yaw: float, table: Table) -> Box:
    return Box((length, ROD_SECTION, ROD_SECTION), (x, y, table.height + ROD_SECTION / 2 + 1e-3),
               yaw)


def walls(door_width: float) -> list[Box]:
    x0, x1, y0, y1 = ROOMS
    t, h = WALL_THICKNESS, WALL_HEIGHT
    side = (y1 - y0 - door_width) / 2  # the middle wall on each side of the door
    return [Box((x1 - x0 + 2 * t, t, h), ((x0 + x1) / 2, y0 - t / 2, h / 2), 0.0),
            Box((x1 - x0 + 2 * t, t, h), ((x0 + x1) / 2, y1 + t / 2, h / 2), 0.0),
            Box((t, y1 - y0, h), (x0 - t / 2, (y0 + y1) / 2, h / 2), 0.0),
            Box((t, y1 - y0, h), (x1 + t / 2, (y0 + y1) / 2, h / 2), 0.0),
            Box((t, side, h), (0.0, y0 + side / 2, h / 2), 0.0),
            Box((t, side, h), (0.0, y1 - side / 2, h / 2), 0.0)]


class PickPlaceDomain(Domain):
    name = "pick_place"
    config_class = PickPlaceConfig
    fixed_constraints = False
    steps = STEPS

    def __init__(self, config: PickPlaceConfig, planner):
        super().__init__(config, planner)
        c = config
        if c.obstacles < 0 or c.ik_restarts < 1 or c.pregrasp_offset < 0:
            raise ValueError("domain: need obstacles >= 0, ik_restarts >= 1 and "
                             "pregrasp_offset >= 0")
        if not c.rod_lengths or any(not 0.1 <= v <= 1.2 for v in c.rod_lengths):
            raise ValueError("domain.rod_lengths: need one or more lengths in [0.1, 1.2] m")
        if not 0.6 <= c.door_width <= ROOMS[3] - ROOMS[2] - 0.2:
            raise ValueError("domain.door_width must be in [0.6, 3.0] m (the platform is "
                             "0.5 m wide)")
        if not (c.reach_radius > 0 and c.psi_scale > 0 and c.arm_weight >= 0
                and c.base_max_checks >= 1 and c.base_resolution > 0):
            raise ValueError("domain: need reach_radius, psi_scale, base_resolution > 0, "
                             "arm_weight >= 0 and base_max_checks >= 1")
        if c.step_order not in ORDERS:
            raise ValueError(f"domain.step_order must be one of {', '.join(ORDERS)}, got "
                             f"{c.step_order!r}")
        if min(c.raw_grasps, c.raw_placements, c.raw_base_samples) < 1:
            raise ValueError("domain.raw_*: need at least 1 of each")
        self.grasps = rod_grasps()
        self._grasp_index = {tuple(np.round(g.features, 9)): k
                             for k, g in enumerate(self.grasps)}
        self.arm_motion = self.planner_for(MobileArm)
        self.base_motion = self.planner_for(MobileBase, max_checks=c.base_max_checks,
                                            resolution=c.base_resolution)
        self.furniture = [START_TABLE.box(), GOAL_TABLE.box(), *walls(c.door_width)]
        self._scene: MobileScene | None = None
        self._rod: int | None = None
        self._carry: dict[tuple[int, float], tuple[np.ndarray | None, Status]] = {}

    @property
    def n_features(self) -> int:
        return 12

    # -- instances -------------------------------------------------------------------------
    def sample_instance(self, seed: int) -> dict:
        c = self.config
        rng = np.random.default_rng(int(seed))
        length = float(c.rod_lengths[int(rng.integers(len(c.rod_lengths)))])
        placer = TablePlacer(rng, [START_TABLE, GOAL_TABLE])
        placer.block(rectangle(ROD_START, (length + 0.16, ROD_SECTION + 0.16), 0.0))
        tables = iter(range(c.obstacles))  # half on each table
        obstacles = sample_obstacles(rng, c.obstacles, c.obstacle_size, c.obstacle_height,
                                     lambda size: placer.place(size, table=next(tables) % 2))
        return {"domain": self.name, "seed": int(seed), "rod_length": length,
                "obstacles": obstacles}

    def check_instance(self, instance) -> PickPlaceInstance:
        if isinstance(instance, PickPlaceInstance):
            return instance
        seed = require(instance, "seed", int)
        length = require(instance, "rod_length", (int, float))
        if not 0.1 <= length <= 1.2:
            raise InstanceError("instance spec: rod_length must be in [0.1, 1.2] m")
        return PickPlaceInstance(seed, float(length), parse_obstacles(instance))

    # -- constraints -----------------------------------------------------------------------
    def constraint(self, constraint) -> Route:
        """θ from its feature row: grasp (fraction, rotation, tilt), placement (x, y, yaw),
        k_b (x, y, ψ), k_sg (x, y, ψ)."""
        if isinstance(constraint, Route):
            return constraint
        row = np.asarray(constraint, float)
        index = None
        if row.shape == (12,) and np.all(np.isfinite(row)):
            index = self._grasp_index.get(tuple(np.round(row[:3], 9)))
        if index is None:
            raise ValueError(f"pick_place constraint {constraint!r} is not a feature row of "
                             "12 numbers (grasp fraction, rotation, tilt; placement x, y, "
                             "yaw; k_b x, y, psi; k_sg x, y, psi) with one of the 81 grasps")
        return Route(self.grasps[index], row[3:6].copy(), row[6:9].copy(), row[9:12].copy())

    # -- scene -----------------------------------------------------------------------------
    def scene(self, inst: PickPlaceInstance) -> MobileScene:
        """The process's cached scene loaded with ``inst``: rod on the start table, robot at
        the start with the arm at home, nothing held."""
        if self._scene is None:
            self._scene = MobileScene(self.furniture)
        scene = self._scene
        if scene.key != inst:
            bodies = scene.load(inst, [(b, OBSTACLE_RGBA) for b in inst.obstacles])
            rod = rod_box(inst.rod_length, *ROD_START, 0.0, START_TABLE)
            bodies.append(add_box(scene.client_id, rod.size, rod.position, 0.0, rgba=ROD_RGBA,
                                  movable=True))
            self._rod = bodies[-1]
        self._reset(inst)
        return scene

    def _reset(self, inst: PickPlaceInstance) -> None:
        robot = self._scene.robot
        robot.release()
        self._put_rod(rod_box(inst.rod_length, *ROD_START, 0.0, START_TABLE))
        robot.set_base(START_POSE)
        robot.set_arm(P.HOME)

    def _put_rod(self, box: Box) -> None:
        pb.resetBasePositionAndOrientation(self._rod, list(box.position),
                                           quaternion(rot_z(box.yaw)).tolist(),
                                           physicsClientId=self._scene.client_id)

    def _rod_collides(self) -> bool:
        c = self._scene.client_id
        pb.performCollisionDetection(physicsClientId=c)
        return any(pt[8] < 0 for pt in pb.getContactPoints(bodyA=self._rod, physicsClientId=c))

    def rod_pose(self, length: float, placement) -> np.ndarray:
        """World transform of the rod lying at placement (x, y, yaw) on the goal table."""
        box = rod_box(length, placement[0], placement[1], placement[2], GOAL_TABLE)
        return pose_matrix(box.position, rot_z(box.yaw))

    def carry(self, inst: PickPlaceInstance, g: RodGrasp) -> tuple[np.ndarray | None, Status]:
        """The arm's carry configuration for grasp g (cached): solved at ``PARK_POSE``,
        away from everything, so it depends on g and the rod length only."""
        key = (self._grasp_index[tuple(np.round(g.features, 9))], inst.rod_length)
        if key not in self._carry:
            robot = self._scene.robot
            tcp_rod = np.linalg.inv(g.rod_tcp(inst.rod_length))
            robot.set_base(PARK_POSE)
            robot.set_arm(P.HOME)
            robot.grasp(self._rod, tcp_rod)
            # the rod's frame is the base's (rod along the heading), so the TCP turns by g's
            world = base_transform(PARK_POSE) @ pose_matrix(CARRY_TCP, g.rod_tcp(1.0)[:3, :3])
            q, _, reached = robot.ik(world[:3, 3], quaternion(world[:3, :3]),
                                     np.random.default_rng([key[0], 11]), self.config.ik_restarts)
            status = Status.OK if q is not None else (
                Status.GOAL_IN_COLLISION if reached else Status.NO_IK)
            self._carry[key] = (q, status)
            self._reset(inst)
        return self._carry[key]

    # -- planning --------------------------------------------------------------------------
    def _plan(self, inst: PickPlaceInstance, theta: Route, seed: int) -> PlanResult:
        self.scene(inst)
        try:
            return self._plan_route(inst, theta, seed)
        finally:
            self._reset(inst)

    def _plan_route(self, inst: PickPlaceInstance, theta: Route, seed: int) -> PlanResult:
        """Run the steps in the configured order; the first that fails ends the call."""
        done: dict = {"checks": 0}
        for step in ORDERS[self.config.step_order]:
            failed = getattr(self, f"_step_{step}")(inst, theta, seed, done)
            if failed is not None:
                failed.checks, failed.step = done["checks"], step
                return failed
        return self._joined(done["pick_path"], done["base_path"], done["place_path"],
                            done["carry"], theta.place_pose, done["checks"])

    # Each step reads what earlier steps left in ``done``, adds its own result and its
    # collision checks, and returns None, or a PlanResult when it fails.
    def _step_carry(self, inst, theta: Route, seed: int, done: dict):
        """Cached per grasp and rod length, so its IK checks are not charged to entries."""
        done["carry"], status = self.carry(inst, theta.grasp)
        return None if done["carry"] is not None else PlanResult(status)

    def _step_placement(self, inst, theta: Route, seed: int, done: dict):
        self._reset(inst)
        self._put_rod(rod_box(inst.rod_length, *theta.placement, GOAL_TABLE))
        done["checks"] += 1
        if not _on_table(inst.rod_length, theta.placement) or self._rod_collides():
            return PlanResult(Status.GOAL_IN_COLLISION)
        return None

    def _step_base_pose(self, inst, theta: Route, seed: int, done: dict):
        self._hold(inst, theta.grasp, done["carry"])
        for pose, status in ((theta.subgoal, Status.START_IN_COLLISION),
                             (theta.place_pose, Status.GOAL_IN_COLLISION)):
            done["checks"] += 1
            if self._scene.robot.base_collides(pose):
                return PlanResult(status)
        return None

    def _step_place_ik(self, inst, theta: Route, seed: int, done: dict):
        self._reset(inst)
        self._hold(inst, theta.grasp, done["carry"])
        self._scene.robot.set_base(theta.place_pose)
        done["place"], n, status = self._place_ik(inst, theta, seed)
        done["checks"] += n
        return None if done["place"] is not None else PlanResult(status)

    def _step_pick_ik(self, inst, theta: Route, seed: int, done: dict):
        self._reset(inst)
        done["pre"], n, status = self._pick_ik(inst, theta.grasp, seed)
        done["checks"] += n
        return None if done["pre"] is not None else PlanResult(status)

    def _step_pick_path(self, inst, theta: Route, seed: int, done: dict):
        self._reset(inst)
        robot = self._scene.robot
        return self._path(done, "pick_path", self.arm_motion.plan(
            MobileArm(robot), P.HOME, done["pre"], seed=2 * seed))

    def _step_place_path(self, inst, theta: Route, seed: int, done: dict):
        self._reset(inst)
        self._hold(inst, theta.grasp, done["carry"])
        robot = self._scene.robot
        robot.set_base(theta.place_pose)
        return self._path(done, "place_path", self.arm_motion.plan(
            MobileArm(robot), done["carry"], done["place"], seed=2 * seed + 1))

    def _step_base_path(self, inst, theta: Route, seed: int, done: dict):
        return self._path(done, "base_path", self._drive(
            inst, theta.grasp, done["carry"], [START_POSE, theta.subgoal, theta.place_pose],
            seed))

    @staticmethod
    def _path(done: dict, key: str, result: PlanResult):
        done["checks"] += result.checks
        done[key] = result.path
        return None if result.feasible else result

    def base_model(self, robot) -> MobileBase:
        """The base as the planners see it: (x, y, psi_scale · ψ) inside the rooms."""
        s = self.config.psi_scale
        return MobileBase(robot, s, [ROOMS[0], ROOMS[2], -np.pi * s],
                          [ROOMS[1], ROOMS[3], np.pi * s])

    def close(self) -> None:
        if self._scene is not None:
            self._scene.close()
            self._scene, self._rod = None, None

    def _hold(self, inst, g: RodGrasp, carry: np.ndarray) -> None:
        """The rod in the hand, the arm in the carry configuration."""
        robot = self._scene.robot
        robot.release()
        robot.set_arm(carry)
        robot.grasp(self._rod, np.linalg.inv(g.rod_tcp(inst.rod_length)))

    def _place_ik(self, inst, theta: Route, seed: int):
        """IK at k_b for the TCP that puts the rod down at the placement, rod in hand
        (the robot already holds the rod and stands at k_b)."""
        robot = self._scene.robot
        target = self.rod_pose(inst.rod_length, theta.placement) @ theta.grasp.rod_tcp(
            inst.rod_length)
        ik = solve_ik(robot, target[:3, 3], quaternion(target[:3, :3]),
                      np.random.default_rng([seed, 13]), self.config.ik_restarts)
        return ik.q, ik.checks, ik.status

    def _pick_ik(self, inst, g: RodGrasp, seed: int):
        """IK at the start for g's pre-grasp of the rod on the start table."""
        robot = self._scene.robot
        rod = rod_box(inst.rod_length, *ROD_START, 0.0, START_TABLE)
        grasp = pose_matrix(rod.position, np.eye(3)) @ g.rod_tcp(inst.rod_length)
        pre = grasp[:3, 3] - grasp[:3, 2] * self.config.pregrasp_offset
        ik = solve_ik(robot, pre, quaternion(grasp[:3, :3]),
                      np.random.default_rng([seed, 17]), self.config.ik_restarts)
        return ik.q, ik.checks, ik.status

    def _drive(self, inst, g: RodGrasp, carry, poses, seed: int) -> PlanResult:
        """Base path through ``poses`` (the first is the start), arm in carry, rod held."""
        self._hold(inst, g, carry)
        s = self.config.psi_scale
        robot = self._scene.robot
        base = self.base_model(robot)
        budget = self.base_motion.budget(base)
        legs = []
        scaled = [np.array([p[0], p[1], s * p[2]]) for p in poses]
        for leg, (a, b) in enumerate(zip(scaled[:-1], scaled[1:], strict=True)):
            result = self.base_motion.plan(base, a, b, seed=3 * seed + leg, budget=budget)
            if not result.feasible:
                result.checks = budget.used
                return result
            legs.append(result.path if not legs else result.path[1:])
        path = np.concatenate(legs)
        path[:, 2] /= s
        return PlanResult(Status.OK, path=path, length=path_length(np.concatenate(legs)),
                          checks=budget.used)

    def _joined(self, pick, drive, put, carry, place_pose, checks) -> PlanResult:
        """One (x, y, ψ, 7 joints) path, its three planned motions as named segments."""
        def with_base(pose, arm):
            return np.column_stack([np.tile(pose, (len(arm), 1)), arm])

        segments = {"pick_path": with_base(START_POSE, pick),
                    "base_path": np.column_stack([drive, np.tile(carry, (len(drive), 1))]),
                    "place_path": with_base(place_pose, put)}
        base_length = path_length(np.column_stack([drive[:, :2],
                                                   self.config.psi_scale * drive[:, 2]]))
        length = base_length + self.config.arm_weight * (path_length(pick) + path_length(put))
        return PlanResult(Status.OK, path=np.concatenate(list(segments.values())),
                          length=length, checks=checks, segments=segments)

    # -- RAWPLANNER ------------------------------------------------------------------------
    def _raw_search(self, inst: PickPlaceInstance, seed: int) -> RawSearch:
        """The paper's six steps with backtracking (module docstring)."""
        self.scene(inst)
        try:
            plan, used, tries = self._raw(inst, seed)
        finally:
            self._reset(inst)
        return RawSearch(plan, None if used is None else used.features, tries, plan.checks)

    def _raw(self, inst: PickPlaceInstance, seed: int):
        c, robot = self.config, self._scene.robot
        rng = np.random.default_rng([seed, 2])
        checks, tries = 0, 0
        plan = PlanResult(Status.NO_IK, step="pick_ik")
        for gi in rng.permutation(len(self.grasps))[: c.raw_grasps]:
            g = self.grasps[int(gi)]
            tries += 1
            self._reset(inst)
            carry, status = self.carry(inst, g)
            if carry is None:
                plan = PlanResult(status, step="carry")
                continue
            pre, n, status = self._pick_ik(inst, g, seed + tries)
            checks += n
            if pre is None:
                plan = PlanResult(status, step="pick_ik")
                continue
            pick = self.arm_motion.plan(MobileArm(robot), P.HOME, pre, seed=seed + tries)
            checks += pick.checks
            if not pick.feasible:
                plan = _failed(pick, 0, "pick_path")
                continue
            for _ in range(c.raw_placements):
                placement, n = self._sample_placement(inst, rng)
                checks += n
                if placement is None:
                    plan = PlanResult(Status.GOAL_IN_COLLISION, step="placement")
                    continue
                found, plan, n, tries = self._raw_place(inst, g, carry, pick.path, placement,
                                                        rng, seed, tries)
                checks += n
                if found is not None:
                    plan.checks = checks
                    return plan, found, tries
        plan.checks = checks
        return plan, None, tries

    def _raw_place(self, inst, g, carry, pick_path, placement, rng, seed, tries):
        """Steps 4-6 for one grasp and placement: (Route or None, plan, checks, tries)."""
        c, robot = self.config, self._scene.robot
        checks, plan, free, draws = 0, PlanResult(Status.GOAL_IN_COLLISION, step="base_pose"), 0, 0
        while free < c.raw_base_samples and draws < 20 * c.raw_base_samples:
            pose = sample_base_pose(rng, placement[:2], c.reach_radius)
            draws, checks = draws + 1, checks + 1
            self._hold(inst, g, carry)
            if not _in_rooms(pose) or robot.base_collides(pose):
                continue
            free, tries = free + 1, tries + 1
            theta = Route(g, placement, pose, START_POSE)
            place, n, status = self._place_ik(inst, theta, seed + tries)
            checks += n
            if place is None:
                plan = PlanResult(status, step="place_ik")
                continue
            drive = self._drive(inst, g, carry, [START_POSE, pose], seed + tries)
            checks += drive.checks
            if not drive.feasible:
                plan = _failed(drive, 0, "base_path")
                continue
            self._hold(inst, g, carry)
            robot.set_base(pose)
            put = self.arm_motion.plan(MobileArm(robot), carry, place, seed=seed + tries)
            checks += put.checks
            if not put.feasible:
                plan = _failed(put, 0, "place_path")
                continue
            subgoal = _subgoal(drive.path)
            plan = self._joined(pick_path, drive.path, put.path, carry, pose, 0)
            return Route(g, placement, pose, subgoal), plan, checks, tries
        return None, plan, checks, tries

    def _sample_placement(self, inst, rng, draws: int = 30):
        """A collision-free rod pose (x, y, yaw) on the goal table, or None."""
        t = GOAL_TABLE
        for k in range(1, draws + 1):
            yaw = rng.uniform(-np.pi, np.pi)
            xy = rng.uniform(np.subtract(t.centre, np.divide(t.size, 2)),
                             np.add(t.centre, np.divide(t.size, 2)))
            placement = np.round(np.array([xy[0], xy[1], yaw]), 6)
            if not _on_table(inst.rod_length, placement):
                continue
            self._put_rod(rod_box(inst.rod_length, *placement, GOAL_TABLE))
            if not self._rod_collides():
                return placement, k
        return None, draws

    # -- inspection ------------------------------------------------------------------------
    def recheck(self, instance, constraint, plan: PlanResult,
                resolution: float | None = None) -> dict[str, bool]:
        """Re-check each planned motion of a feasible ``plan`` in a fresh scene, every edge
        at ``resolution`` (default: the planners'); also whether the last configuration
        puts the rod down at θ's placement.  {segment: free, "placed": bool}."""
        inst, theta = self.check_instance(instance), self.constraint(constraint)
        scene = self.build_scene(inst)
        robot, rod = scene.robot, scene.bodies[-1]
        pick, drive, put = (plan.segments[k] for k in ("pick_path", "base_path", "place_path"))
        s = self.config.psi_scale
        try:
            out = {"pick_path": path_is_free(pick[:, 3:], MobileArm(robot),
                                             resolution or self.planner.resolution)}
            robot.set_arm(drive[0, 3:])
            robot.grasp(rod, np.linalg.inv(theta.grasp.rod_tcp(inst.rod_length)))
            out["base_path"] = path_is_free(drive[:, :3] * [1.0, 1.0, s], self.base_model(robot),
                                            resolution or self.config.base_resolution)
            robot.set_base(put[0, :3])
            out["place_path"] = path_is_free(put[:, 3:], MobileArm(robot),
                                             resolution or self.planner.resolution)
            robot.set_arm(put[-1, 3:])
            placed, held = self.rod_pose(inst.rod_length, theta.placement), robot.held_pose()
            out["placed"] = bool(np.linalg.norm(held[:3, 3] - placed[:3, 3]) < 0.01
                                 and np.abs(held[:3, :3] - placed[:3, :3]).max() < 0.06)
        finally:
            scene.close()
        return out

    def build_scene(self, instance) -> MobileScene:
        """A new scene (its own pybullet client) for inspection; close() it when done."""
        inst = self.check_instance(instance)
        scene = MobileScene(self.furniture)
        scene.load(inst, [(b, OBSTACLE_RGBA) for b in inst.obstacles])
        rod = rod_box(inst.rod_length, *ROD_START, 0.0, START_TABLE)
        scene.bodies.append(add_box(scene.client_id, rod.size, rod.position, 0.0, rgba=ROD_RGBA,
                                  movable=True))
        scene.robot.set_base(START_POSE)
        return scene

    def render(self, instance, plan: PlanResult | None = None, path="pick_place.png",
               constraint=None) -> Path:
        """Camera view (the robot placing the rod when ``plan`` is feasible) and a floor
        plan: start, k_sg and k_b footprints, the placement, and the base path's strip."""
        inst = self.check_instance(instance)
        scene = self.build_scene(inst)
        rod = rod_box(inst.rod_length, *ROD_START, 0.0, START_TABLE)
        boxes = [(b, OBSTACLE_RGBA) for b in inst.obstacles] + [(rod, ROD_RGBA)]
        poses, marks, base_path = [(START_POSE, "0.4", "start")], [], None
        try:
            if constraint is not None:
                theta = self.constraint(constraint)
                poses += [(theta.subgoal, "tab:orange", "k_sg"),
                          (theta.place_pose, "tab:green", "k_b")]
                marks.append((rod_box(inst.rod_length, *theta.placement, GOAL_TABLE),
                              "tab:purple", "placement o"))
                if plan is not None and plan.feasible:
                    base_path = plan.segments["base_path"][:, :3]
                    rod_body = scene.bodies[-1]
                    placed = rod_box(inst.rod_length, *theta.placement, GOAL_TABLE)
                    pb.resetBasePositionAndOrientation(
                        rod_body, list(placed.position), quaternion(rot_z(placed.yaw)).tolist(),
                        physicsClientId=scene.client_id)
                    scene.set_configuration(plan.path[-1])
            status = "" if plan is None else f", {plan.status.name.lower()}" + (
                f" at {plan.step}" if plan.step else "")
            return render_two_panels(
                scene, f"pick_place instance {inst.seed} (rod {inst.rod_length:g} m){status}",
                path, eye=(0.0, -4.2, 4.2), target=(0.0, 0.0, 0.3), furniture=self.furniture,
                boxes=boxes, poses=poses, base_path=base_path,
                extent=(ROOMS[0] - 0.2, ROOMS[1] + 0.2, ROOMS[2] - 0.2, ROOMS[3] + 0.2),
                marks=marks)
        finally:
            scene.close()


def _on_table(length: float, placement) -> bool:
    corners = rectangle(placement[:2], (length, ROD_SECTION), placement[2])
    lo = np.subtract(GOAL_TABLE.centre, np.divide(GOAL_TABLE.size, 2))
    hi = np.add(GOAL_TABLE.centre, np.divide(GOAL_TABLE.size, 2))
    return bool(np.all(corners >= lo) and np.all(corners <= hi))


def _in_rooms(pose) -> bool:
    return ROOMS[0] < pose[0] < ROOMS[1] and ROOMS[2] < pose[1] < ROOMS[3]


def _subgoal(path: np.ndarray) -> np.ndarray:
    """Where the base path first crosses x = -SUBGOAL_GAP, in front of the door (on a
    checked edge, so collision-free); the start if it never does."""
    for a, b in zip(path[:-1], path[1:], strict=True):
        if a[0] < -SUBGOAL_GAP <= b[0]:
            t = (-SUBGOAL_GAP - a[0]) / (b[0] - a[0])
            return np.round(a + t * (b - a), 6)
    return START_POSE.copy()


def _failed(result: PlanResult, checks: int, step: str) -> PlanResult:
    result.checks += checks
    result.step = step
    return result


__all__ = ["PickPlaceConfig", "PickPlaceDomain", "Route", "rod_grasps"]
