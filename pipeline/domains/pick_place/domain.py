"""The pick_place domain: instances, constraints, π (its steps in
:mod:`~pipeline.domains.pick_place.steps`), RAWPLANNER
(:mod:`~pipeline.domains.pick_place.raw`), re-check and render."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from pipeline.domains import features as F
from pipeline.domains.base import Domain, Feature, RawSearch, constraint_row
from pipeline.domains.geometry import rectangle, sample_obstacles
from pipeline.domains.ik import IKOutcome, planner_check, settles_by_spheres, solve_ik
from pipeline.domains.mobile_world import (
    OBSTACLE_RGBA,
    TablePlacer,
    render_two_panels,
)
from pipeline.domains.pick_place import raw
from pipeline.domains.pick_place import steps as plan_steps
from pipeline.domains.pick_place.scene import PickPlaceScene
from pipeline.domains.pick_place.world import (
    CARRY_TCP,
    GOAL_TABLE,
    PARK_POSE,
    ROD_RGBA,
    ROD_SECTION,
    ROD_START,
    ROOMS,
    START_POSE,
    START_TABLE,
    PickPlaceInstance,
    RodGrasp,
    Route,
    furniture,
    placed_rod,
    rod_grasps,
    rod_pose,
    start_rod,
)
from pipeline.domains.schemas import PickPlaceConfig
from pipeline.domains.specs import InstanceError, parse_obstacles, require
from pipeline.planning import PlanResult, Status, path_is_free, path_length
from pipeline.sim import panda as P
from pipeline.sim.mobile import MobileArm, MobileBase, base_transform
from pipeline.sim.world import pose_matrix, quaternion


def _own_copy(ik: IKOutcome) -> IKOutcome:
    """``ik`` with its own copy of the solution (a kept outcome is never handed out)."""
    return ik if ik.q is None else replace(ik, q=ik.q.copy())


#: The instance features (PickPlaceDomain._instance_features): the rod, what is near it on
#: the start table, and how crowded the goal table is (gaps between box surfaces).
INSTANCE_FEATURES = (
    Feature("rod_length", "m", "length of the rod"),
    Feature("start_obstacles", "1", "obstacles on the start table"),
    Feature("start_nearest_gap", "m", "gap between the rod and the nearest obstacle "
                                      f"({F.GAP_CAP:g} when none is nearer)"),
    *(Feature(f"start_within_{round(r * 100)}cm", "1",
              f"obstacles whose gap to the rod is at most {r:g} m") for r in F.NEAR),
    Feature("goal_obstacles", "1", "obstacles on the goal table"),
    Feature("goal_cover", "1", "fraction of the goal table's top under obstacles' "
                               "footprints"),
)


class PickPlaceDomain(Domain):
    name = "pick_place"
    fixed_constraints = False
    steps = tuple(plan_steps.STEPS)
    theta_features = (
        Feature("grasp_fraction", "1", "grasp position along the rod, × half its length"),
        Feature("grasp_rotation", "rad", "wrist rotation about the approach"),
        Feature("grasp_tilt", "rad", "approach tilt about the rod's axis"),
        Feature("place_x", "m", "rod placement x"), Feature("place_y", "m", "rod placement y"),
        Feature("place_yaw", "rad", "rod placement yaw"),
        Feature("place_base_x", "m", "base pose for placing (k_b) x"),
        Feature("place_base_y", "m", "base pose for placing (k_b) y"),
        Feature("place_base_yaw", "rad", "base pose for placing (k_b) heading ψ"),
        Feature("subgoal_x", "m", "base subgoal (k_sg) x"),
        Feature("subgoal_y", "m", "base subgoal (k_sg) y"),
        Feature("subgoal_yaw", "rad", "base subgoal (k_sg) heading ψ"))
    #: base path (yaw scaled by psi_scale, m/rad) + arm_weight (m/rad) × arm joint paths
    length_units = "m"
    length_name = "base path length plus arm_weight × arm joint path lengths"
    home = P.HOME
    start_pose = START_POSE
    omega_features = INSTANCE_FEATURES

    def __init__(self, config: PickPlaceConfig, planner):
        super().__init__(config, planner)
        c = config  # its values were checked by the schema (PickPlaceConfig)
        plan_steps.check_order(plan_steps.ORDERS[c.step_order])
        self.grasps = rod_grasps()
        self._grasp_index = {tuple(np.round(g.features, 9)): k
                             for k, g in enumerate(self.grasps)}
        self.arm_motion = self.planner_for(MobileArm)
        self.base_motion = self.planner_for(MobileBase, max_checks=c.base_max_checks,
                                            resolution=c.base_resolution)
        self.furniture = furniture(c.door_width)
        self._scene: PickPlaceScene | None = None
        self._carry: dict[tuple[int, float], tuple[np.ndarray | None, Status]] = {}
        #: pick IK's outcomes that no seed changes, per grasp, for one state of the scene
        self._picks: dict[RodGrasp, IKOutcome] = {}
        self._picks_at: tuple | None = None


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

    def _instance_features(self, inst: PickPlaceInstance) -> np.ndarray:
        tables = [START_TABLE.area(), GOAL_TABLE.area()]
        on = [F.region_of(o.position, tables) for o in inst.obstacles]
        start = [o for o, k in zip(inst.obstacles, on, strict=True) if k == 0]
        goal = [o for o, k in zip(inst.obstacles, on, strict=True) if k == 1]
        covered = sum(o.size[0] * o.size[1] for o in goal)
        return np.array([inst.rod_length, len(start),
                         *F.nearby(start_rod(inst.rod_length), start), len(goal),
                         covered / (GOAL_TABLE.size[0] * GOAL_TABLE.size[1])])

    # -- constraints -----------------------------------------------------------------------
    def constraint(self, constraint) -> Route:
        """θ from its feature row: grasp (fraction, rotation, tilt), placement (x, y, yaw),
        k_b (x, y, ψ), k_sg (x, y, ψ)."""
        if isinstance(constraint, Route):
            return constraint
        row = constraint_row(constraint, self.name)
        index = None
        if row.shape == (12,) and np.all(np.isfinite(row)):
            index = self._grasp_index.get(tuple(np.round(row[:3], 9)))
        if index is None:
            raise ValueError(f"pick_place constraint {constraint!r} is not a feature row of "
                             "12 numbers (grasp fraction, rotation, tilt; placement x, y, "
                             "yaw; k_b x, y, psi; k_sg x, y, psi) with one of the 81 grasps")
        return Route(self.grasps[index], row[3:6].copy(), row[6:9].copy(), row[9:12].copy())

    # -- the scene -------------------------------------------------------------------------
    def scene(self, inst: PickPlaceInstance) -> PickPlaceScene:
        """The domain's scene (one pybullet client, made on first use) loaded with
        ``inst``: rod on the start table, robot at the start, arm at home, nothing held."""
        if self._scene is None:
            self._scene = PickPlaceScene(self.furniture, self.config.psi_scale,
                                         self.config.contacts)
        self._scene.load(inst)
        return self._scene

    def scene_of(self) -> PickPlaceScene:
        """The loaded scene (after :meth:`scene`)."""
        return self._scene

    @property
    def robot(self):
        return self._scene.robot

    def reset(self, inst: PickPlaceInstance) -> PickPlaceScene:
        self._scene.reset(inst)
        return self._scene

    def hold(self, inst: PickPlaceInstance, g: RodGrasp, carry: np.ndarray) -> None:
        self._scene.hold(inst, g, carry)

    def close(self) -> None:
        if self._scene is not None:
            self._scene.close()
            self._scene = None

    # -- the motions steps and RAWPLANNER share --------------------------------------------
    def carry(self, inst: PickPlaceInstance, g: RodGrasp) -> tuple[np.ndarray | None, Status]:
        """The arm's carry configuration for grasp g (cached): solved at ``PARK_POSE``,
        away from everything, so it depends on g and the rod length only."""
        key = (self._grasp_index[tuple(np.round(g.features, 9))], inst.rod_length)
        if key not in self._carry:
            scene, robot = self._scene, self._scene.robot
            robot.set_base(PARK_POSE)
            robot.set_arm(P.HOME)
            robot.grasp(scene.rod, g.rod_in_hand(inst.rod_length))
            # the rod's frame is the base's (rod along the heading), so the TCP turns by g's
            world = base_transform(PARK_POSE) @ pose_matrix(CARRY_TCP, g.rod_tcp(1.0)[:3, :3])
            ik = solve_ik(robot, world[:3, 3], quaternion(world[:3, :3]),
                          [key[0], 11], self.config.ik_restarts, self.config.ik)
            self._carry[key] = (ik.q, ik.status)
            scene.reset(inst)
        return self._carry[key]

    def place_ik(self, inst, theta: Route, seed: int) -> IKOutcome:
        """IK at k_b for the TCP that puts the rod down at the placement, rod in hand
        (the robot already holds the rod and stands at k_b)."""
        target = rod_pose(inst.rod_length, theta.placement) @ theta.grasp.rod_tcp(
            inst.rod_length)
        return solve_ik(self.robot, target[:3, 3], quaternion(target[:3, :3]),
                        [seed, 13], self.config.ik_restarts, self.config.ik, self.ik_collides())

    def pick_ik(self, inst, g: RodGrasp, seed: int) -> IKOutcome:
        """IK at the start for g's pre-grasp of the rod on the start table.

        Every constraint of an instance with grasp g asks this IK again, and its outcome
        seldom depends on the seed (IK from home settles it), so such outcomes are kept
        while the scene stays as it is (:meth:`_kept_picks`)."""
        kept = self._kept_picks()
        known = None if kept is None else kept.get(g)
        if known is not None:
            return _own_copy(known)
        grasp = pose_matrix(start_rod(inst.rod_length).position, np.eye(3)) @ g.rod_tcp(
            inst.rod_length)
        pre = grasp[:3, 3] - grasp[:3, 2] * self.config.pregrasp_offset
        ik = solve_ik(self.robot, pre, quaternion(grasp[:3, :3]),
                      [seed, 17], self.config.ik_restarts, self.config.ik, self.ik_collides())
        if kept is not None and not ik.seeded:
            kept[g] = _own_copy(ik)
        return ik

    def _kept_picks(self) -> dict[RodGrasp, IKOutcome] | None:
        """The pick IK outcomes kept for the scene as it is now (the instance loaded, the
        rod where it lies, the base where it stands, what it holds), or None under cached
        contacts, where a check's answer depends on what pybullet checked before
        (docs/contacts.md)."""
        robot = self.robot
        if not robot.fresh_contacts:
            return None
        at = (self._scene.world_key(), robot.pose.tobytes(), robot.held)
        if at != self._picks_at:
            self._picks, self._picks_at = {}, at
        return self._picks

    def ik_collides(self):
        """IK's check of a solution at the robot's current base and load: the arm planner's
        (:func:`pipeline.domains.ik.planner_check`; the arm motion that follows the IK step
        plans on the same model)."""
        return planner_check(self.arm_motion, self._scene.arm, self.robot.fresh_contacts)

    def base_pose_collides(self, prepare=None):
        """The check of a base pose (x, y, ψ) at the robot's current arm state and load:
        where the base planner's sphere pre-check settles the pose by geometry alone
        (:func:`pipeline.domains.ik.settles_by_spheres`), its answer, else pybullet's at
        the pose itself.  The base motion that follows plans on the same model, which then knows
        these poses.  ``prepare``: called before pybullet is asked (a caller that put off
        moving the robot brings pybullet up to date)."""
        robot = self.robot
        ask = robot.base_collides
        if prepare is not None:
            def ask(pose) -> bool:
                prepare()
                return robot.base_collides(pose)
        if not settles_by_spheres(self.base_motion, robot.fresh_contacts):
            return ask
        checker = getattr(self.base_motion.check_model(self._scene.base), "checker", None)
        if checker is None:
            return ask
        s = self.config.psi_scale

        def collides(pose) -> bool:
            free = checker.settle(np.array([pose[0], pose[1], s * pose[2]]))
            return ask(pose) if free is None else not free
        return collides

    def drive(self, inst, g: RodGrasp, carry, poses, seed: int) -> PlanResult:
        """Base path through ``poses`` (the first is the start), arm in carry, rod held."""
        self.hold(inst, g, carry)
        s = self.config.psi_scale
        base = self._scene.base
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

    def joined(self, pick, drive, put, carry, place_pose, checks) -> PlanResult:
        """One (x, y, ψ, 7 joints) path, its three planned motions as named segments;
        score = -(base length + arm_weight × arm lengths)."""
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

    # -- π and RAWPLANNER ------------------------------------------------------------------
    def _plan(self, inst: PickPlaceInstance, theta: Route, seed: int) -> PlanResult:
        self.scene(inst)
        try:
            order = plan_steps.ORDERS[self.config.step_order]
            return plan_steps.run_steps(self, inst, theta, seed, order)
        finally:
            self._scene.reset(inst)

    def _raw_search(self, inst: PickPlaceInstance, seed: int) -> RawSearch:
        self.scene(inst)
        try:
            return raw.raw_search(self, inst, seed)
        finally:
            self._scene.reset(inst)

    def check_limit(self) -> int:
        """Two arm paths' budgets, the base path's, one check per IK solution tried in the
        place and pick IK, the placement's and the two base poses' checks."""
        c = self.config
        return 2 * self.planner.max_checks + c.base_max_checks + 2 * c.ik_restarts + 3

    # -- inspection ------------------------------------------------------------------------
    def recheck(self, instance, constraint, plan: PlanResult,
                resolution: float | None = None) -> dict[str, bool]:
        """Re-check each planned motion of a feasible ``plan`` in a fresh scene, every edge
        at ``resolution`` (default: the planners'); also whether the last configuration
        puts the rod down at θ's placement.  {segment: free, "placed": bool}."""
        inst, theta = self.check_instance(instance), self.constraint(constraint)
        scene = self.build_scene(inst)
        robot = scene.robot
        pick, drive, put = (plan.segments[k] for k in ("pick_path", "base_path", "place_path"))
        s = self.config.psi_scale
        try:
            out = {"pick_path": path_is_free(pick[:, 3:], scene.arm,
                                             resolution or self.planner.resolution)}
            robot.set_arm(drive[0, 3:])
            robot.grasp(scene.rod, np.linalg.inv(theta.grasp.rod_tcp(inst.rod_length)))
            out["base_path"] = path_is_free(drive[:, :3] * [1.0, 1.0, s], scene.base,
                                            resolution or self.config.base_resolution)
            robot.set_base(put[0, :3])
            out["place_path"] = path_is_free(put[:, 3:], scene.arm,
                                             resolution or self.planner.resolution)
            robot.set_arm(put[-1, 3:])
            placed, held = rod_pose(inst.rod_length, theta.placement), robot.held_pose()
            out["placed"] = bool(np.linalg.norm(held[:3, 3] - placed[:3, 3]) < 0.01
                                 and np.abs(held[:3, :3] - placed[:3, :3]).max() < 0.06)
        finally:
            scene.close()
        return out

    def build_scene(self, instance) -> PickPlaceScene:
        """A new scene (its own pybullet client) for inspection; close() it when done."""
        scene = PickPlaceScene(self.furniture, self.config.psi_scale, self.config.contacts)
        scene.load(self.check_instance(instance))
        return scene

    def render(self, instance, plan: PlanResult | None = None, path="pick_place.png",
               constraint=None) -> Path:
        """Camera view (the robot placing the rod when ``plan`` is feasible) and a floor
        plan: start, k_sg and k_b footprints, the placement, and the base path's strip."""
        inst = self.check_instance(instance)
        scene = self.build_scene(inst)
        boxes = [(b, OBSTACLE_RGBA) for b in inst.obstacles] + [
            (start_rod(inst.rod_length), ROD_RGBA)]
        poses, marks, base_path = [(START_POSE, "0.4", "start")], [], None
        try:
            if constraint is not None:
                theta = self.constraint(constraint)
                poses += [(theta.subgoal, "tab:orange", "k_sg"),
                          (theta.place_pose, "tab:green", "k_b")]
                placed = placed_rod(inst.rod_length, theta.placement)
                marks.append((placed, "tab:purple", "placement o"))
                if plan is not None and plan.feasible:
                    # the base stands still while the arm moves: the whole path's (x, y, ψ)
                    # is the base path's strip (a plan read back from disk has no segments)
                    base_path = np.asarray(plan.path)[:, :3]
                    scene.put_rod(placed)
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
