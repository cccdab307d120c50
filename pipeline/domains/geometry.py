"""Plain geometry the domains share: boxes, rectangles on the floor plan, and drawing box
obstacles for instance specs.  No simulator."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.sim.transforms import rot_z


@dataclass(frozen=True)
class Box:
    """A box of full extents ``size`` centred at ``position``, turned by ``yaw``."""

    size: tuple[float, float, float]
    position: tuple[float, float, float]
    yaw: float


def rectangle(centre, size, yaw: float) -> np.ndarray:
    """(4, 2) corners of a rectangle of full ``size`` turned by ``yaw``."""
    half = np.asarray(size[:2], float) / 2
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
    return corners @ rot_z(yaw)[:2, :2].T + np.asarray(centre[:2], float)


def rectangles_overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> bool:
    """Separating-axis test of two convex quadrilaterals (corners in order), ``margin``
    added to the gap that counts as separation."""
    for poly in (a, b):
        for k in range(4):
            edge = poly[(k + 1) % 4] - poly[k]
            axis = np.array([-edge[1], edge[0]]) / np.hypot(*edge)
            pa, pb_ = a @ axis, b @ axis
            if pa.max() + margin < pb_.min() or pb_.max() + margin < pa.min():
                return False
    return True


def sample_obstacles(rng: np.random.Generator, count: int, size, height, place) -> list[dict]:
    """``count`` boxes with edges drawn from ``size`` and heights from ``height``, each put
    where ``place(size)`` says (None: no room left, the box is dropped)."""
    boxes = []
    for _ in range(count):
        edge = rng.uniform(*size, 2)
        box = place(np.array([edge[0], edge[1], rng.uniform(*height)]))
        if box is not None:
            boxes.append(box)
    return boxes
