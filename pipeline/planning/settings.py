"""The settings of each built-in planner: one dataclass per planner, the schema of its
``conf/planner/<name>.yaml`` (registered in Hydra's ConfigStore as ``<name>_schema``).

Plain data, so that registering the pipeline's configs or validating a config loads no
planner (and neither OMPL nor scipy).  Every class checks its values when it is built
(``__post_init__``, ValueError naming the key), so the up-front validation refuses a bad
value before anything runs.  Defaults are declared here only: the YAML files, the README
and :class:`pipeline.planning.trajopt.TrajOptOptions` take them from these classes.

A store's identity holds the chosen planner's name and the keys of its own class (minus
``collision``), so a key added to one planner leaves every other planner's stores as they
are (:func:`pipeline.configs.comparable`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

#: collision checking: sphere pre-check then pybullet, or pybullet everywhere
COLLISION = ("spheres", "exact")


@dataclass
class PlannerSettings:
    """The keys every planner has.

    ``max_checks`` (configurations checked per planning call), ``wall_cap_s`` (a safety
    net only: status "timeout") and ``resolution`` (of edge checks and of the dense
    re-check of a result).  ``collision``: ``spheres`` gives a planner robots whose checks
    run a sphere pre-check and ask pybullet only what it cannot clear (the robot model's
    ``certified`` capability; the same answers and counts as ``exact``, pybullet on every
    configuration).  It changes the cost of a score matrix, never its contents, so it is
    left out of a store's identity.
    """

    name: str = "rrt_connect"
    max_checks: int = 20_000
    wall_cap_s: float = 10.0
    resolution: float = 0.01
    collision: str = "spheres"

    def __post_init__(self):
        if self.max_checks < 1:
            raise ValueError(f"planner.max_checks must be positive, got {self.max_checks}")
        if not self.wall_cap_s > 0:
            raise ValueError(f"planner.wall_cap_s must be positive, got {self.wall_cap_s}")
        if not self.resolution > 0:
            raise ValueError(f"planner.resolution must be positive, got {self.resolution}")
        if self.collision not in COLLISION:
            raise ValueError(f"planner.collision must be one of {', '.join(COLLISION)}, got "
                             f"{self.collision!r}")


@dataclass
class NoopSettings(PlannerSettings):
    """``noop`` plans nothing: the pipeline records "skipped" for every score entry (its
    stand-in for RAWPLANNER, rrt_connect, gets these keys and its own defaults)."""

    name: str = "noop"


@dataclass
class RRTConnectSettings(PlannerSettings):
    """``rrt_connect``: ``range`` is the extension length (0 = OMPL's default, 0.2 x the
    space's extent), ``shortcut_attempts`` bounds the random shortcutting of a path."""

    name: str = "rrt_connect"
    range: float = 0.0
    shortcut_attempts: int = 40

    def __post_init__(self):
        super().__post_init__()
        if self.range < 0 or self.shortcut_attempts < 0:
            raise ValueError("planner.range and planner.shortcut_attempts must be >= 0")


@dataclass
class OmplSettings(RRTConnectSettings):
    """``ompl``: one of OMPL's geometric planners by name (``algorithm``; those listed in
    :data:`pipeline.planning.ompl_adapter.ALGORITHMS`), with its parameters (``params``,
    OMPL's ParamSet names, e.g. ``{goal_bias: 0.1}``) and the shortcutting of rrt_connect.
    ``range`` > 0 sets the algorithm's ``range`` parameter (0: OMPL's default)."""

    name: str = "ompl"
    algorithm: str = "RRTConnect"  # og.<algorithm>: RRT, RRTstar, BITstar, KPIECE1, ...
    #: OMPL's names, e.g. +planner.params.goal_bias=0.1
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        super().__post_init__()
        from pipeline.planning.ompl_adapter import check_algorithm

        check_algorithm(self.algorithm, dict(self.params))


@dataclass
class TrajOptSettings(PlannerSettings):
    """``trajopt`` (:mod:`pipeline.planning.trajopt`)."""

    name: str = "trajopt"
    trajopt_waypoints: int = 20  # T: configurations from start to goal, both included
    trajopt_margin: float = 0.02  # safety margin on signed distance, metres
    trajopt_penalty: float = 10.0  # initial hinge coefficient (x10 per penalty round)
    trajopt_penalty_rounds: int = 4  # each multiplies the coefficient by 10
    trajopt_iterations: int = 30  # SQP iterations per call, over all rounds
    trajopt_trust_radius: float = 0.3  # initial trust region, radians per joint

    def __post_init__(self):
        super().__post_init__()
        if self.trajopt_waypoints < 3:
            raise ValueError("planner.trajopt_waypoints must be >= 3, got "
                             f"{self.trajopt_waypoints}")
        if (self.trajopt_margin < 0 or self.trajopt_penalty <= 0
                or self.trajopt_penalty_rounds < 1 or self.trajopt_iterations < 1
                or self.trajopt_trust_radius <= 0):
            raise ValueError("planner.trajopt_*: margin must be >= 0, penalty and "
                             "trust_radius > 0, penalty_rounds and iterations >= 1")


#: the settings class of each built-in planner (a plug-in's is its class's settings_class)
SETTINGS = {"rrt_connect": RRTConnectSettings, "ompl": OmplSettings,
            "trajopt": TrajOptSettings, "noop": NoopSettings}


def planner_label(planner) -> str:
    """A planner's name in default store paths and report labels: its ``name``, with its
    ``algorithm`` where it has one (``ompl-RRTstar``), so two OMPL algorithms' stores do not
    share a path.  ``planner``: settings or their mapping."""
    get = planner.get if isinstance(planner, dict) else lambda k, d=None: getattr(planner, k, d)
    algorithm = get("algorithm", None)
    return f"{get('name')}-{algorithm}" if algorithm else get("name")


def own_settings(settings_class: type, mapping: dict) -> dict:
    """``mapping`` (planner settings as a store's identity or a replay record holds them)
    without the keys that other built-in planners declare and ``settings_class`` does not:
    stores made before planners had a settings class each hold every planner's keys.  Any
    other key is kept, so a typo is still refused."""
    mine = set(keys_of(settings_class))
    others = {k for cls in SETTINGS.values() for k in keys_of(cls)}
    return {k: v for k, v in mapping.items() if k in mine or k not in others}


def keys_of(settings_class: type) -> list[str]:
    """The keys a settings class declares, in order."""
    return [f.name for f in fields(settings_class)]


def convert(settings: PlannerSettings, settings_class: type) -> PlannerSettings:
    """``settings`` as an instance of ``settings_class``: itself when it is one, else the
    keys both declare (``name`` included) with the class's defaults for the rest (how a
    stand-in planner, or a planner given the common settings only, gets its own)."""
    if isinstance(settings, settings_class):
        return settings
    mine = set(keys_of(settings_class))
    return settings_class(**{k: getattr(settings, k) for k in keys_of(type(settings))
                             if k in mine and k != "name"})
