"""Plain geometry the domains share: boxes, rectangles on the floor plan, and drawing box
obstacles for instance specs.  No simulator."""

from __future__ import annotations

import math
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
    """Separating-axis test of two rectangles (corners in order, as :func:`rectangle` makes
    them), ``margin`` added to the gap that counts as separation.  Rectangles far apart
    are answered by their circumcircles first (:func:`_far_apart`), with the same answer."""
    return not _far_apart(a, b, margin) and separating_axes_overlap(a, b, margin)


def _circumcircle(poly: np.ndarray) -> tuple[float, float, float]:
    (x0, y0), _, (x2, y2), _ = corners = poly.tolist()
    cx, cy = (x0 + x2) / 2, (y0 + y2) / 2
    return cx, cy, max(math.hypot(x - cx, y - cy) for x, y in corners)


def _far_apart(a: np.ndarray, b: np.ndarray, margin: float) -> bool:
    """Whether an edge normal of rectangle ``a`` certainly separates it from ``b`` by more
    than ``margin``: the line through their centres (d apart) is within 45° of one of a's
    normals, along which the centres lie at least d/√2 apart and each rectangle reaches no
    farther than its circumradius.  1e-9 m more covers the rounding of both tests.
    (Sampling pick_place's obstacles spent nearly all its time on such pairs.)"""
    ax, ay, ra = _circumcircle(a)
    bx, by, rb = _circumcircle(b)
    return math.hypot(ax - bx, ay - by) > math.sqrt(2.0) * (ra + rb + margin + 1e-9)


def separating_axes_overlap(a: np.ndarray, b: np.ndarray, margin: float = 0.0) -> bool:
    """The separating-axis test itself, for two convex quadrilaterals (corners in order):
    no edge normal separates them by more than ``margin``."""
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
