"""Geometry for the domains' instance features
(:meth:`pipeline.domains.base.Domain.instance_features`): gaps between boxes, what lies near
a box, which region a point lies in.  Plain numpy, no
simulator: every value follows from the instance spec alone.

Boxes here turn about z only (:class:`~pipeline.domains.geometry.Box`), so each is a prism:
its footprint (a rectangle) extruded over its height.  The gap between two such prisms is
exact: ``hypot(footprint gap, height gap)``, because the set of differences of two prisms is
the product of the footprints' differences and the height intervals' differences.
"""

from __future__ import annotations

import numpy as np

from pipeline.domains.geometry import Box, rectangle, rectangles_overlap

#: Gaps are reported up to this many metres: "nothing within 1 m" counts as 1 m, so that a
#: feature stays finite (and comparable) when an instance has no obstacle at all.
GAP_CAP = 1.0
#: The radii (metres) within which the near-obstacle counts are taken.
NEAR = (0.10, 0.20)


def footprint_gap(a: np.ndarray, b: np.ndarray) -> float:
    """The distance between two convex polygons (corners in order), 0 when they overlap."""
    if rectangles_overlap(a, b):
        return 0.0
    return min(min(_point_segment(p, poly[k], poly[(k + 1) % len(poly)])
                   for p in other for k in range(len(poly)))
               for poly, other in ((a, b), (b, a)))


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0)
    return float(np.hypot(*(p - (a + t * ab))))


def box_gap(a: Box, b: Box) -> float:
    """The distance between two boxes (0 when they touch or overlap)."""
    flat = footprint_gap(rectangle(a.position, a.size, a.yaw),
                         rectangle(b.position, b.size, b.yaw))
    rise = abs(a.position[2] - b.position[2]) - (a.size[2] + b.size[2]) / 2
    return float(np.hypot(flat, max(rise, 0.0)))


def gaps(box: Box, others) -> np.ndarray:
    """(k,) the gap from ``box`` to each of ``others``."""
    return np.array([box_gap(box, o) for o in others], dtype=float)


def nearby(box: Box, others) -> list[float]:
    """What lies near ``box``: the gap to the nearest of ``others`` (capped at GAP_CAP), and
    how many of them lie within each radius of NEAR."""
    found = gaps(box, others)
    nearest = min(float(found.min()), GAP_CAP) if len(found) else GAP_CAP
    return [nearest, *(float(np.count_nonzero(found <= r)) for r in NEAR)]


def headroom(box: Box, above) -> float:
    """Free height over ``box``'s top: up to the lowest of ``above`` (boxes) whose footprint
    overlaps its own and whose bottom lies higher than its top; GAP_CAP when none."""
    top = box.position[2] + box.size[2] / 2
    mine = rectangle(box.position, box.size, box.yaw)
    room = [o.position[2] - o.size[2] / 2 - top for o in above
            if o.position[2] - o.size[2] / 2 >= top
            and rectangles_overlap(mine, rectangle(o.position, o.size, o.yaw))]
    return min([GAP_CAP, *room])


def one_hot(index: int, count: int) -> list[float]:
    return [1.0 if k == index else 0.0 for k in range(count)]


def region_of(point, regions) -> int:
    """The index of the first axis-aligned region ((x0, x1), (y0, y1)) holding ``point``'s
    x and y, else that of the nearest region's centre."""
    x, y = float(point[0]), float(point[1])
    for k, ((x0, x1), (y0, y1)) in enumerate(regions):
        if x0 <= x <= x1 and y0 <= y <= y1:
            return k
    centres = np.array([[(x0 + x1) / 2, (y0 + y1) / 2] for (x0, x1), (y0, y1) in regions])
    return int(np.argmin(np.hypot(centres[:, 0] - x, centres[:, 1] - y)))


def yaw_features(yaw: float) -> list[float]:
    """An angle as (cos, sin): nearby headings stay near across ±π."""
    return [float(np.cos(yaw)), float(np.sin(yaw))]
