"""Domains and planners from other packages, found through Python entry points.

A package adds a domain or a planner by declaring an entry point in one of the groups below
(in its ``pyproject.toml``), whose value is ``"module:Class"``: the plug-in's config schema,
in a light module (one that imports neither a simulator nor a planning library: it is
imported whenever the pipeline registers its configs), whose ``domain_class`` or
``planner_class`` names the class that does the work, imported only when it is used:

    [project.entry-points."box_planning.domains"]
    shelf = "my_package.shelf_schema:ShelfConfig"

    [project.entry-points."box_planning.planners"]
    lazy_rrt = "my_package.lazy_settings:LazyRRTSettings"

Nothing is imported to list the names: the installed packages' metadata is read once per
process, and a plug-in's module is imported only when its name is asked for (as xarray finds
its backends).  A built-in name always wins over a plug-in of the same name, so installing a
package never changes what an existing name computes.  docs/architecture.md explains the
classes such an entry point must name.
"""

from __future__ import annotations

import functools
import importlib
from importlib.metadata import entry_points

#: entry-point group of each kind of plug-in (named after this distribution, box-planning)
GROUPS = {"domain": "box_planning.domains", "planner": "box_planning.planners"}


@functools.cache
def plugin_targets(kind: str) -> dict[str, str]:
    """name -> "module:Class" of every installed plug-in of ``kind`` ("domain" or
    "planner"), without importing any of them."""
    return {ep.name: ep.value for ep in entry_points(group=GROUPS[kind])}


def registry(kind: str, builtins: dict[str, str]) -> dict[str, str]:
    """The built-in names of ``kind`` and the installed plug-ins' (built-ins win)."""
    return {**plugin_targets(kind), **builtins}


def load(target: str):
    """The object a ``"module:Name"`` target names (its module imported)."""
    module, name = target.split(":")
    return getattr(importlib.import_module(module), name)


@functools.cache
def problem(kind: str, name: str) -> str | None:
    """Why the installed plug-in ``name`` of ``kind`` cannot be loaded (one line: its target
    and the error), or None when it loads or is not a plug-in.  A broken plug-in is left out
    of the configs, so it stops only the runs that ask for it (with this line), not every
    run."""
    target = plugin_targets(kind).get(name)
    if target is None:
        return None
    try:
        load(target)
    except Exception as exc:  # noqa: BLE001 - whatever a third-party import raises
        reason = (str(exc).strip().splitlines() or [""])[0]
        return (f"the {kind} plug-in {name!r} ({GROUPS[kind]}: {target}) cannot be loaded: "
                f"{type(exc).__name__}: {reason}")
    return None
