"""History-free penetration checks in pybullet.

``performCollisionDetection`` keeps one persistent contact manifold per overlapping pair of
collision objects between calls.  At each call the pair's narrow phase adds the contacts it
finds now, then ``refreshContactPoints`` moves the points already cached with the bodies
(from their stored local points, distance measured along the *stored* normal) and drops
only those that moved apart along that normal, or slid sideways, by more than the pair's
contact breaking threshold (2 % of the smaller shape's bounding radius: millimetres for
Panda links, 4 mm for a 40 cm rod).  After a teleport (``resetBasePositionAndOrientation``,
``resetJointStatesMultiDof``) a cached point can therefore still report a penetration
where the shapes are apart: slide a box a few millimetres off the edge of the box it sank
into and ``getContactPoints`` keeps reporting the old depth.  Which points are cached
depends on what the client checked before, so the plain check's answer near contact
depends on the check history (docs/contacts.md).

:func:`penetrating` confirms each candidate pair of links that the cached contacts report
penetrating with ``getClosestPoints(..., 0.0)`` on that pair alone, which builds a new
collision algorithm with no manifold for the query: the answer is a function of the poses.
A pair that really penetrates always has a candidate, since the narrow phase adds the
contact it finds now at every call; only stale candidates are dropped.  Free
configurations cost nothing extra (no candidate, no query).

Two boxes are confirmed by the separating-axis test on their current poses instead: that
is what pybullet's box-box narrow phase computes (exact boxes), while ``getClosestPoints``
runs GJK on boxes with edges and corners rounded by the 1 mm collision margin and calls
boxes apart that overlap by up to about 0.8 mm across two edges (more at corners).  So the
confirmed answer is the one the plain check gives in a client with no history.
"""

from __future__ import annotations

from collections.abc import Callable

import pybullet as pb

#: a contact point as ``getContactPoints`` returns it -> whether the check ignores it
Ignore = Callable[[tuple], bool]


#: cross products of two edge directions shorter than this are parallel edges: no axis
PARALLEL = 1e-9


def box_of(client: int, body: int, link: int):
    """(axes, centre, half extents) of a body that is a single box (its base link, no
    joints): its three axes as unit 3-tuples in world coordinates; None for anything
    else."""
    if link != -1 or pb.getNumJoints(body, physicsClientId=client):
        return None
    shapes = pb.getCollisionShapeData(body, -1, physicsClientId=client)
    if len(shapes) != 1 or shapes[0][2] != pb.GEOM_BOX:
        return None
    position, orientation = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    centre, turn = pb.multiplyTransforms(position, orientation, shapes[0][5], shapes[0][6])
    m = pb.getMatrixFromQuaternion(turn)  # row-major: axis i is column i
    axes = tuple((m[i], m[3 + i], m[6 + i]) for i in range(3))
    return axes, centre, tuple(e / 2 for e in shapes[0][3])


def _dot(u, v) -> float:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def boxes_overlap(a, b) -> bool:
    """Whether two boxes (as :func:`box_of` gives them) overlap with positive depth: no
    separating axis among both boxes' face normals and the cross products of their edges
    (touching is not overlapping, as for pybullet's box-box contacts).  Plain floats: for
    15 axes numpy's per-call overhead costs more than the arithmetic."""
    (A, ca, ha), (B, cb, hb) = a, b
    d = (cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2])
    axes = [*A, *B]
    for u in A:
        for v in B:
            n = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                 u[0] * v[1] - u[1] * v[0])
            length = _dot(n, n) ** 0.5
            if length > PARALLEL:
                axes.append((n[0] / length, n[1] / length, n[2] / length))
    for n in axes:
        reach = (ha[0] * abs(_dot(n, A[0])) + ha[1] * abs(_dot(n, A[1]))
                 + ha[2] * abs(_dot(n, A[2])) + hb[0] * abs(_dot(n, B[0]))
                 + hb[1] * abs(_dot(n, B[1])) + hb[2] * abs(_dot(n, B[2])))
        if abs(_dot(n, d)) >= reach:
            return False
    return True


def confirmed(client: int, body_a: int, link_a: int, body_b: int, link_b: int) -> bool:
    """Whether link ``link_a`` of ``body_a`` and link ``link_b`` of ``body_b`` penetrate,
    computed afresh (no cached manifold): two boxes by :func:`boxes_overlap`, anything else
    by ``getClosestPoints`` with distance 0."""
    a, b = box_of(client, body_a, link_a), box_of(client, body_b, link_b)
    if a is not None and b is not None:
        return boxes_overlap(a, b)
    return any(pt[8] < 0 for pt in pb.getClosestPoints(
        body_a, body_b, 0.0, linkIndexA=link_a, linkIndexB=link_b, physicsClientId=client))


def penetrating(client: int, body: int, ignore: Ignore | None = None) -> bool:
    """Whether ``body`` penetrates anything at the poses last detected (call
    ``performCollisionDetection`` first): the contacts of ``body`` with distance < 0 that
    ``ignore`` does not reject, each pair of links confirmed by :func:`confirmed`."""
    seen = set()
    for pt in pb.getContactPoints(bodyA=body, physicsClientId=client):
        if pt[8] >= 0 or (ignore is not None and ignore(pt)):
            continue
        pair = (pt[3], pt[2], pt[4])
        if pair in seen:
            continue
        seen.add(pair)
        if confirmed(client, body, *pair):
            return True
    return False


def collides(client: int, body: int, ignore: Ignore | None = None) -> bool:
    """:func:`penetrating` after a fresh ``performCollisionDetection``: the history-free
    replacement of ``performCollisionDetection`` + "any contact of ``body`` with distance
    < 0 not ignored"."""
    pb.performCollisionDetection(physicsClientId=client)
    return penetrating(client, body, ignore)


def cached_collides(client: int, body: int, ignore: Ignore | None = None) -> bool:
    """The plain check the project used so far (history-dependent near contact): kept for
    comparisons and tests."""
    pb.performCollisionDetection(physicsClientId=client)
    return any(pt[8] < 0 and not (ignore is not None and ignore(pt))
               for pt in pb.getContactPoints(bodyA=body, physicsClientId=client))
