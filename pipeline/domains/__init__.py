"""Planning domains: a schema (a plain dataclass), a module (a Domain subclass) and, for the
built-in ones, a YAML file under ``conf/domain/`` each; domains from other packages join
through the entry-point group ``box_planning.domains`` (:mod:`pipeline.plugins`).
``load_domain`` is how Python code gets one; Hydra composes the same configs for the
pipeline, so both see the same parameters.  Adding a domain: docs/architecture.md (the
smallest complete example is :mod:`pipeline.domains.planar`).

A domain is declared by its schema: the registry names the schema ("module:Class", in a
module that loads no simulator), and the schema's ``domain_class`` names the Domain
subclass.  So the schema of any domain is found (to register and validate configs) without
importing its domain module, and importing this package loads no domain module, hence no
simulator and no planner.
"""

from __future__ import annotations

from pipeline.domains.base import (
    ConstraintSet,
    Domain,
    Feature,
    RawResult,
    RawSearch,
    constraint_row,
)
from pipeline.domains.specs import InstanceError, finite_rows, require
from pipeline.plugins import load, registry
from pipeline.yaml_configs import CONF_DIR, load_yaml_config, planner_settings

#: The built-in domains: name -> "module:Schema" (see the module docstring).
DOMAINS = {
    "planar": "pipeline.domains.schemas:PlanarConfig",
    "grasp_arm": "pipeline.domains.schemas:GraspArmConfig",
    "grasp_base": "pipeline.domains.schemas:GraspBaseConfig",
    "pick_place": "pipeline.domains.schemas:PickPlaceConfig",
}


def domain_names() -> list[str]:
    """The built-in domains and the installed plug-ins' (nothing imported)."""
    return list(registry("domain", DOMAINS))


def domain_schema(name: str) -> type:
    """The config schema of domain ``name`` (imports its schema module only)."""
    known = registry("domain", DOMAINS)
    if name not in known:
        raise ValueError(f"unknown domain {name!r}; known domains: {', '.join(sorted(known))}")
    return load(known[name])


def domain_class(name: str) -> type[Domain]:
    return load(domain_schema(name).domain_class)


def has_yaml(name: str) -> bool:
    """Whether ``conf/domain/<name>.yaml`` exists (a plug-in's domain has none: its schema's
    defaults are its config)."""
    return (CONF_DIR / "domain" / f"{name}.yaml").is_file()


def domain_config(name: str, overrides: dict | None = None):
    """The checked config of domain ``name``: ``conf/domain/<name>.yaml`` (or, for a plug-in,
    its schema's defaults) with ``overrides``; ValueError naming a bad key or value."""
    return load_yaml_config("domain", name, domain_schema(name),
                            {**(overrides or {}), "name": name}, required=has_yaml(name))


def load_domain(name: str, planner=None, **overrides) -> Domain:
    """The domain ``name`` with parameters from ``conf/domain/<name>.yaml`` (a plug-in's:
    its schema's defaults) and ``overrides``.

    ``planner`` is a planner name (``conf/planner/<name>.yaml``), a mapping of planner
    settings, or a :class:`pipeline.planning.PlannerSettings`; default ``rrt_connect``.
    """
    config = domain_config(name, overrides)
    return domain_class(name)(config, planner_settings(planner))


__all__ = ["DOMAINS", "ConstraintSet", "Domain", "Feature", "InstanceError", "RawResult",
           "RawSearch", "constraint_row", "domain_class", "domain_config", "domain_names",
           "domain_schema", "finite_rows", "has_yaml", "load_domain", "require"]
