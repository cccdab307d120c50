"""Reading one YAML file of ``conf/`` against its schema: the same composition Hydra does,
for code that builds a domain or planner without Hydra (tests, workers, ``box``)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from pipeline.planning.settings import PlannerSettings

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"


def load_yaml_config(group: str, name: str, schema: type, overrides: dict | None = None,
                     required: bool = True):
    """``conf/<group>/<name>.yaml`` checked against ``schema``, with ``overrides``, as a
    ``schema`` instance.  Without that file: refused, or (``required=False``, a plug-in
    that has no YAML) the schema's defaults with ``overrides``."""
    path = CONF_DIR / group / f"{name}.yaml"
    if path.is_file():
        text = path.read_text()
    elif required:
        raise ValueError(f"no {group} config {name!r}: {path} does not exist")
    else:
        text = None
    return _merged(group, name, schema, overrides, text)


def load_structured(group: str, name: str, schema: type, overrides: dict | None = None,
                    raw=None):
    """``schema``'s defaults, then ``raw`` (a YAML file's contents) and ``overrides``, as a
    ``schema`` instance (a ValueError of one line when a key or value does not fit)."""
    try:
        node = OmegaConf.merge(OmegaConf.structured(schema), raw or {},
                               OmegaConf.create(overrides or {}))
        return OmegaConf.to_object(node)
    except OmegaConfBaseException as exc:
        raise ValueError(f"{group} config {name!r}: {exc}".splitlines()[0]) from None


#: merged configs by (group, name, schema, YAML text, overrides as JSON): OmegaConf takes
#: some 20 ms to merge one, and a run, its checks and ``box`` ask for the same ones often
_MERGED: dict[tuple, object] = {}


def _merged(group: str, name: str, schema: type, overrides: dict | None, text: str | None):
    """:func:`load_structured` of a YAML file's ``text`` (None: no file), remembered per
    process; each caller gets its own copy."""
    try:
        key = (group, name, schema, text, json.dumps(overrides, sort_keys=True))
    except TypeError:  # values JSON cannot hold: merged every time
        key = None
    if key is None or key not in _MERGED:
        raw = None
        if text is not None:
            raw = OmegaConf.create(text)
            raw.pop("defaults", None)
        merged = load_structured(group, name, schema, overrides, raw)
        if key is None:
            return merged
        _MERGED[key] = merged
    return copy.deepcopy(_MERGED[key])


def planner_settings(planner=None) -> PlannerSettings:
    """The settings of a planner (an instance of its own settings class) from a name
    (``conf/planner/<name>.yaml``; a plug-in planner, which has no YAML, its schema's
    defaults), a mapping of settings (with ``name``; default rrt_connect; the keys of other
    built-in planners in it are left out, as stores made before per-planner settings hold
    them) or themselves."""
    from pipeline.planning.registry import settings_class
    from pipeline.planning.settings import own_settings

    if planner is None:
        planner = "rrt_connect"
    if isinstance(planner, PlannerSettings):
        return planner
    overrides = None if isinstance(planner, str) else dict(planner)
    name = planner if isinstance(planner, str) else planner.get("name", "rrt_connect")
    schema = settings_class(name)
    if overrides is not None:
        overrides = own_settings(schema, overrides)
    if not (CONF_DIR / "planner" / f"{name}.yaml").is_file():  # a plug-in's: its schema
        return load_structured("planner", name, schema, overrides)
    return load_yaml_config("planner", name, schema, overrides)
