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


def corners(boxes) -> np.ndarray:
    """(k, 4, 2) the footprint corners of each box, in order."""
    return np.array([rectangle(b.position, b.size, b.yaw) for b in boxes]).reshape(-1, 4, 2)


def footprint_gaps(a: np.ndarray, others: np.ndarray) -> np.ndarray:
    """(k,) the distance from the convex quadrilateral ``a`` (4, 2) to each of ``others``
    (k, 4, 2), 0 where they overlap (separating axes; else the least distance from a corner
    of one to an edge of the other)."""
    separated = np.zeros(len(others), dtype=bool)
    for axes in (_normals(a)[None], _normals(others)):  # (1 or k, 4, 2)
        pa = np.einsum("vd,kad->kav", a, axes)  # (k, axis, corner)
        pb = np.einsum("kvd,kad->kav", others, axes)
        separated |= np.any((pa.max(-1) < pb.min(-1)) | (pb.max(-1) < pa.min(-1)), axis=1)
    ahead = np.roll(a, -1, axis=0)
    from_a = _point_segment(a[None, :, None], others[:, None], np.roll(others, -1, axis=1)[:, None])
    from_b = _point_segment(others[:, :, None], a[None, None], ahead[None, None])
    gap = np.minimum(from_a.min(axis=(1, 2)), from_b.min(axis=(1, 2)))
    return np.where(separated, gap, 0.0)


def _normals(polys: np.ndarray) -> np.ndarray:
    """Unit normals of the edges of polygons (..., 4, 2)."""
    edges = np.roll(polys, -1, axis=-2) - polys
    normal = np.stack([-edges[..., 1], edges[..., 0]], axis=-1)
    return normal / np.linalg.norm(normal, axis=-1, keepdims=True)


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distances from points ``p`` to segments a-b (broadcast over the leading axes)."""
    ab, ap = b - a, p - a
    t = np.clip(np.sum(ap * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0.0, 1.0)
    return np.linalg.norm(ap - t[..., None] * ab, axis=-1)


def gaps(box: Box, others) -> np.ndarray:
    """(k,) the distance from ``box`` to each of ``others`` (boxes; 0 where they touch or
    overlap)."""
    others = list(others)
    if not others:
        return np.zeros(0)
    flat = footprint_gaps(corners([box])[0], corners(others))
    z = np.array([o.position[2] for o in others])
    h = np.array([o.size[2] for o in others])
    rise = np.maximum(np.abs(box.position[2] - z) - (box.size[2] + h) / 2, 0.0)
    return np.hypot(flat, rise)


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
