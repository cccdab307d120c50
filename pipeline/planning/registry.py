"""Planner names and the one place that turns settings into a planner for a kind of robot.

Importing this module loads no planner; each is imported on first use.  The names are the
built-in ones below and those of installed plug-ins (entry-point group
``box_planning.planners``, :mod:`pipeline.plugins`; a built-in name wins).  Adding a
planner: its own module with a :class:`~pipeline.planning.interface.Planner` subclass and
its settings class, then a line here (built in) or an entry point (plug-in);
docs/architecture.md.
"""

from __future__ import annotations

import importlib

from pipeline.planning.settings import COLLISION, SETTINGS, PlannerSettings, convert
from pipeline.plugins import registry

#: name -> "module:class" of the built-in planners (plug-ins: :func:`planners`)
PLANNERS = {
    "rrt_connect": "pipeline.planning.rrt_connect:RRTConnect",
    "ompl": "pipeline.planning.ompl_planner:OmplPlanner",
    "trajopt": "pipeline.planning.trajopt:TrajOpt",
    "noop": "pipeline.planning.noop:Noop",
}


def planners() -> dict[str, str]:
    """name -> "module:class" of every planner: the built-in ones and the installed
    plug-ins' (read once per process, without importing them; a built-in name wins)."""
    return registry("planner", PLANNERS)


def planner_class(name: str):
    known = planners()
    if name not in known:
        raise ValueError(f"unknown planner {name!r}; known: {', '.join(known)}")
    module, cls = known[name].split(":")
    return getattr(importlib.import_module(module), cls)


def settings_class(name: str) -> type[PlannerSettings]:
    """The settings class (schema) of planner ``name``: a built-in's without importing the
    planner, a plug-in's from its class's ``settings_class``."""
    if name in SETTINGS and name in PLANNERS:
        return SETTINGS[name]
    return planner_class(name).settings_class


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
           "planner_class", "planners", "plans_nothing", "settings_class"]
