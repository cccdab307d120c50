"""Reading instance specs (JSON objects): fields checked by type, finite number rows, boxes.
Every error is an :class:`InstanceError` naming the field."""

from __future__ import annotations

import math

import numpy as np

from pipeline.domains.geometry import Box


class InstanceError(ValueError):
    """An instance spec with a missing or malformed field."""


def require(instance: dict, key: str, kind: type | tuple[type, ...]):
    """``instance[key]``, checked to be of ``kind``; InstanceError naming the key if not."""
    if not isinstance(instance, dict):
        raise InstanceError(f"instance spec must be a JSON object, got {type(instance).__name__}")
    if key not in instance:
        raise InstanceError(f"instance spec: missing field {key!r}")
    value = instance[key]
    if isinstance(value, bool) or not isinstance(value, kind):  # no field is boolean
        raise InstanceError(f"instance spec: field {key!r} has the wrong type "
                            f"({type(value).__name__})")
    return value


def finite_rows(value, key: str, width: int) -> np.ndarray:
    """A list of ``width``-number lists, all finite, as an (k, width) array."""
    try:
        arr = np.asarray(value, dtype=float).reshape(-1, width) if len(value) else \
            np.empty((0, width))
    except (TypeError, ValueError):
        raise InstanceError(f"instance spec: field {key!r} must be a list of "
                            f"{width}-number lists") from None
    if len(arr) != len(value) or not all(math.isfinite(x) for x in arr.ravel()):
        raise InstanceError(f"instance spec: field {key!r} must be a list of finite "
                            f"{width}-number lists")
    return arr


def parse_box(value, key: str) -> Box:
    """A box spec {"size", "position", "yaw"} as a :class:`Box`."""
    if not isinstance(value, dict):
        raise InstanceError(f"instance spec: {key} must be an object with size, position, yaw")
    size = finite_rows([require(value, "size", list)], f"{key}.size", 3)[0]
    pos = finite_rows([require(value, "position", list)], f"{key}.position", 3)[0]
    yaw = require(value, "yaw", (int, float))
    if np.any(size <= 0) or not np.isfinite(yaw):
        raise InstanceError(f"instance spec: {key} needs a positive size and a finite yaw")
    return Box(tuple(size), tuple(pos), float(yaw))


def parse_obstacles(instance) -> tuple[Box, ...]:
    """The spec's ``obstacles`` list as boxes (InstanceError naming a bad one)."""
    return tuple(parse_box(o, f"obstacles[{k}]")
                 for k, o in enumerate(require(instance, "obstacles", list)))
