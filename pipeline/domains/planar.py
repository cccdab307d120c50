"""``planar``: a disc robot crossing a room with random box obstacles.

The smallest complete domain, milliseconds per call, so that tests and the quick start
exercise the whole pipeline; also the worked example of adding a domain.  The start and
goal are fixed; a solution constraint θ is a via-point the robot must pass through, and
π(ω, θ) plans start → θ → goal with RRT-Connect (each leg shortcut on its own, so the path
keeps passing θ).  RAWPLANNER samples via-points uniformly until one works, and the
via-point it used is the constraint extracted from its solution.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.domains.base import Domain, Feature, RawSearch, constraint_row
from pipeline.domains.schemas import PlanarConfig
from pipeline.domains.specs import InstanceError, finite_rows, require
from pipeline.planning import PlanResult, Robot, Status, path_is_free, path_length

#: metres between the points of the straight start → goal line the features look at
LINE_STEP = 0.01


@dataclass(frozen=True)
class PlanarInstance:
    seed: int
    boxes: np.ndarray  # (k, 4): centre x, centre y, width, height


class PlanarScene(Robot):
    """The room as plain geometry (no simulator), and the disc robot's model: its centre is
    the configuration, inside ``lower``/``upper``."""

    description = "the planar disc robot"
    client_id = None
    robot_ids = ()

    def __init__(self, boxes: np.ndarray, radius: float, lower=None, upper=None):
        self.lo = boxes[:, :2] - boxes[:, 2:] / 2
        self.hi = boxes[:, :2] + boxes[:, 2:] / 2
        self.radius = radius
        self.lower, self.upper = lower, upper
        self.configuration = None

    def set_configuration(self, q) -> None:
        self.configuration = np.asarray(q, float)

    def collides(self, states: np.ndarray) -> np.ndarray:
        """(k,) bool: the disc at each state overlaps a box."""
        below = self.lo[None] - states[:, None]
        above = states[:, None] - self.hi[None]
        gap = np.maximum(np.maximum(below, above), 0.0)
        return np.any(np.einsum("kbi,kbi->kb", gap, gap) < self.radius**2, axis=1)

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        """The planner's checker: free?, and how many states a sequential check would use."""
        hits = np.flatnonzero(self.collides(states))
        return (True, len(states)) if hits.size == 0 else (False, int(hits[0]) + 1)


class PlanarDomain(Domain):
    name = "planar"
    fixed_constraints = False
    steps = ("via_leg", "goal_leg")
    theta_features = (Feature("via_x", "m", "via point x"), Feature("via_y", "m", "via point y"))
    length_units = "m"
    #: the straight line start → goal, taken at LINE_STEP spacing (_instance_features)
    omega_features = (
        Feature("obstacles", "1", "number of boxes"),
        Feature("obstacle_area", "1", "summed area of the boxes over the room's"),
        Feature("line_blockers", "1", "boxes the robot hits going straight from start to goal"),
        Feature("line_blocked", "1", "fraction of that straight line where the robot would "
                                     "overlap a box"))

    def __init__(self, config: PlanarConfig, planner):
        super().__init__(config, planner)
        c = config  # its values were checked by the schema (PlanarConfig)
        self.start = np.asarray(c.start, float)
        self.goal = np.asarray(c.goal, float)
        self.lower = np.full(2, c.robot_radius)
        self.upper = np.full(2, c.size - c.robot_radius)
        self.motion = self.planner_for(PlanarScene)


    def sample_instance(self, seed: int) -> dict:
        c = self.config
        rng = np.random.default_rng(int(seed))
        boxes = []
        target = int(rng.integers(c.obstacles_min, c.obstacles_max + 1))
        clearance = c.robot_radius * 1.5
        for _ in range(100 * (target + 1)):
            if len(boxes) == target:
                break
            w, h = rng.uniform(c.obstacle_size_min, c.obstacle_size_max, 2)
            x, y = rng.uniform(0.0, c.size, 2)
            box = np.array([[x, y, w, h]])
            near = PlanarScene(box, clearance).collides(np.stack([self.start, self.goal]))
            if not near.any():
                boxes.append([round(float(v), 6) for v in (x, y, w, h)])
        return {"domain": self.name, "seed": int(seed), "obstacles": boxes}

    def check_instance(self, instance) -> PlanarInstance:
        if isinstance(instance, PlanarInstance):
            return instance
        seed = require(instance, "seed", int)
        boxes = finite_rows(require(instance, "obstacles", list), "obstacles", 4)
        if np.any(boxes[:, 2:] <= 0):
            raise InstanceError("instance spec: field 'obstacles' has a box with a size <= 0")
        return PlanarInstance(seed=seed, boxes=boxes)

    def _instance_features(self, inst: PlanarInstance) -> np.ndarray:
        size = self.config.size
        boxes = inst.boxes
        steps = max(2, int(np.ceil(np.linalg.norm(self.goal - self.start) / LINE_STEP)) + 1)
        line = np.linspace(self.start, self.goal, steps)
        gap = np.maximum(np.maximum(boxes[None, :, :2] - boxes[None, :, 2:] / 2 - line[:, None],
                                    line[:, None] - boxes[None, :, :2] - boxes[None, :, 2:] / 2),
                         0.0)
        hit = np.hypot(gap[..., 0], gap[..., 1]) < self.config.robot_radius  # (steps, boxes)
        return np.array([len(boxes), float(np.prod(boxes[:, 2:], axis=1).sum()) / size**2,
                         np.count_nonzero(hit.any(axis=0)), float(hit.any(axis=1).mean())])

    def constraint(self, constraint) -> np.ndarray:
        """The via-point θ as a 2-vector."""
        via = constraint_row(constraint, self.name)
        if via.shape != (2,) or not np.all(np.isfinite(via)):
            raise ValueError(f"planar constraint must be 2 finite numbers, got {constraint!r}")
        return via

    def _plan(self, inst: PlanarInstance, via: np.ndarray, seed: int) -> PlanResult:
        robot = self.build_scene(inst)
        budget = self.motion.budget(robot)
        legs = []
        for leg, (a, b) in enumerate(((self.start, via), (via, self.goal))):
            result = self.motion.plan(robot, a, b, seed=2 * seed + leg, budget=budget)
            if not result.feasible:
                result.checks, result.step = budget.used, self.steps[leg]
                return result
            legs.append(result.path)
        path = np.concatenate([legs[0], legs[1][1:]])
        return PlanResult(Status.OK, path=path, length=path_length(path), checks=budget.used)

    def _raw_search(self, inst: PlanarInstance, seed: int) -> RawSearch:
        """Via-points drawn uniformly in the room until one gives a path."""
        rng = np.random.default_rng([seed, 2])
        checks = 0
        for tries in range(1, self.config.raw_max_tries + 1):
            via = rng.uniform(self.lower, self.upper)
            plan = self.attempt(inst, via, seed * self.config.raw_max_tries + tries)
            checks += plan.checks
            if plan.feasible:
                return RawSearch(plan, via, tries, checks)
        return RawSearch(plan, None, tries, checks)

    def recheck(self, instance, constraint, plan: PlanResult) -> dict[str, bool]:
        """The path, and that it passes the via-point θ."""
        via = self.constraint(constraint)
        return {"path": path_is_free(plan.path, self.build_scene(instance),
                                     self.planner.resolution),
                "via": bool(np.any(np.all(np.isclose(plan.path, via), axis=1)))}

    def build_scene(self, instance) -> PlanarScene:
        return PlanarScene(self.check_instance(instance).boxes, self.config.robot_radius,
                           self.lower, self.upper)

    def render(self, instance, plan: PlanResult | None = None, path="planar.png",
               constraint=None) -> Path:
        from matplotlib.figure import Figure
        from matplotlib.patches import Circle, Rectangle

        inst = self.check_instance(instance)
        fig = Figure(figsize=(4, 4), dpi=100)  # no pyplot: no backend, no global state
        ax = fig.subplots()
        ax.set_xlim(0, self.config.size)
        ax.set_ylim(0, self.config.size)
        ax.set_aspect("equal")
        for x, y, w, h in inst.boxes:
            ax.add_patch(Rectangle((x - w / 2, y - h / 2), w, h, color="0.45"))
        for q, colour in ((self.start, "tab:green"), (self.goal, "tab:red")):
            ax.add_patch(Circle(q, self.config.robot_radius, color=colour))
        if constraint is not None:
            ax.plot(*self.constraint(constraint), marker="x", color="tab:orange", ms=10)
        if plan is not None and plan.feasible:
            ax.plot(plan.path[:, 0], plan.path[:, 1], color="tab:blue", lw=2)
        ax.set_title(f"planar instance {inst.seed}")
        out = Path(path)
        fig.savefig(out)
        return out
