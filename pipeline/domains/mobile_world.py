"""What the mobile-manipulation domains (``grasp_base``, ``pick_place``) share: fixed
furniture, boxes placed on table tops without overlap, a scene with the mobile Panda,
base poses drawn from a disc, and the two-panel render (camera view and floor plan)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet as pb

from pipeline.domains.geometry import Box, rectangle, rectangles_overlap
from pipeline.sim.mobile import PLATFORM, MobilePanda
from pipeline.sim.world import add_box, camera_image, connect

FURNITURE_RGBA = (0.55, 0.45, 0.35, 1.0)
FLOOR_RGBA = (0.85, 0.85, 0.82, 1.0)
OBSTACLE_RGBA = (0.75, 0.2, 0.15, 1.0)
TARGET_RGBA = (0.15, 0.3, 0.85, 1.0)
FLOOR = Box((12.0, 12.0, 0.02), (0.0, 0.0, -0.01), 0.0)


@dataclass(frozen=True)
class Table:
    """An axis-aligned table: top centre (x, y), top size (x, y), top height."""

    centre: tuple[float, float]
    size: tuple[float, float]
    height: float

    def box(self) -> Box:
        return Box((*self.size, self.height), (*self.centre, self.height / 2), 0.0)

    def area(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The top's (x range, y range)."""
        return tuple((c - s / 2, c + s / 2) for c, s in zip(self.centre, self.size, strict=True))

    def edge_distance(self, point) -> float:
        """Distance from ``point`` (x, y) to the nearest edge of the top (0 outside it)."""
        (x0, x1), (y0, y1) = self.area()
        return max(0.0, min(point[0] - x0, x1 - point[0], point[1] - y0, y1 - point[1]))


class TablePlacer:
    """Draws box poses on table tops, uniformly by area, without overlapping earlier ones."""

    def __init__(self, rng: np.random.Generator, tables: list[Table], gap: float = 0.01):
        self.rng, self.tables, self.gap = rng, tables, gap
        areas = np.array([t.size[0] * t.size[1] for t in tables])
        self.weights = areas / areas.sum()
        self.placed: list[np.ndarray] = []

    def block(self, corners: np.ndarray) -> None:
        """Keep boxes out of a region (say, where a fixed object lies)."""
        self.placed.append(corners)

    def place(self, size, tries: int = 200, table: int | None = None) -> dict | None:
        for _ in range(tries):
            k = table if table is not None else int(self.rng.choice(len(self.tables),
                                                                    p=self.weights))
            t = self.tables[k]
            yaw = float(self.rng.uniform(-np.pi, np.pi))
            r = float(np.hypot(size[0], size[1]) / 2)
            lo = np.asarray(t.centre) - np.asarray(t.size) / 2 + r
            hi = np.asarray(t.centre) + np.asarray(t.size) / 2 - r
            if np.any(lo >= hi):
                return None
            xy = self.rng.uniform(lo, hi)
            corners = rectangle(xy, size, yaw)
            if any(rectangles_overlap(corners, c, self.gap) for c in self.placed):
                continue
            self.placed.append(corners)
            return {"size": [round(float(v), 4) for v in size],
                    "position": [round(float(xy[0]), 4), round(float(xy[1]), 4),
                                 round(float(t.height + size[2] / 2 + 1e-3), 4)],
                    "yaw": round(yaw, 4)}
        return None


def sample_base_pose(rng: np.random.Generator, centre, radius: float) -> np.ndarray:
    """(x, y, ψ): a point uniform in the disc of ``radius`` around ``centre``, ψ uniform."""
    r = radius * np.sqrt(rng.uniform())
    a = rng.uniform(-np.pi, np.pi)
    return np.array([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a),
                     rng.uniform(-np.pi, np.pi)])


class MobileScene:
    """A pybullet client with the floor, the fixed ``furniture`` (boxes), the mobile Panda
    and one instance's boxes (replaced when another instance is loaded)."""

    def __init__(self, furniture: list[Box], contacts: str = "cached"):
        self.client_id = connect()
        add_box(self.client_id, FLOOR.size, FLOOR.position, rgba=FLOOR_RGBA)
        for b in furniture:
            add_box(self.client_id, b.size, b.position, b.yaw, rgba=FURNITURE_RGBA)
        self.robot = MobilePanda(self.client_id, contacts=contacts)
        self.robot_ids = (self.robot.platform, self.robot.body)
        self.key = None
        self.bodies: list[int] = []
        #: how many times an instance was loaded (a paused try checks it was not replaced)
        self.loads = 0

    def load(self, key, boxes: list[tuple[Box, tuple]]) -> list[int]:
        """Replace the instance boxes by ``boxes`` ((box, rgba) pairs) unless ``key`` (a
        hashable instance) is already loaded; returns their body ids."""
        if self.key != key:
            self.robot.release()
            for body in self.bodies:
                pb.removeBody(body, physicsClientId=self.client_id)
            self.bodies = [add_box(self.client_id, b.size, b.position, b.yaw, rgba=rgba)
                           for b, rgba in boxes]
            self.key = key
            self.loads += 1
        return self.bodies

    def set_configuration(self, q) -> None:
        """q = (x, y, ψ, 7 arm joints)."""
        self.robot.set_base(q[:3])
        self.robot.set_arm(q[3:])

    def close(self) -> None:
        pb.disconnect(physicsClientId=self.client_id)


def render_two_panels(scene: MobileScene, title: str, path, *, eye, target,
                      furniture: list[Box], boxes: list[tuple[Box, tuple]],
                      poses: list[tuple[np.ndarray, str, str]], base_path: np.ndarray | None,
                      extent: tuple[float, float, float, float],
                      marks: list[tuple[Box, str, str]] = ()) -> Path:
    """Camera view of ``scene`` as it is now, beside a floor plan: furniture, boxes, the
    platform's footprint at each of ``poses`` ((pose, colour, label)), the base path as a
    strip of ghost footprints, and ``marks`` (outlined boxes such as a placement)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon

    rgb = camera_image(scene.client_id, eye, target, 480, 360)
    fig = Figure(figsize=(10, 4), dpi=100)  # no pyplot: no backend, no global state
    left, right = fig.subplots(1, 2, gridspec_kw={"width_ratios": [4, 3]})
    left.imshow(rgb)
    left.axis("off")
    for b in furniture:
        right.add_patch(Polygon(rectangle(b.position, b.size, b.yaw),
                                color=FURNITURE_RGBA[:3]))
    for b, rgba in boxes:
        right.add_patch(Polygon(rectangle(b.position, b.size, b.yaw), color=rgba[:3]))
    if base_path is not None and len(base_path) > 1:
        right.plot(base_path[:, 0], base_path[:, 1], color="tab:green", lw=1.5)
        for q in _ghosts(base_path):
            right.add_patch(Polygon(rectangle(q[:2], PLATFORM, q[2]), fill=False,
                                    ec="tab:green", lw=0.5, alpha=0.5))
    for pose, colour, label in poses:
        right.add_patch(Polygon(rectangle(pose[:2], PLATFORM, pose[2]), fill=False,
                                ec=colour, lw=2, label=label))
        head = pose[:2] + 0.35 * np.array([np.cos(pose[2]), np.sin(pose[2])])
        right.plot([pose[0], head[0]], [pose[1], head[1]], color=colour, lw=2)
    for b, colour, label in marks:
        right.add_patch(Polygon(rectangle(b.position, b.size, b.yaw), fill=False,
                                ec=colour, lw=1.5, ls="--", label=label))
    right.set_xlim(extent[0], extent[1])
    right.set_ylim(extent[2], extent[3])
    right.set_aspect("equal")
    right.set_title("floor plan", fontsize=9)
    if poses or marks:
        right.legend(fontsize=7, loc="upper left")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out)
    return out


def _ghosts(path: np.ndarray, spacing: float = 0.25) -> list[np.ndarray]:
    """Poses along a base path about ``spacing`` metres apart."""
    out, travelled = [path[0]], 0.0
    for a, b in zip(path[:-1], path[1:], strict=True):
        steps = max(1, int(np.ceil(np.hypot(*(b[:2] - a[:2])) / (spacing / 4))))
        for t in np.arange(1, steps + 1) / steps:
            travelled += np.hypot(*(b[:2] - a[:2])) / steps
            if travelled >= spacing:
                out.append(a + t * (b - a))
                travelled = 0.0
    return out

