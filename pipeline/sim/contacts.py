"""History-free penetration checks in pybullet.

``performCollisionDetection`` keeps one persistent contact manifold per overlapping pair of
collision objects between calls.  At each call the pair's narrow phase adds the contacts it
finds now, then ``refreshContactPoints`` moves the points already cached with the bodies
(from their stored local points, distance measured along the *stored* normal) and drops
only those that drifted beyond the pair's contact breaking threshold (about 2 % of the
smaller shape's bounding radius; millimetres for Panda links, about a centimetre for a
long rod).  After a teleport (``resetBasePositionAndOrientation``,
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
"""

from __future__ import annotations

from collections.abc import Callable

import pybullet as pb

#: a contact point as ``getContactPoints`` returns it -> whether the check ignores it
Ignore = Callable[[tuple], bool]


def confirmed(client: int, body_a: int, link_a: int, body_b: int, link_b: int) -> bool:
    """Whether link ``link_a`` of ``body_a`` and link ``link_b`` of ``body_b`` penetrate,
    computed afresh (no cached manifold)."""
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
