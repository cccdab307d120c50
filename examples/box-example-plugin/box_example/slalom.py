"""``slalom``: a square robot crosses a room from left to right through the doors of two
walls, pillars in the way.

An instance (a seed) draws which of each wall's door places are open, and the pillars.  A
solution constraint θ is the pair of heights at which the robot passes the two walls;
π(ω, θ) plans start → the first wall at θ₁ → the second wall at θ₂ → goal with the
configured planner, the three legs sharing one check budget.  RAWPLANNER plans start → goal
directly, unguided, and the heights at which its path first crosses the walls are the
constraint extracted from its solution.

It uses only the public API of ``pipeline.domains`` and ``pipeline.planning``: a Domain
subclass, its robot model (a :class:`pipeline.planning.Robot`) and no simulator.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from box_example.schema import SlalomConfig
from pipeline.domains import (
    Domain,
    Feature,
    InstanceError,
    RawSearch,
    constraint_row,
    finite_rows,
    require,
)
from pipeline.planning import PlanResult, Robot, Status, path_is_free, path_length


@dataclass(frozen=True)
class SlalomInstance:
    seed: int
    doors: np.ndarray  # (2, doors) bool: which door places of each wall are open
    pillars: np.ndarray  # (k, 4): centre x, centre y, width, height


class SlalomScene(Robot):
    """The walls and pillars as axis-aligned boxes, and the square robot's model: its centre
    is the configuration, inside ``lower``/``upper``."""

    description = "the slalom square robot"
    client_id = None  # no simulator
    robot_ids = ()

    def __init__(self, boxes: np.ndarray, half_width: float, lower=None, upper=None):
        self.centres = boxes[:, :2]
        self.reach = boxes[:, 2:] / 2 + half_width  # centre distances that overlap, per axis
        self.lower, self.upper = lower, upper
        self.configuration = None

    def set_configuration(self, q) -> None:
        self.configuration = np.asarray(q, float)

    def collides(self, states: np.ndarray) -> np.ndarray:
        """(k,) bool: the square at each state overlaps a box."""
        gap = np.abs(states[:, None] - self.centres[None])
        return np.any(np.all(gap < self.reach[None], axis=2), axis=1)

    def check(self, states: np.ndarray) -> tuple[bool, int]:
        hits = np.flatnonzero(self.collides(states))
        return (True, len(states)) if hits.size == 0 else (False, int(hits[0]) + 1)


class SlalomDomain(Domain):
    name = "slalom"
    fixed_constraints = False
    steps = ("first_door", "second_door", "goal_leg")
    theta_features = (Feature("door_1_y", "m", "height at which the robot passes wall 1"),
                      Feature("door_2_y", "m", "height at which the robot passes wall 2"))
    length_units = "m"

    def __init__(self, config: SlalomConfig, planner):
        super().__init__(config, planner)
        c = config
        self.walls_x = np.array([c.size / 3, 2 * c.size / 3])
        self.start = np.array([1.0, c.size / 2])
        self.goal = np.array([c.size - 1.0, c.size / 2])
        self.lower = np.full(2, c.half_width)
        self.upper = np.full(2, c.size - c.half_width)
        self.motion = self.planner_for(SlalomScene)

    # -- instances and constraints -------------------------------------------------------
    def sample_instance(self, seed: int) -> dict:
        c = self.config
        rng = np.random.default_rng(int(seed))
        doors = rng.random((2, c.doors)) < c.open_share
        doors[np.arange(2), rng.integers(0, c.doors, 2)] = True  # a way through each wall
        pillars = []
        for _ in range(int(rng.integers(0, c.pillars_max + 1))):
            x, y = rng.uniform(0.0, c.size, 2)
            box = np.array([[x, y, c.pillar_size, c.pillar_size]])
            ends = np.stack([self.start, self.goal])
            if not SlalomScene(box, 2 * c.half_width).collides(ends).any():
                pillars.append([round(float(v), 6) for v in box[0]])
        return {"domain": self.name, "seed": int(seed),
                "doors": doors.astype(int).tolist(), "obstacles": pillars}

    def check_instance(self, instance) -> SlalomInstance:
        if isinstance(instance, SlalomInstance):
            return instance
        seed = require(instance, "seed", int)
        doors = finite_rows(require(instance, "doors", list), "doors", self.config.doors)
        if doors.shape[0] != 2 or not np.all((doors == 0) | (doors == 1)):
            raise InstanceError("instance spec: field 'doors' must be 2 rows of 0 or 1")
        pillars = finite_rows(require(instance, "obstacles", list), "obstacles", 4)
        if np.any(pillars[:, 2:] <= 0):
            raise InstanceError("instance spec: field 'obstacles' has a box with a size <= 0")
        return SlalomInstance(seed=seed, doors=doors.astype(bool), pillars=pillars)

    def constraint(self, constraint) -> np.ndarray:
        """θ: the two heights, inside the room."""
        heights = constraint_row(constraint, self.name)
        if (heights.shape != (2,) or not np.all(np.isfinite(heights))
                or np.any(heights < self.lower[1]) or np.any(heights > self.upper[1])):
            raise ValueError(f"slalom constraint must be 2 heights inside the room, got "
                             f"{constraint!r}")
        return heights

    # -- π and RAWPLANNER ----------------------------------------------------------------
    def _plan(self, inst: SlalomInstance, heights: np.ndarray, seed: int) -> PlanResult:
        robot = self.build_scene(inst)
        budget = self.motion.budget(robot)
        points = [self.start, *np.column_stack([self.walls_x, heights]), self.goal]
        legs = []
        for leg, (a, b) in enumerate(zip(points[:-1], points[1:], strict=True)):
            result = self.motion.plan(robot, a, b, seed=3 * seed + leg, budget=budget)
            if not result.feasible:
                result.checks, result.step = budget.used, self.steps[leg]
                return result
            legs.append(result.path if not legs else result.path[1:])
        path = np.concatenate(legs)
        return PlanResult(Status.OK, path=path, length=path_length(path), checks=budget.used)

    def _raw_search(self, inst: SlalomInstance, seed: int) -> RawSearch:
        """Start → goal unguided, a new planner seed per try; θ is where the path crosses."""
        robot = self.build_scene(inst)
        checks = 0
        for tries in range(1, self.config.raw_max_tries + 1):
            plan = self.motion.plan(robot, self.start, self.goal,
                                    seed=seed * self.config.raw_max_tries + tries)
            checks += plan.checks
            if plan.feasible:
                return RawSearch(plan, self.crossings(plan.path), tries, checks)
            plan.step = self.steps[-1]
        return RawSearch(plan, None, tries, checks)

    def crossings(self, path: np.ndarray) -> np.ndarray:
        """The height at which ``path`` first reaches each wall's x."""
        out = []
        for x in self.walls_x:
            i = int(np.argmax(path[1:, 0] >= x))  # the first state at or past the wall
            (x0, y0), (x1, y1) = path[i], path[i + 1]
            out.append(y1 if x1 == x0 else y0 + (x - x0) / (x1 - x0) * (y1 - y0))
        return np.asarray(out, float)

    # -- inspection ------------------------------------------------------------------------
    def recheck(self, instance, constraint, plan: PlanResult) -> dict[str, bool]:
        return {"path": path_is_free(plan.path, self.build_scene(instance),
                                     self.planner.resolution)}

    def walls(self, inst: SlalomInstance) -> np.ndarray:
        """(k, 4) boxes: each wall between its open doors."""
        c = self.config
        centres = c.size * np.arange(1, c.doors + 1) / (c.doors + 1)
        boxes = []
        for x, open_ in zip(self.walls_x, inst.doors, strict=True):
            edges = [0.0]
            for y in centres[open_]:
                edges += [y - c.door_width / 2, y + c.door_width / 2]
            edges.append(c.size)
            boxes += [[x, (lo + hi) / 2, c.wall_thickness, hi - lo]
                      for lo, hi in zip(edges[::2], edges[1::2], strict=True) if hi > lo]
        return np.asarray(boxes, float).reshape(-1, 4)

    def build_scene(self, instance) -> SlalomScene:
        inst = self.check_instance(instance)
        boxes = np.concatenate([self.walls(inst), inst.pillars.reshape(-1, 4)])
        return SlalomScene(boxes, self.config.half_width, self.lower, self.upper)

    def render(self, instance, plan: PlanResult | None = None, path="slalom.png",
               constraint=None) -> Path:
        from matplotlib.figure import Figure
        from matplotlib.patches import Rectangle

        inst = self.check_instance(instance)
        fig = Figure(figsize=(4, 4), dpi=100)
        ax = fig.subplots()
        ax.set_xlim(0, self.config.size)
        ax.set_ylim(0, self.config.size)
        ax.set_aspect("equal")
        for x, y, w, h in np.concatenate([self.walls(inst), inst.pillars.reshape(-1, 4)]):
            ax.add_patch(Rectangle((x - w / 2, y - h / 2), w, h, color="0.45"))
        r = self.config.half_width
        for q, colour in ((self.start, "tab:green"), (self.goal, "tab:red")):
            ax.add_patch(Rectangle(q - r, 2 * r, 2 * r, color=colour))
        if constraint is not None:
            ax.plot(self.walls_x, self.constraint(constraint), "x", color="tab:orange", ms=10)
        if plan is not None and plan.feasible:
            ax.plot(plan.path[:, 0], plan.path[:, 1], color="tab:blue", lw=2)
        ax.set_title(f"slalom instance {inst.seed}")
        out = Path(path)
        fig.savefig(out)
        return out
