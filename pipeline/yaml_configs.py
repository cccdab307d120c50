"""Reading one YAML file of ``conf/`` against its schema: the same composition Hydra does,
for code that builds a domain or planner without Hydra (tests, workers, ``box``)."""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from pipeline.planning.registry import PlannerSettings

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def load_yaml_config(group: str, name: str, schema: type, overrides: dict | None = None,
                     required: bool = True):
    """``conf/<group>/<name>.yaml`` checked against ``schema``, with ``overrides``, as a
    ``schema`` instance.  Without that file: refused, or (``required=False``, a plug-in
    that has no YAML) the schema's defaults with ``overrides``."""
    path = CONF_DIR / group / f"{name}.yaml"
    if path.is_file():
        raw = OmegaConf.load(path)
        raw.pop("defaults", None)
    elif required:
        raise ValueError(f"no {group} config {name!r}: {path} does not exist")
    else:
        raw = OmegaConf.create({})
    try:
        node = OmegaConf.merge(OmegaConf.structured(schema), raw, OmegaConf.create(overrides or {}))
        return OmegaConf.to_object(node)
    except OmegaConfBaseException as exc:
        raise ValueError(f"{group} config {name!r}: {exc}".splitlines()[0]) from None


def planner_settings(planner=None) -> PlannerSettings:
    """A PlannerSettings from a name (conf/planner/<name>.yaml), a mapping or itself."""
    if planner is None:
        planner = "rrt_connect"
    if isinstance(planner, PlannerSettings):
        return planner
    if isinstance(planner, str):
        return load_yaml_config("planner", planner, PlannerSettings)
    return load_yaml_config("planner", planner.get("name", "rrt_connect"), PlannerSettings,
                            dict(planner))
