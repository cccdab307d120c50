"""Planning domains: one module (a Domain subclass), one schema in
:mod:`pipeline.domains.schemas` and one YAML file under ``conf/domain/`` each.
``load_domain`` is how Python code gets one; Hydra composes the same YAML files for the
pipeline, so both see the same parameters.  Adding a domain: docs/architecture.md (the
smallest complete example is :mod:`pipeline.domains.planar`).

Importing this package loads no domain module, hence no simulator and no planner.
"""

from __future__ import annotations

import importlib

from pipeline.domains.base import ConstraintSet, Domain, InstanceError, RawResult
from pipeline.domains.schemas import DOMAIN_SCHEMAS
from pipeline.yaml_configs import load_yaml_config, planner_settings

#: name -> "module:class"; imported on first use so that unused simulators stay unloaded.
DOMAINS = {
    "planar": "pipeline.domains.planar:PlanarDomain",
    "grasp_arm": "pipeline.domains.grasp_arm:GraspArmDomain",
    "grasp_base": "pipeline.domains.grasp_base:GraspBaseDomain",
    "pick_place": "pipeline.domains.pick_place:PickPlaceDomain",
}


def domain_class(name: str) -> type[Domain]:
    if name not in DOMAINS:
        raise ValueError(f"unknown domain {name!r}; known domains: {', '.join(sorted(DOMAINS))}")
    module, cls = DOMAINS[name].split(":")
    return getattr(importlib.import_module(module), cls)


def load_domain(name: str, planner=None, **overrides) -> Domain:
    """The domain ``name`` with parameters from ``conf/domain/<name>.yaml`` and ``overrides``.

    ``planner`` is a planner name (``conf/planner/<name>.yaml``), a mapping of planner
    settings, or a :class:`pipeline.planning.PlannerSettings`; default ``rrt_connect``.
    """
    cls = domain_class(name)
    config = load_yaml_config("domain", name, DOMAIN_SCHEMAS[name], overrides)
    return cls(config, planner_settings(planner))


__all__ = ["DOMAINS", "ConstraintSet", "Domain", "InstanceError", "RawResult", "domain_class",
           "load_domain"]
