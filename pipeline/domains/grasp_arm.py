"""``grasp_arm`` (paper §V-A): choose an arm and one of its 81 grasps, then plan the arm.

Two Pandas stand side by side on a stand, facing a table with a shelf unit whose board
blocks approaches from above to whatever lies under it.  The target box lies on the table
in front of the shelf, on the table under the shelf, or on the shelf board; 0-20 box
obstacles stand on the same surfaces.  A constraint θ = (arm, grasp): 2 × 81 fixed
constraints, the grasps generated from the object's geometry (9 approach directions ×
3 wrist rotations × 3 depths), each with a pre-grasp 10 cm back along the approach.
π(ω, θ): a collision-free IK solution for the pre-grasp, then the configured planner
(RRT-Connect with bounded shortcutting, or TrajOpt) from home; score = -(joint-space path
length).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from pipeline.domains import features as F
from pipeline.domains.base import (
    ConstraintSet,
    Domain,
    EntryTry,
    Feature,
    RawSearch,
    constraint_row,
)
from pipeline.domains.geometry import Box, sample_obstacles
from pipeline.domains.grasps import (
    GRASP_FEATURES,
    Grasp,
    grasp_index,
    grasp_set,
    pregrasp_pose,
)
from pipeline.domains.ik import planner_check, solve_ik
from pipeline.domains.schemas import GraspArmConfig
from pipeline.domains.specs import parse_box, parse_obstacles, require
from pipeline.planning import PlanResult, path_is_free
from pipeline.sim import panda as P
from pipeline.sim.world import add_box, camera_image, connect, save_png

#: name -> (x range, y range, surface height, free height above it)
SURFACES = {
    "table_front": ((0.32, 0.50), (-0.55, 0.55), 0.0, 1.0),
    "under_shelf": ((0.60, 0.76), (-0.50, 0.50), 0.0, 0.28),
    "shelf_top": ((0.60, 0.76), (-0.50, 0.50), 0.30, 1.0),
}
#: the furniture: (full size, centre)
FURNITURE = (
    ((0.40, 1.20, 0.50), (-0.05, 0.0, -0.255)),  # stand under both arms
    ((0.70, 1.40, 0.05), (0.65, 0.0, -0.025)),  # table, top at z = 0
    ((0.22, 1.10, 0.02), (0.68, 0.0, 0.29)),  # shelf board, top at z = 0.30
    ((0.22, 0.02, 0.28), (0.68, 0.56, 0.14)),  # shelf side panels
    ((0.22, 0.02, 0.28), (0.68, -0.56, 0.14)),
    ((0.02, 1.14, 0.60), (0.80, 0.0, 0.30)),  # shelf back panel
)
ARM_BASES = ((0.0, 0.30, 0.0), (0.0, -0.30, 0.0))

#: The instance features (GraspArmDomain._instance_features): the target's pose, its
#: surface, and what is near it.  Gaps are between box surfaces (0: touching), in 3-D.
INSTANCE_FEATURES = (
    Feature("target_x", "m", "target centre x (away from the arms)"),
    Feature("target_y", "m", "target centre y (+: arm 0's side)"),
    Feature("target_z", "m", "target centre height above the table top"),
    Feature("target_yaw_cos", "1", "cosine of the target's yaw"),
    Feature("target_yaw_sin", "1", "sine of the target's yaw"),
    *(Feature(f"on_{name}", "1", f"1 if the target stands {name.replace('_', ' ')}, else 0")
      for name in SURFACES),
    Feature("obstacles", "1", "number of obstacles"),
    Feature("nearest_gap", "m", "gap between the target and the nearest obstacle (box "
                                f"surface to box surface; {F.GAP_CAP:g} when none is nearer)"),
    *(Feature(f"obstacles_within_{round(r * 100)}cm", "1",
              f"obstacles whose gap to the target is at most {r:g} m") for r in F.NEAR),
    Feature("headroom", "m", "free height above the target's top under the shelf board "
                             f"({F.GAP_CAP:g} where nothing is above it)"),
    Feature("arm_side", "m", "horizontal distance from the target to arm 1's base minus "
                             "that to arm 0's (+: nearer arm 0)"),
)


FURNITURE_BOXES = tuple(Box(size, centre, 0.0) for size, centre in FURNITURE)


def surface_of(box: Box) -> int:
    """The index in SURFACES of the surface ``box`` stands on: the one whose area holds its
    centre and whose height is nearest its bottom."""
    bottom = box.position[2] - box.size[2] / 2
    inside = [k for k, ((x0, x1), (y0, y1), _, _) in enumerate(SURFACES.values())
              if x0 <= box.position[0] <= x1 and y0 <= box.position[1] <= y1]
    heights = [s[2] for s in SURFACES.values()]
    return min(inside or range(len(SURFACES)), key=lambda k: abs(heights[k] - bottom))


@dataclass(frozen=True)
class GraspArmInstance:
    seed: int
    target: Box
    obstacles: tuple[Box, ...]


#: a number per scene made in this process (part of its world keys)
_SCENES = itertools.count()


class GraspArmScene:
    """One pybullet client with the furniture, both arms at home and an instance's boxes."""

    def __init__(self, instance: GraspArmInstance | None = None, contacts: str = "cached"):
        self.client_id = connect()
        for size, centre in FURNITURE:
            add_box(self.client_id, size, centre, rgba=(0.55, 0.45, 0.35, 1.0))
        self.arms = [P.Panda(self.client_id, base, contacts=contacts) for base in ARM_BASES]
        self.robot_ids = tuple(a.body for a in self.arms)
        self.instance = None
        self._bodies: list[int] = []
        self.target_id = None
        #: how many times an instance was loaded (a paused try checks it was not replaced)
        self.loads = 0
        self._number = next(_SCENES)
        for arm in self.arms:
            arm.world_key = functools.partial(self.world_key, arm)
        if instance is not None:
            self.load(instance)

    def load(self, instance: GraspArmInstance) -> None:
        if self.instance == instance:  # by value: re-parsed specs reuse the loaded boxes
            return
        for body in self._bodies:
            pb.removeBody(body, physicsClientId=self.client_id)
        t = instance.target
        self.target_id = add_box(self.client_id, t.size, t.position, t.yaw,
                                 rgba=(0.9, 0.15, 0.1, 1.0))
        self._bodies = [self.target_id] + [
            add_box(self.client_id, b.size, b.position, b.yaw, rgba=(0.3, 0.4, 0.7, 1.0))
            for b in instance.obstacles]
        for arm in self.arms:
            arm.set(P.HOME)
        self.instance = instance
        self.loads += 1

    def world_key(self, arm: P.Panda) -> tuple:
        """A key that stays the same only while everything but ``arm`` does (the sphere
        pre-check reads the world once per key): this scene, the instance loaded and the
        other arms' joints."""
        others = [s[0] for o in self.arms if o is not arm for s in pb.getJointStates(
            o.body, range(7), physicsClientId=self.client_id)]
        return ("grasp_arm", self._number, self.loads, np.round(others, 9).tobytes())

    def set_configuration(self, q, arm: int = 0) -> None:
        self.arms[arm].set(q)

    def close(self) -> None:
        pb.disconnect(physicsClientId=self.client_id)


class GraspArmDomain(Domain):
    name = "grasp_arm"
    fixed_constraints = True
    steps = ("ik", "arm_path")
    theta_features = (Feature("arm", "1", "which Panda grasps: 0 or 1"), *GRASP_FEATURES)
    length_units = "rad"
    length_name = "joint-space path length of the arm"
    omega_features = INSTANCE_FEATURES

    def __init__(self, config: GraspArmConfig, planner):
        super().__init__(config, planner)
        self.grasps = grasp_set()
        self.motion = self.planner_for(P.Panda)
        self._scene: GraspArmScene | None = None


    # -- instances -------------------------------------------------------------------------
    def sample_instance(self, seed: int) -> dict:
        c = self.config
        rng = np.random.default_rng(int(seed))
        names = list(SURFACES)
        placed: list[tuple[str, np.ndarray, float]] = []  # surface, centre xy, radius

        def place(size) -> dict | None:
            for _ in range(200):
                surface = names[int(rng.integers(len(names)))]
                (x0, x1), (y0, y1), z, free = SURFACES[surface]
                if size[2] > free - 0.01:
                    continue
                r = float(np.hypot(size[0], size[1]) / 2)
                xy = np.array([rng.uniform(x0 + r, x1 - r), rng.uniform(y0 + r, y1 - r)])
                if all(s != surface or np.linalg.norm(xy - p) > r + q + 0.01
                       for s, p, q in placed):
                    placed.append((surface, xy, r))
                    return {"size": [round(float(v), 4) for v in size],
                            "position": [round(float(xy[0]), 4), round(float(xy[1]), 4),
                                         round(float(z + size[2] / 2 + 1e-3), 4)],
                            "yaw": round(float(rng.uniform(-np.pi, np.pi)), 4),
                            "surface": surface}
            return None

        target = place(np.asarray(c.target_size, float))
        count = int(rng.integers(c.obstacles_min, c.obstacles_max + 1))
        obstacles = sample_obstacles(rng, count, c.obstacle_size, c.obstacle_height, place)
        return {"domain": self.name, "seed": int(seed), "target": target,
                "obstacles": obstacles}

    def check_instance(self, instance) -> GraspArmInstance:
        if isinstance(instance, GraspArmInstance):
            return instance
        seed = require(instance, "seed", int)
        target = parse_box(require(instance, "target", dict), "target")
        return GraspArmInstance(seed, target, parse_obstacles(instance))

    def _instance_features(self, inst: GraspArmInstance) -> np.ndarray:
        t = inst.target
        surface = surface_of(t)
        to_arm = [float(np.hypot(t.position[0] - b[0], t.position[1] - b[1])) for b in ARM_BASES]
        return np.array([*t.position, *F.yaw_features(t.yaw), *F.one_hot(surface, len(SURFACES)),
                         len(inst.obstacles), *F.nearby(t, inst.obstacles),
                         F.headroom(t, FURNITURE_BOXES), to_arm[1] - to_arm[0]])

    # -- constraints -----------------------------------------------------------------------
    def constraints(self, extracted: ConstraintSet | None = None) -> ConstraintSet:
        feats = np.stack([g.features for g in self.grasps])
        return ConstraintSet(feats, np.full(len(feats), -1))

    def constraint(self, constraint) -> Grasp:
        """A grasp from its index (0..161) or its feature row."""
        if isinstance(constraint, int | np.integer):
            if not 0 <= constraint < len(self.grasps):
                raise ValueError(f"grasp_arm constraint index {constraint} out of range "
                                 f"0..{len(self.grasps) - 1}")
            return self.grasps[int(constraint)]
        row = constraint_row(constraint, self.name)
        index = grasp_index(row)
        if index is None:
            raise ValueError(f"grasp_arm constraint {constraint!r} is neither an index nor a "
                             "grasp's feature row")
        return self.grasps[index]

    def pregrasp_pose(self, inst: GraspArmInstance, g: Grasp) -> tuple[np.ndarray, np.ndarray]:
        """World position and quaternion of the TCP at the pre-grasp."""
        return pregrasp_pose(inst.target, g, self.config.pregrasp_offset)

    # -- planning --------------------------------------------------------------------------
    def scene(self, inst: GraspArmInstance) -> GraspArmScene:
        """The domain's scene (one pybullet client, made on first use), loaded with
        ``inst``."""
        if self._scene is None:
            self._scene = GraspArmScene(contacts=self.config.contacts)
        self._scene.load(inst)
        return self._scene

    def close(self) -> None:
        if self._scene is not None:
            self._scene.close()
            self._scene = None

    def _plan(self, inst: GraspArmInstance, g: Grasp, seed: int) -> PlanResult:
        scene = self.scene(inst)
        arm = scene.arms[g.arm]
        try:
            return self._plan_arm(inst, g, arm, seed)
        finally:  # IK and planning move the arm; the next call must find both arms at home
            arm.set(P.HOME)

    def _plan_arm(self, inst: GraspArmInstance, g: Grasp, arm: P.Panda, seed: int) -> PlanResult:
        return GraspArmTry(self, inst, g, seed).step(arm, None)

    def _start(self, inst: GraspArmInstance, g: Grasp, seed: int) -> GraspArmTry | None:
        return GraspArmTry(self, inst, g, seed) if self.motion.resumable else None

    def _raw_search(self, inst: GraspArmInstance, seed: int) -> RawSearch:
        """(arm, grasp) pairs drawn without replacement until one is feasible."""
        order = np.random.default_rng([seed, 2]).permutation(len(self.grasps))
        checks = 0
        for tries, j in enumerate(order, start=1):
            g = self.grasps[int(j)]
            plan = self.attempt(inst, g, seed + tries)
            checks += plan.checks
            if plan.feasible:
                return RawSearch(plan, g.features, tries, checks)
        return RawSearch(plan, None, tries, checks)

    def ik_collides(self, arm: P.Panda):
        """IK's check of a solution (:func:`pipeline.domains.ik.planner_check`)."""
        return planner_check(self.motion, arm, arm.fresh_contacts)

    def check_limit(self) -> int:
        """The arm path's budget and a check per IK solution tried."""
        return self.planner.max_checks + self.config.ik_restarts

    # -- inspection ------------------------------------------------------------------------
    def recheck(self, instance, constraint, plan: PlanResult) -> dict[str, bool]:
        """θ's arm path home → pre-grasp, the other arm at home."""
        scene = self.build_scene(instance)
        try:
            arm = scene.arms[self.constraint(constraint).arm]
            return {"arm_path": path_is_free(plan.path, arm, self.planner.resolution)}
        finally:
            scene.close()

    def build_scene(self, instance) -> GraspArmScene:
        """A new scene (its own pybullet client) for inspection; close() it when done."""
        return GraspArmScene(self.check_instance(instance), self.config.contacts)

    def render(self, instance, plan: PlanResult | None = None, path="grasp_arm.png",
               constraint=None, width: int = 480, height: int = 360) -> Path:
        inst = self.check_instance(instance)
        scene = GraspArmScene(inst, self.config.contacts)
        try:
            if plan is not None and plan.feasible and constraint is not None:
                scene.set_configuration(plan.path[-1], arm=self.constraint(constraint).arm)
            rgb = camera_image(scene.client_id, [-0.2, 1.3, 1.1], [0.5, 0.0, 0.1], width,
                               height)
        finally:
            scene.close()
        return save_png(rgb, path)


class GraspArmTry(EntryTry):
    """π(ω, θ) of grasp_arm in slices: the IK step runs whole in the first slice (its
    checks, one per IK solution tried, count towards the allowance like the planner's),
    then the arm path is the motion planner's try, resumed slice after slice.  Other calls
    may use the domain's scene between two slices: each slice loads the instance again
    (a no-op when it is still loaded) and, when the scene was rebuilt or reloaded, remakes
    the robot model the planner checks on (the same answers)."""

    def __init__(self, domain: GraspArmDomain, inst: GraspArmInstance, g: Grasp, seed: int):
        super().__init__()
        self.domain, self.inst, self.g, self.seed = domain, inst, g, seed
        self.ik_checks = 0
        self.search = None  # the arm path's planning try, once IK found a goal
        self._scene_key = None

    def _slice(self, allowance):
        scene = self.domain.scene(self.inst)
        arm = scene.arms[self.g.arm]
        key = (scene, scene.loads)  # the scene object itself: a new one may reuse its id()
        try:
            if self.search is not None and key != self._scene_key:
                self.search.rebind(arm)
            self._scene_key = key
            return self.step(arm, allowance)
        finally:  # the next call must find both arms at home
            arm.set(P.HOME)

    def step(self, arm: P.Panda, allowance: int | None) -> PlanResult | None:
        """IK (first time only), then the arm path until ``allowance`` checks in all."""
        d = self.domain
        if self.search is None:
            pos, orn = d.pregrasp_pose(self.inst, self.g)
            ik = solve_ik(arm, pos, orn, [self.seed, 7], d.config.ik_restarts, d.config.ik,
                          d.ik_collides(arm))
            if not ik.found:
                return PlanResult(ik.status, checks=ik.checks, step="ik")
            self.ik_checks = ik.checks
            self.search = d.motion.start(arm, P.HOME, ik.q, seed=self.seed)
        result = self.search.advance(None if allowance is None else allowance - self.ik_checks)
        if result is None:
            return None
        result.checks += self.ik_checks
        if not result.feasible:
            result.step = "arm_path"
        return result


__all__ = ["GraspArmConfig", "GraspArmDomain"]
