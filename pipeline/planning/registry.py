"""Planner names and the one place that turns settings into a planner for a kind of robot.

Importing this module loads no planner; each is imported on first use.  The names are the
built-in ones below and those of installed plug-ins (entry-point group
``box_planning.planners``, :mod:`pipeline.plugins`; a built-in name wins).  Adding a
planner: its own module with a :class:`~pipeline.planning.interface.Planner` subclass and
its settings class, then a line here (built in) or an entry point (plug-in);
docs/architecture.md.
"""

from __future__ import annotations

from pipeline.planning.settings import COLLISION, SETTINGS, PlannerSettings, convert
from pipeline.plugins import load, registry

#: name -> "module:class" of the built-in planners (plug-ins: :func:`planners`)
PLANNERS = {
    "rrt_connect": "pipeline.planning.rrt_connect:RRTConnect",
    "ompl": "pipeline.planning.ompl_planner:OmplPlanner",
    "trajopt": "pipeline.planning.trajopt:TrajOpt",
    "noop": "pipeline.planning.noop:Noop",
}


def planners() -> dict[str, str]:
    """name -> "module:class" of every planner: the built-in ones (their Planner class) and
    the installed plug-ins' (their settings class, whose ``planner_class`` names the
    Planner); read once per process, nothing imported; a built-in name wins."""
    return registry("planner", PLANNERS)


def _known(name: str) -> str:
    known = planners()
    if name not in known:
        raise ValueError(f"unknown planner {name!r}; known: {', '.join(known)}")
    return known[name]


def planner_class(name: str):
    if name in PLANNERS:
        return load(PLANNERS[name])
    return load(settings_class(name).planner_class)


def planner_module(name: str) -> str:
    """The module that holds planner ``name``'s Planner class (it is not imported)."""
    target = PLANNERS[name] if name in PLANNERS else settings_class(name).planner_class
    return target.split(":")[0]


def settings_class(name: str) -> type[PlannerSettings]:
    """The settings class (schema) of planner ``name``, without importing the planner: a
    built-in's from :data:`SETTINGS`, a plug-in's from its entry point."""
    target = _known(name)
    return SETTINGS[name] if name in PLANNERS else load(target)


def plans_nothing(settings: PlannerSettings) -> bool:
    return planner_class(settings.name).plans_nothing


def make_planner(settings: PlannerSettings, robot):
    """The planner ``settings`` name for ``robot`` (a robot model or its class).

    A planner that plans nothing is replaced by its stand-in (RAWPLANNER still needs
    solutions), which gets the common keys of ``settings`` and its own defaults for the
    rest.  A planner that needs a capability the robot lacks is refused here, with the one
    message every domain gives.
    """
    from pipeline.planning.base import capabilities

    cls = planner_class(settings.name)
    if cls.stand_in is not None:
        cls = planner_class(cls.stand_in)
    missing = cls.requires - capabilities(robot)
    if missing:
        raise ValueError(f"planner={settings.name} needs {', '.join(sorted(missing))}, which "
                         f"{robot.description} does not provide; use planner=rrt_connect")
    return cls(convert(settings, cls.settings_class))


__all__ = ["COLLISION", "PLANNERS", "PlannerSettings", "make_planner",
           "planner_class", "planner_module", "planners", "plans_nothing", "settings_class"]
