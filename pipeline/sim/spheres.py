"""The Panda as spheres: batched forward kinematics and a conservative sphere model.

A sphere model *covers* the arm: every point of every link's collision shape lies inside
one of that link's spheres.  So a configuration whose spheres touch nothing is certainly
collision-free, and only configurations whose spheres touch something need the exact
(pybullet) check; see :mod:`pipeline.sim.fast_check`.

Where the spheres come from.  pybullet collides a link's ``.obj`` collision mesh as the
convex hull of its vertices (one object per file here).  Each hull is cut into slabs
perpendicular to its longest principal axis; a slab's piece of the hull is the convex hull
of the hull vertices inside the slab and the points where hull edges cross the slab's two
planes, so a sphere holding those points holds the piece.  The slabs are about as thick as
the hull is wide (``slab_ratio``), which keeps the spheres tight.  Every radius then gets
``margin`` metres on top (pybullet's contact margin, rounding).

An *inner* model (:func:`panda_inner_spheres`) is the opposite: spheres inside the hulls,
so one of them deep in an obstacle proves a collision without asking pybullet.

Kinematics come from the URDF in ``pybullet_data`` (joint origins, axes, the fixed finger
opening), in the URDF link frames pybullet reports as ``worldLinkFramePosition``.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull

URDF = "franka_panda/panda.urdf"
#: pybullet's link indices of the links that have collision geometry (-1: the base link)
LINKS = (-1, 0, 1, 2, 3, 4, 5, 6, 8, 9, 10)
TCP_LINK = 11  # panda_grasptarget


def _data_path() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath())


def _rpy_matrix(rpy) -> np.ndarray:
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _origin(element) -> np.ndarray:
    T = np.eye(4)
    o = element.find("origin") if element is not None else None
    if o is not None:
        T[:3, :3] = _rpy_matrix([float(v) for v in o.get("rpy", "0 0 0").split()])
        T[:3, 3] = [float(v) for v in o.get("xyz", "0 0 0").split()]
    return T


@dataclass(frozen=True)
class Chain:
    """The URDF's joints in pybullet's order (joint k moves link k)."""

    origins: np.ndarray  # (J, 4, 4): joint frame in the parent link's frame
    axes: np.ndarray  # (J, 3)
    kinds: tuple[str, ...]  # "revolute", "prismatic" or "fixed"
    parents: tuple[int, ...]  # parent link index, -1 for the base
    link_names: tuple[str, ...]  # child link of joint k
    base_name: str
    meshes: dict  # link index -> (mesh path, 4 × 4 collision origin in the link frame)


@functools.lru_cache(maxsize=1)
def panda_chain() -> Chain:
    root = ET.parse(_data_path() / URDF).getroot()
    joints = root.findall("joint")
    children = [j.find("child").get("link") for j in joints]
    index = {name: k for k, name in enumerate(children)}
    base = next(link.get("name") for link in root.findall("link") if link.get("name")
                not in index)
    index[base] = -1
    meshes = {}
    for link in root.findall("link"):
        col = link.find("collision")
        if col is None:
            continue
        mesh = col.find("geometry/mesh").get("filename").replace("package://", "")
        meshes[index[link.get("name")]] = (_data_path() / Path(URDF).parent / mesh,
                                           _origin(col))
    return Chain(
        origins=np.stack([_origin(j) for j in joints]),
        axes=np.array([[float(v) for v in (j.find("axis").get("xyz") if j.find("axis") is not
                                           None else "0 0 0").split()] for j in joints]),
        kinds=tuple(j.get("type") for j in joints),
        parents=tuple(index[j.find("parent").get("link")] for j in joints),
        link_names=tuple(children), base_name=base, meshes=meshes)


#: pybullet link index -> the kinematic frame it rides on: 0 the base link, k + 1 the link
#: moved by arm joint k (k = 0..6); the flange, hand and fingers are fixed to link 6
FRAME_OF_LINK = {-1: 0, **{k: k + 1 for k in range(7)}, 7: 7, 8: 7, 9: 7, 10: 7, 11: 7}


@functools.lru_cache(maxsize=4)
def fixed_offsets(fingers: float = 0.04) -> dict[int, np.ndarray]:
    """4 × 4 transform of each link in the frame it rides on (identity for moving links),
    the fingers at opening ``fingers``."""
    chain = panda_chain()
    out = {-1: np.eye(4)}
    for k in range(len(chain.kinds)):
        if k < 7:
            out[k] = np.eye(4)
            continue
        T = out[chain.parents[k]] @ chain.origins[k]
        if chain.kinds[k] == "prismatic":
            T = T.copy()
            T[:3, 3] += fingers * (T[:3, :3] @ chain.axes[k])
        out[k] = T
    return out


def arm_frames(q: np.ndarray, base: np.ndarray | None = None) -> np.ndarray:
    """World frames (N, 8, 3, 4) of the base link and links 0..6 (``FRAME_OF_LINK``) for N
    arm configurations ``q`` (N, 7), the base link's frame at ``base`` (4 × 4, default the
    origin).  The seven arm joints rotate about their z axes."""
    chain = panda_chain()
    q = np.atleast_2d(np.asarray(q, float))
    n = len(q)
    frames = np.empty((n, 8, 3, 4))
    frames[:, 0] = (np.eye(4) if base is None else np.asarray(base, float))[:3]
    c, s = np.cos(q), np.sin(q)
    for k in range(7):
        parent = frames[:, k]  # the Panda's arm joints form a chain: k's parent is k - 1
        A = parent[:, :, :3] @ chain.origins[k, :3, :3]
        out = frames[:, k + 1]
        out[:, :, 3] = parent[:, :, :3] @ chain.origins[k, :3, 3] + parent[:, :, 3]
        out[:, :, 0] = c[:, k, None] * A[:, :, 0] + s[:, k, None] * A[:, :, 1]
        out[:, :, 1] = c[:, k, None] * A[:, :, 1] - s[:, k, None] * A[:, :, 0]
        out[:, :, 2] = A[:, :, 2]
    return frames


def link_frame(frames: np.ndarray, link: int, fingers: float = 0.04) -> np.ndarray:
    """(N, 4, 4) world frames of pybullet link ``link`` from :func:`arm_frames`."""
    F = frames[:, FRAME_OF_LINK[link]]
    T = np.zeros((len(frames), 4, 4))
    T[:, :3] = F @ fixed_offsets(fingers)[link]
    T[:, 3, 3] = 1.0
    return T


def _mesh_vertices(path: Path) -> np.ndarray:
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    return np.asarray(rows, float)


def _hull_pieces(points: np.ndarray, slab_ratio: float) -> list[np.ndarray]:
    """Point sets whose convex hulls cover the hull of ``points``, one per slab."""
    hull = ConvexHull(points)
    verts = points[hull.vertices]
    centred = verts - verts.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0]
    t = points @ axis
    lo, hi = t[hull.vertices].min(), t[hull.vertices].max()
    width = np.ptp(centred - np.outer(centred @ axis, axis), axis=0).max()
    count = max(1, int(np.ceil((hi - lo) / max(slab_ratio * width, 1e-3))))
    cuts = np.linspace(lo, hi, count + 1)
    edges = {tuple(sorted((int(a), int(b)))) for simplex in hull.simplices
             for a, b in ((simplex[0], simplex[1]), (simplex[1], simplex[2]),
                          (simplex[0], simplex[2]))}
    ea = np.array([e[0] for e in edges])
    eb = np.array([e[1] for e in edges])
    pieces = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        inside = verts[(verts @ axis >= a - 1e-12) & (verts @ axis <= b + 1e-12)]
        crossing = [inside]
        for plane in (a, b):
            ta, tb = t[ea], t[eb]
            cross = (ta - plane) * (tb - plane) < 0
            w = (plane - ta[cross]) / (tb[cross] - ta[cross])
            crossing.append(points[ea[cross]] + w[:, None] * (points[eb[cross]]
                                                                - points[ea[cross]]))
        pieces.append(np.concatenate(crossing))
    return pieces


def _enclosing_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """A small sphere holding ``points``: from the bounding box's centre, a few steps
    towards the farthest point (any centre gives a valid sphere: the radius is measured)."""
    centre = (points.min(axis=0) + points.max(axis=0)) / 2
    for step in np.geomspace(0.2, 0.002, 40):
        d = points - centre
        far = int(np.argmax(np.einsum("ij,ij->i", d, d)))
        centre = centre + step * d[far]
    return centre, float(np.sqrt(np.einsum("ij,ij->i", points - centre, points - centre).max()))


@dataclass(frozen=True)
class SphereModel:
    """Spheres fixed to links: ``centres`` (S, 3) in the frame their link rides on
    (``FRAME_OF_LINK``), ``radii`` (S,), ``links`` (S,) pybullet link indices."""

    centres: np.ndarray
    radii: np.ndarray
    links: np.ndarray

    @functools.cached_property
    def frames(self) -> np.ndarray:
        """The frame each sphere rides on (made once per model; read-only)."""
        out = np.array([FRAME_OF_LINK[int(k)] for k in self.links])
        out.flags.writeable = False
        return out

    def world(self, frames: np.ndarray) -> np.ndarray:
        """Centres (N, S, 3) for the frames (N, 8, 3, 4) of :func:`arm_frames`."""
        F = frames[:, self.frames]
        return np.einsum("nsij,sj->nsi", F[..., :3], self.centres) + F[..., 3]

    def subset(self, mask: np.ndarray) -> SphereModel:
        return SphereModel(self.centres[mask], self.radii[mask], self.links[mask])


@functools.lru_cache(maxsize=4)
def panda_spheres(margin: float = 0.0025, slab_ratio: float = 0.3,
                  fingers: float = 0.04) -> SphereModel:
    """The conservative sphere model of the Panda's collision meshes (module docstring),
    the fingers at opening ``fingers``."""
    centres, radii, links = [], [], []
    offsets = fixed_offsets(fingers)
    for link, (path, origin) in sorted(panda_chain().meshes.items()):
        T = offsets[link] @ origin
        verts = _mesh_vertices(path) @ T[:3, :3].T + T[:3, 3]
        for piece in _hull_pieces(verts, slab_ratio):
            c, r = _enclosing_sphere(piece)
            centres.append(c)
            radii.append(r + margin)
            links.append(link)
    return SphereModel(np.array(centres), np.array(radii), np.array(links))


@functools.lru_cache(maxsize=4)
def panda_hulls(fingers: float = 0.04) -> dict[int, np.ndarray]:
    """Each link's collision shape as pybullet collides it (the convex hull of its mesh):
    the hull's vertices (H, 3) in the frame the link rides on (``FRAME_OF_LINK``), the
    fingers at opening ``fingers``."""
    out = {}
    offsets = fixed_offsets(fingers)
    for link, (path, origin) in sorted(panda_chain().meshes.items()):
        T = offsets[link] @ origin
        verts = _mesh_vertices(path) @ T[:3, :3].T + T[:3, 3]
        out[link] = np.ascontiguousarray(verts[ConvexHull(verts).vertices])
    return out


def frame_reach() -> np.ndarray:
    """(8,) for each frame of :func:`arm_frames`, a bound on the distance of its origin
    from the origin of frame 0 (the base link's), whatever the joints."""
    steps = np.linalg.norm(panda_chain().origins[:7, :3, 3], axis=1)
    return np.concatenate([[0.0], np.cumsum(steps)])


@functools.lru_cache(maxsize=2)
def panda_inner_spheres(fingers: float = 0.04, per_link: int = 12,
                        min_radius: float = 0.01) -> SphereModel:
    """Spheres inside the Panda's collision hulls (not the base link's, whose contacts the
    exact check ignores): centres on each hull's longest principal axis, through the
    centroid of its vertices, each radius the centre's distance to the nearest hull
    facet.  Those under ``min_radius`` are dropped."""
    centres, radii, links = [], [], []
    offsets = fixed_offsets(fingers)
    for link, (path, origin) in sorted(panda_chain().meshes.items()):
        if link == -1:
            continue
        T = offsets[link] @ origin
        verts = _mesh_vertices(path) @ T[:3, :3].T + T[:3, 3]
        hull = ConvexHull(verts)
        mean = verts[hull.vertices].mean(axis=0)
        axis = np.linalg.svd(verts[hull.vertices] - mean, full_matrices=False)[2][0]
        t = (verts[hull.vertices] - mean) @ axis
        for c in mean + np.outer(np.linspace(t.min(), t.max(), per_link + 2)[1:-1], axis):
            r = -float(np.max(hull.equations[:, :3] @ c + hull.equations[:, 3]))
            if r >= min_radius:
                centres.append(c)
                radii.append(r)
                links.append(link)
    return SphereModel(np.array(centres), np.array(radii), np.array(links))
