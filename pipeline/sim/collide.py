"""Compiled geometry for the sphere pre-check: frames, spheres against boxes and spheres,
boxes against boxes (separating axes), one state after another with an early exit.

Everything here answers one question per configuration: could the robot touch anything?
False is a proof (the robot's spheres and boxes cover its geometry, see
:mod:`pipeline.sim.spheres`); True only means "ask pybullet".  One kernel answers the
opposite question, a proof of collision: a box the robot carries (its platform, a held
object) deep inside a box of the world (:func:`box_hit`: exact geometry on both sides), or
a sphere inside a link's hull deep inside one (:func:`sphere_hit`).
The kernels are compiled with numba (``cache=True``: compiled once per installation, then
loaded in about 0.1 s).

Layouts.  A *frame* is a 3 × 4 array [R | t].  The robot is a list of sphere *groups*
(the spheres of one link, or of a held object), each riding on one frame, with a
bounding sphere for a quick first test; and optional robot boxes (a mobile base's
platform), each riding on a frame.  The world is a list of boxes (centre, rotation,
half extents, circumradius) and a list of spheres (say, another robot's).

Segments.  An arm's straight motion is scanned row by row, but most of its rows lie in
free space, far from everything.  The scan first tries a whole segment of ``SEGMENT``
consecutive rows at once (:func:`_segment_clear`): the frames at the segment's middle,
and every radius grown by how far the motion can move that part within the segment (a
bound from the chain's lengths, :func:`_levers`).  Where no grown sphere or box touches
anything, the row test clears every row of the segment, so those rows need no test of
their own; the scan's answer is the row test's, row for row.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def arm_frames(q, base, origins, out):  # pragma: no cover (compiled)
    """Frames (N, 8, 3, 4) of a 7-joint chain whose joints rotate about their own z:
    frame 0 is ``base`` (3 × 4), frame k + 1 = frame k · origins[k] · Rz(q[k])."""
    for n in range(q.shape[0]):
        _chain(q[n], base, origins, out[n])


@njit(cache=True)
def planar_frames(states, psi_scale, out):  # pragma: no cover (compiled)
    """Frames (N, 1, 3, 4) of base states (x, y, psi_scale · ψ): a turn about z."""
    for n in range(states.shape[0]):
        psi = states[n, 2] / psi_scale
        c, s = math.cos(psi), math.sin(psi)
        out[n, 0] = 0.0
        out[n, 0, 0, 0], out[n, 0, 0, 1], out[n, 0, 0, 3] = c, -s, states[n, 0]
        out[n, 0, 1, 0], out[n, 0, 1, 1], out[n, 0, 1, 3] = s, c, states[n, 1]
        out[n, 0, 2, 2] = 1.0


@njit(cache=True)
def _apply(F, p, out):  # pragma: no cover (compiled)
    for i in range(3):
        out[i] = F[i, 0] * p[0] + F[i, 1] * p[1] + F[i, 2] * p[2] + F[i, 3]


@njit(cache=True)
def _place(F, T, R, c):  # pragma: no cover (compiled)
    """World rotation R and centre c of a box at pose T (3 × 4) in frame F (3 × 4)."""
    for i in range(3):
        for j in range(3):
            R[i, j] = F[i, 0] * T[0, j] + F[i, 1] * T[1, j] + F[i, 2] * T[2, j]
        c[i] = F[i, 0] * T[0, 3] + F[i, 1] * T[1, 3] + F[i, 2] * T[2, 3] + F[i, 3]


@njit(cache=True)
def _off_aabb(x, y, z, r, c, e):  # pragma: no cover (compiled)
    """Does the sphere (x, y, z; r) miss the axis-aligned box (centre c, half extents e)
    that holds a world box?  (A first test, tighter than the box's circumsphere.)"""
    acc = 0.0
    d = abs(x - c[0]) - e[0]
    if d > 0.0:
        acc += d * d
    d = abs(y - c[1]) - e[1]
    if d > 0.0:
        acc += d * d
    d = abs(z - c[2]) - e[2]
    if d > 0.0:
        acc += d * d
    return acc >= r * r


@njit(cache=True)
def _sphere_box(p, r, c, R, h):  # pragma: no cover (compiled)
    """Does the sphere (p, r) reach into the box (centre c, rotation R, half extents h)?"""
    d0, d1, d2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    out = 0.0
    for j in range(3):
        e = abs(d0 * R[0, j] + d1 * R[1, j] + d2 * R[2, j]) - h[j]
        if e > 0.0:
            out += e * e
    return out < r * r


@njit(cache=True)
def _relative(ca, Ra, cb, Rb, eps):  # pragma: no cover (compiled)
    """Box B seen from box A: B's axes in A's frame (Rm), their absolute values plus
    ``eps`` (Am, the slack that keeps near-parallel edges from separating by rounding) and
    the centre offset in A's frame (t)."""
    Rm = np.empty((3, 3))
    Am = np.empty((3, 3))
    t = np.empty(3)
    for i in range(3):
        for j in range(3):
            Rm[i, j] = Ra[0, i] * Rb[0, j] + Ra[1, i] * Rb[1, j] + Ra[2, i] * Rb[2, j]
            Am[i, j] = abs(Rm[i, j]) + eps
    d0, d1, d2 = cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]
    for i in range(3):
        t[i] = d0 * Ra[0, i] + d1 * Ra[1, i] + d2 * Ra[2, i]
    return Rm, Am, t


@njit(cache=True)
def _box_box(ca, Ra, ha, cb, Rb, hb):  # pragma: no cover (compiled)
    """Separating-axis test of two boxes (Ericson, Real-Time Collision Detection 4.4.1):
    True unless one of the 15 axes separates them."""
    Rm, Am, t = _relative(ca, Ra, cb, Rb, 1e-9)
    for i in range(3):
        if abs(t[i]) > ha[i] + hb[0] * Am[i, 0] + hb[1] * Am[i, 1] + hb[2] * Am[i, 2]:
            return False
    for j in range(3):
        if abs(t[0] * Rm[0, j] + t[1] * Rm[1, j] + t[2] * Rm[2, j]) > (
                ha[0] * Am[0, j] + ha[1] * Am[1, j] + ha[2] * Am[2, j] + hb[j]):
            return False
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            ra = ha[i1] * Am[i2, j] + ha[i2] * Am[i1, j]
            rb = hb[j1] * Am[i, j2] + hb[j2] * Am[i, j1]
            if abs(t[i2] * Rm[i1, j] - t[i1] * Rm[i2, j]) > ra + rb:
                return False
    return True


@njit(cache=True)
def _box_overlap(ca, Ra, ha, cb, Rb, hb):  # pragma: no cover (compiled)
    """How deep two boxes interpenetrate: the least overlap of their projections on the 15
    separating axes (unit length; edge axes of nearly parallel edges, which the face axes
    stand in for, are left out).  Negative when an axis separates them."""
    Rm, Am, t = _relative(ca, Ra, cb, Rb, 0.0)
    least = np.inf
    for i in range(3):
        least = min(least, ha[i] + hb[0] * Am[i, 0] + hb[1] * Am[i, 1] + hb[2] * Am[i, 2]
                    - abs(t[i]))
    for j in range(3):
        least = min(least, ha[0] * Am[0, j] + ha[1] * Am[1, j] + ha[2] * Am[2, j] + hb[j]
                    - abs(t[0] * Rm[0, j] + t[1] * Rm[1, j] + t[2] * Rm[2, j]))
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            norm = math.sqrt(max(0.0, 1.0 - Rm[i, j] * Rm[i, j]))  # |a_i × b_j|
            if norm < 1e-6:
                continue
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            ra = ha[i1] * Am[i2, j] + ha[i2] * Am[i1, j]
            rb = hb[j1] * Am[i, j2] + hb[j2] * Am[i, j1]
            least = min(least, (ra + rb - abs(t[i2] * Rm[i1, j] - t[i1] * Rm[i2, j])) / norm)
    return least


@njit(cache=True)
def box_hit(frames, n, rbox_frame, rbox_T, rbox_solid, box_c, box_R, box_h, box_r,
            depth):  # pragma: no cover (compiled)
    """Does one of the robot's boxes (their true half extents ``rbox_solid``) reach at
    least ``depth`` into one of the world's boxes at configuration n?  True is a proof of
    collision: box against box is exact geometry, for pybullet too."""
    Rw = np.empty((3, 3))
    cw = np.empty(3)
    for b in range(rbox_T.shape[0]):
        _place(frames[n, rbox_frame[b]], rbox_T[b], Rw, cw)
        rb = math.sqrt(rbox_solid[b, 0] ** 2 + rbox_solid[b, 1] ** 2 + rbox_solid[b, 2] ** 2)
        for m in range(box_c.shape[0]):
            dx, dy, dz = cw[0] - box_c[m, 0], cw[1] - box_c[m, 1], cw[2] - box_c[m, 2]
            reach = rb + box_r[m]
            if dx * dx + dy * dy + dz * dz >= reach * reach:
                continue
            if _box_overlap(cw, Rw, rbox_solid[b], box_c[m], box_R[m], box_h[m]) >= depth:
                return True
    return False


@njit(cache=True)
def sphere_hit(frames, n, in_frame, in_c, in_r, box_c, box_R, box_h, box_r,
               depth):  # pragma: no cover (compiled)
    """Does one of the robot's inner spheres (each inside its link's collision hull) reach
    at least ``depth`` into one of the world's boxes at configuration n?  True is a proof
    of collision: the hull holding the sphere reaches at least as deep."""
    p = np.empty(3)
    for s in range(in_c.shape[0]):
        _apply(frames[n, in_frame[s]], in_c[s], p)
        reach = in_r[s] - depth
        for m in range(box_c.shape[0]):
            dx, dy, dz = p[0] - box_c[m, 0], p[1] - box_c[m, 1], p[2] - box_c[m, 2]
            far = reach + box_r[m]
            if dx * dx + dy * dy + dz * dz >= far * far:
                continue
            if _sphere_box(p, reach, box_c[m], box_R[m], box_h[m]):
                return True
    return False


@njit(cache=True)
def inner_hit_rbox(frames, n, in_frame, in_c, in_r, in_rbox, rbox_frame, rbox_T, rbox_solid,
                   depth):  # pragma: no cover (compiled)
    """Does an inner sphere s reach at least ``depth`` into a robot box b it is tested
    against (``in_rbox[s, b]``; the box's true half extents ``rbox_solid``) at
    configuration n?  True is a proof of collision, as for :func:`sphere_hit`."""
    p = np.empty(3)
    Rw = np.empty((3, 3))
    cw = np.empty(3)
    for b in range(rbox_T.shape[0]):
        _place(frames[n, rbox_frame[b]], rbox_T[b], Rw, cw)
        rb = math.sqrt(rbox_solid[b, 0] ** 2 + rbox_solid[b, 1] ** 2 + rbox_solid[b, 2] ** 2)
        for s in range(in_c.shape[0]):
            reach = in_r[s] - depth
            if not in_rbox[s, b] or reach <= 0.0:
                continue
            _apply(frames[n, in_frame[s]], in_c[s], p)
            dx, dy, dz = p[0] - cw[0], p[1] - cw[1], p[2] - cw[2]
            far = reach + rb
            if dx * dx + dy * dy + dz * dz >= far * far:
                continue
            if _sphere_box(p, reach, cw, Rw, rbox_solid[b]):
                return True
    return False


@njit(cache=True)
def _support_hull(F, hull, lo, hi, d, out):  # pragma: no cover (compiled)
    """The vertex of hull[lo:hi] (points in frame F, 3 × 4) furthest along the world
    direction d, in world coordinates (``out``)."""
    l0 = F[0, 0] * d[0] + F[1, 0] * d[1] + F[2, 0] * d[2]
    l1 = F[0, 1] * d[0] + F[1, 1] * d[1] + F[2, 1] * d[2]
    l2 = F[0, 2] * d[0] + F[1, 2] * d[1] + F[2, 2] * d[2]
    best, arg = -np.inf, lo
    for v in range(lo, hi):
        s = hull[v, 0] * l0 + hull[v, 1] * l1 + hull[v, 2] * l2
        if s > best:
            best, arg = s, v
    _apply(F, hull[arg], out)


@njit(cache=True)
def _support_box(c, R, h, d, out):  # pragma: no cover (compiled)
    """The corner of the box (centre c, rotation R, half extents h) furthest along d."""
    out[0], out[1], out[2] = c[0], c[1], c[2]
    for j in range(3):
        e = h[j] if R[0, j] * d[0] + R[1, j] * d[1] + R[2, j] * d[2] >= 0.0 else -h[j]
        for i in range(3):
            out[i] += e * R[i, j]


@njit(cache=True)
def _nearest_on_simplex(W, k, v, lam):  # pragma: no cover (compiled)
    """The point of the convex hull of W[:k] (k <= 4 points) nearest the origin, into v;
    lam[:k] its barycentric coordinates (zero for points it does not need).  Every subset
    whose affine hull's nearest point lies inside it is tried; the nearest such point is
    the answer (the nearest point of the hull lies inside one of its faces)."""
    best = np.inf
    Q = np.empty((3, 3))
    A = np.empty((3, 3))
    rhs = np.empty(3)
    mu = np.empty(3)
    p = np.empty(3)
    idx = np.empty(4, dtype=np.int64)
    for mask in range(1, 1 << k):
        m = 0
        for i in range(k):
            if mask & (1 << i):
                idx[m] = i
                m += 1
        o = idx[0]
        for a in range(m - 1):
            for c in range(3):
                Q[a, c] = W[idx[a + 1], c] - W[o, c]
        # normal equations (Q Q^T) mu = -Q p0, solved by Gaussian elimination
        ok = True
        for a in range(m - 1):
            for b in range(m - 1):
                A[a, b] = Q[a, 0] * Q[b, 0] + Q[a, 1] * Q[b, 1] + Q[a, 2] * Q[b, 2]
            rhs[a] = -(Q[a, 0] * W[o, 0] + Q[a, 1] * W[o, 1] + Q[a, 2] * W[o, 2])
        for a in range(m - 1):
            piv = a
            for b in range(a + 1, m - 1):
                if abs(A[b, a]) > abs(A[piv, a]):
                    piv = b
            if abs(A[piv, a]) < 1e-18:
                ok = False
                break
            if piv != a:
                for c in range(m - 1):
                    A[a, c], A[piv, c] = A[piv, c], A[a, c]
                rhs[a], rhs[piv] = rhs[piv], rhs[a]
            for b in range(a + 1, m - 1):
                f = A[b, a] / A[a, a]
                for c in range(a, m - 1):
                    A[b, c] -= f * A[a, c]
                rhs[b] -= f * rhs[a]
        if not ok:
            continue
        for a in range(m - 2, -1, -1):
            t = rhs[a]
            for c in range(a + 1, m - 1):
                t -= A[a, c] * mu[c]
            mu[a] = t / A[a, a]
        first = 1.0
        inside = True
        for a in range(m - 1):
            first -= mu[a]
            if mu[a] < 0.0:
                inside = False
        if first < 0.0 or not inside:
            continue
        for c in range(3):
            p[c] = W[o, c]
            for a in range(m - 1):
                p[c] += mu[a] * Q[a, c]
        d = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
        if d < best:
            best = d
            v[0], v[1], v[2] = p[0], p[1], p[2]
            for i in range(k):
                lam[i] = 0.0
            lam[o] = first
            for a in range(m - 1):
                lam[idx[a + 1]] = mu[a]
    return best < np.inf


@njit(cache=True)
def _apart(Fa, hull, alo, ahi, Fb, hull_b, blo, bhi, c, R, h, gap):  # pragma: no cover
    """Are two convex sets certainly at least ``gap`` apart?  A is the hull of
    hull[alo:ahi] in frame Fa; B is the hull of hull_b[blo:bhi] in frame Fb, or, when
    blo == bhi, the box (c, R, h).  (Compiled.)

    GJK (Gilbert, Johnson, Keerthi) looks for the point v of A - B nearest the origin;
    the answer is True only when every point of A - B projects at least ``gap`` onto v
    (the support points of both sets along v, compared directly), so True is a proof
    whatever the iteration did.  False means "not shown"."""
    boxed = blo == bhi
    a = np.empty(3)
    b = np.empty(3)
    v = np.empty(3)
    d = np.empty(3)
    W = np.empty((4, 3))
    lam = np.empty(4)
    # start from the difference of the points of A and B furthest towards each other
    for i in range(3):
        d[i] = (c[i] if boxed else Fb[i, 3]) - Fa[i, 3]
    _support_hull(Fa, hull, alo, ahi, d, a)
    for i in range(3):
        d[i] = -d[i]
    if boxed:
        _support_box(c, R, h, d, b)
    else:
        _support_hull(Fb, hull_b, blo, bhi, d, b)
    for i in range(3):
        v[i] = a[i] - b[i]
    k = 0
    for _ in range(32):
        vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
        if vv < gap * gap:  # v is a point of A - B: the sets are closer than gap
            return False
        for i in range(3):
            d[i] = -v[i]
        _support_hull(Fa, hull, alo, ahi, d, a)
        if boxed:
            _support_box(c, R, h, v, b)
        else:
            _support_hull(Fb, hull_b, blo, bhi, v, b)
        # w = a - b is the point of A - B with the least projection onto v
        vw = v[0] * (a[0] - b[0]) + v[1] * (a[1] - b[1]) + v[2] * (a[2] - b[2])
        if vw >= gap * math.sqrt(vv):
            return True
        if vv - vw <= 1e-12 * vv or k == 4:  # converged (or degenerate): not shown
            return False
        for i in range(3):
            W[k, i] = a[i] - b[i]
        k += 1
        if not _nearest_on_simplex(W, k, v, lam):
            return False
        m = 0  # keep the points the nearest point needs
        for i in range(k):
            if lam[i] > 0.0:
                W[m, 0], W[m, 1], W[m, 2] = W[i, 0], W[i, 1], W[i, 2]
                m += 1
        k = m
    return False


@njit(cache=True)
def _face_gap(ca, Ra, ha, cb, Rb, hb):  # pragma: no cover (compiled)
    """How far apart two boxes are along the best of their six face normals (negative
    when none separates them).  pybullet's box-box contacts test these axes exactly."""
    Rm, Am, t = _relative(ca, Ra, cb, Rb, 0.0)
    best = -np.inf
    for i in range(3):
        best = max(best, abs(t[i]) - (ha[i] + hb[0] * Am[i, 0] + hb[1] * Am[i, 1]
                                      + hb[2] * Am[i, 2]))
    for j in range(3):
        best = max(best, abs(t[0] * Rm[0, j] + t[1] * Rm[1, j] + t[2] * Rm[2, j])
                   - (ha[0] * Am[0, j] + ha[1] * Am[1, j] + ha[2] * Am[2, j] + hb[j]))
    return best


@njit(cache=True)
def _chain(q, base, origins, out):  # pragma: no cover (compiled)
    """:func:`arm_frames` of one configuration q (7,) into out (8, 3, 4)."""
    for i in range(3):  # element by element: a whole-slice copy compiles a shape check
        for j in range(4):  # whose error message alone costs seconds of numba's time
            out[0, i, j] = base[i, j]
    for k in range(7):
        c, s = math.cos(q[k]), math.sin(q[k])
        o = origins[k]
        for i in range(3):
            p0, p1, p2 = out[k, i, 0], out[k, i, 1], out[k, i, 2]
            a0 = p0 * o[0, 0] + p1 * o[1, 0] + p2 * o[2, 0]
            a1 = p0 * o[0, 1] + p1 * o[1, 1] + p2 * o[2, 1]
            a2 = p0 * o[0, 2] + p1 * o[1, 2] + p2 * o[2, 2]
            out[k + 1, i, 3] = p0 * o[0, 3] + p1 * o[1, 3] + p2 * o[2, 3] + out[k, i, 3]
            out[k + 1, i, 0] = c * a0 + s * a1
            out[k + 1, i, 1] = c * a1 - s * a0
            out[k + 1, i, 2] = a2


@njit(cache=True)
def _check_order(k, m):  # pragma: no cover (compiled)
    """The first m of :func:`pipeline.planning.base.check_order` (k)."""
    order = np.empty(m, dtype=np.int64)
    seen = np.zeros(k, dtype=np.bool_)
    order[0] = k - 1
    seen[k - 1] = True
    n = 1
    step = k
    while n < m:
        step = max(1, step // 2)
        for i in range(step - 1, k, step):
            if not seen[i]:
                seen[i] = True
                order[n] = i
                n += 1
                if n == m:
                    break
    return order


@njit(cache=True)
def _proved(kind, fr, in_frame, in_c, in_r, in_rbox, rbox_frame, rbox_T, rbox_solid, box_c,
            box_R, box_h, box_r, depth, og_c, og_r, og_ilo, og_ihi, oin_c,
            oin_r):  # pragma: no cover (compiled)
    """Does the robot at frames ``fr`` certainly collide: an inner sphere or a robot box
    at least ``depth`` deep in a world box, an inner sphere that deep in a robot box it
    is tested against, or in an inner sphere of another robot (:func:`sphere_hit`,
    :func:`box_hit`, :func:`inner_hit_rbox`, :func:`inner_hit_spheres`)?"""
    if kind == 2:
        return False
    f4 = fr.reshape((1, fr.shape[0], 3, 4))
    first = np.int64(0)  # not the literal 0: that would compile the kernels below once more
    if in_rbox.size and inner_hit_rbox(f4, first, in_frame, in_c, in_r, in_rbox, rbox_frame,
                                       rbox_T, rbox_solid, depth):
        return True
    # the robot's few boxes first: the many inner spheres cost more to place and test
    if box_c.shape[0] > 0 and (
            (rbox_solid.shape[0] > 0 and box_hit(f4, first, rbox_frame, rbox_T, rbox_solid,
                                                 box_c, box_R, box_h, box_r, depth))
            or (in_r.shape[0] > 0 and sphere_hit(f4, first, in_frame, in_c, in_r, box_c, box_R,
                                                 box_h, box_r, depth))):
        return True
    return oin_r.shape[0] > 0 and inner_hit_spheres(f4, first, in_frame, in_c, in_r, og_c, og_r,
                                                   og_ilo, og_ihi, oin_c, oin_r, depth)


@njit(cache=True)
def inner_hit_spheres(frames, n, in_frame, in_c, in_r, og_c, og_r, og_ilo, og_ihi, oin_c,
                      oin_r, depth):  # pragma: no cover (compiled)
    """Does one of the robot's inner spheres overlap one of another robot's inner spheres
    (world coordinates ``oin_c``, ``oin_r``; those of group o: og_ilo[o]:og_ihi[o], held
    by the group's bounding sphere (og_c[o], og_r[o])) by at least ``depth`` at
    configuration n?  True is a proof of collision: the two link hulls that hold the
    spheres overlap at least as deep."""
    p = np.empty(3)
    for s in range(in_c.shape[0]):
        _apply(frames[n, in_frame[s]], in_c[s], p)
        for o in range(og_c.shape[0]):
            dx, dy, dz = p[0] - og_c[o, 0], p[1] - og_c[o, 1], p[2] - og_c[o, 2]
            far = in_r[s] + og_r[o]
            if dx * dx + dy * dy + dz * dz >= far * far:
                continue
            for u in range(og_ilo[o], og_ihi[o]):
                dx, dy, dz = p[0] - oin_c[u, 0], p[1] - oin_c[u, 1], p[2] - oin_c[u, 2]
                reach = in_r[s] + oin_r[u] - depth
                if reach > 0.0 and dx * dx + dy * dy + dz * dz < reach * reach:
                    return True
    return False


# each takes its row of the layout's meta (an array, so numba compiles one specialization,
# not one per literal index: 38 of them cost seconds of a cold start; inlining them instead
# made the scan 15 % slower)
@njit(cache=True)
def _f1(fb, row):  # pragma: no cover (compiled)
    o = row[0]
    return fb[o:o + row[1]]


@njit(cache=True)
def _f2(fb, row):  # pragma: no cover (compiled)
    o, n0, n1 = row[0], row[1], row[2]
    return fb[o:o + n0 * n1].reshape((n0, n1))


@njit(cache=True)
def _f3(fb, row):  # pragma: no cover (compiled)
    o, n0, n1, n2 = row[0], row[1], row[2], row[3]
    return fb[o:o + n0 * n1 * n2].reshape((n0, n1, n2))


#: the robot's and the world's arrays :func:`_scan` reads, in the order :func:`pack` lays
#: them out: name, kind ("f" float64, "i" int64; booleans as 0 or 1), dimensions
ROBOT_PACK = (
    ("grp_frame", "i", 1), ("grp_c", "f", 2), ("grp_r", "f", 1), ("grp_lo", "i", 1),
    ("grp_hi", "i", 1), ("grp_world", "i", 1), ("sph_c", "f", 2), ("sph_r", "f", 1),
    ("pair_a", "i", 1), ("pair_b", "i", 1), ("rbox_frame", "i", 1), ("rbox_T", "f", 3),
    ("rbox_h", "f", 2), ("rbox_r", "f", 1), ("rbox_pair_b", "i", 1), ("rbox_pair_g", "i", 1),
    ("rbox_solid", "f", 2), ("hull", "f", 2), ("grp_hlo", "i", 1), ("grp_hhi", "i", 1),
    ("root_c", "f", 1), ("grp_reach", "f", 1), ("rbox_reach", "f", 1), ("gaps", "f", 1),
    ("in_frame", "i", 1), ("in_c", "f", 2), ("in_r", "f", 1), ("in_rbox", "i", 2))
WORLD_PACK = (
    ("box_c", "f", 2), ("box_R", "f", 3), ("box_h", "f", 2), ("box_r", "f", 1),
    ("box_e", "f", 2), ("og_c", "f", 2), ("og_r", "f", 1), ("og_lo", "i", 1),
    ("og_hi", "i", 1), ("obs_c", "f", 2), ("obs_r", "f", 1), ("og_hlo", "i", 1),
    ("og_hhi", "i", 1), ("og_hull", "f", 2), ("og_ilo", "i", 1), ("og_ihi", "i", 1),
    ("oin_c", "f", 2), ("oin_r", "f", 1), ("og_all", "f", 1))


def pack(values: dict, layout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The arrays ``values[name]`` of ``layout`` (``ROBOT_PACK``, ``WORLD_PACK``) in two
    buffers (float64, int64) and where each lies (offset and shape): three arguments for
    the compiled scan, whose call costs about 70 ns per array argument."""
    floats, ints, meta = [], [], np.zeros((len(layout), 4), dtype=np.int64)
    size = {"f": 0, "i": 0}
    for k, (name, kind, ndim) in enumerate(layout):
        a = np.asarray(values[name], dtype=np.float64 if kind == "f" else np.int64)
        if a.ndim != ndim:
            raise ValueError(f"pack: {name} has {a.ndim} dimensions, not {ndim}")
        meta[k, 0] = size[kind]
        meta[k, 1:1 + ndim] = a.shape
        (floats if kind == "f" else ints).append(a.ravel())
        size[kind] += a.size
    return (np.ascontiguousarray(np.concatenate(floats) if floats else np.zeros(0)),
            np.ascontiguousarray(np.concatenate(ints) if ints else np.zeros(0, np.int64)),
            meta)


def near_memo(robot_sizes: tuple[int, int], boxes: int) -> tuple[np.ndarray, np.ndarray]:
    """An empty memo of the boxes near a robot of (groups, robot boxes) ``robot_sizes`` in
    a world of ``boxes`` boxes, for :func:`edge_first` (``memo``): the root frame they
    were found for (3 × 4, NaN: none yet) and the lists themselves."""
    groups, rboxes = robot_sizes
    return (np.full(12, np.nan),
            np.zeros(1 + boxes + groups + groups * boxes + rboxes + rboxes * boxes, np.int64))


@njit(cache=True)
def _memo_views(memo_i, G, R, B):  # pragma: no cover (compiled)
    """(count of near boxes (1,), near, gcount, gnear, bcount, bnear) inside ``memo_i``."""
    o = 1 + B
    gnear = memo_i[o + G:o + G + G * B].reshape((G, B))
    o2 = o + G + G * B
    return (memo_i[0:1], memo_i[1:o], memo_i[o:o + G], gnear, memo_i[o2:o2 + R],
            memo_i[o2 + R:o2 + R + R * B].reshape((R, B)))


@njit(cache=True)
def _meets(x, y, z, r, c, rc):  # pragma: no cover (compiled)
    """Does the sphere (x, y, z; r) reach into the sphere (c[:3]; rc)?"""
    dx, dy, dz = x - c[0], y - c[1], z - c[2]
    reach = r + rc
    return dx * dx + dy * dy + dz * dz < reach * reach


@njit(cache=True)
def _touch(ac, ar, alo, ahi, bc, br, blo, bhi, grow):  # pragma: no cover (compiled)
    """Does one of the spheres (ac, ar)[alo:ahi] touch one of (bc, br)[blo:bhi], with
    ``grow`` added to each pair's sum of radii?"""
    for s in range(alo, ahi):
        for u in range(blo, bhi):
            dx, dy, dz = ac[s, 0] - bc[u, 0], ac[s, 1] - bc[u, 1], ac[s, 2] - bc[u, 2]
            reach = ar[s] + br[u] + grow
            if dx * dx + dy * dy + dz * dz < reach * reach:
                return True
    return False


@njit(cache=True)
def _wrist_apart(fr, wrist_pairs, grp_frame, grp_c, grp_r, grp_lo, grp_hi, sph_c, sph_r, hull,
                 grp_hlo, grp_hhi, sw, c, R, gap):  # pragma: no cover (compiled)
    """Is every pair of groups in ``wrist_pairs`` (P, 2) at frames ``fr`` certainly apart,
    by the test the scan makes of its other link pairs: no sphere of one touches a sphere
    of the other, or their hulls are at least ``gap`` apart (:func:`_apart`)?  ``sw``:
    the scan's scratch for sphere centres; ``c``, ``R``: scratch."""
    for k in range(wrist_pairs.shape[0]):
        a, b = wrist_pairs[k, 0], wrist_pairs[k, 1]
        Fa, Fb = fr[grp_frame[a]], fr[grp_frame[b]]
        for s in range(grp_lo[a], grp_hi[a]):
            _apply(Fa, sph_c[s], sw[s])
        for s in range(grp_lo[b], grp_hi[b]):
            _apply(Fb, sph_c[s], sw[s])
        if _touch(sw, sph_r, grp_lo[a], grp_hi[a], sw, sph_r, grp_lo[b], grp_hi[b],
                  0.0) and not (
                grp_hlo[a] < grp_hhi[a] and grp_hlo[b] < grp_hhi[b] and _apart(
                Fa, hull, grp_hlo[a], grp_hhi[a], Fb, hull, grp_hlo[b], grp_hhi[b], c, R, c,
                gap)):
            return False
    return True


@njit(cache=True)
def _planar_candidates(qa, qb, root_c, root_r, box_c, box_e):  # pragma: no cover (compiled)
    """The boxes that the root sphere (``root_c`` in the base frame, radius ``root_r``) of
    a base moving in a straight line from (x, y) = qa[:2] to qb[:2] can reach: the others
    are at least ``root_r`` from every place of the sphere's centre (it stays within
    |root_c| of the floor point (x, y, 0)), so the per-row test would leave them out."""
    out = np.empty(box_c.shape[0], dtype=np.int64)
    n = 0
    lift = math.sqrt(root_c[0] ** 2 + root_c[1] ** 2 + root_c[2] ** 2) + 1e-9
    lo = np.empty(3)
    hi = np.empty(3)
    for i in range(2):
        lo[i] = min(qa[i], qb[i]) - lift
        hi[i] = max(qa[i], qb[i]) + lift
    lo[2], hi[2] = -lift, lift
    for m in range(box_c.shape[0]):
        acc = 0.0
        for i in range(3):
            gap = max(box_c[m, i] - box_e[m, i] - hi[i], lo[i] - box_c[m, i] - box_e[m, i])
            if gap > 0.0:
                acc += gap * gap
        if root_r == np.inf or acc < (root_r + 1e-9) ** 2:
            out[n] = m
            n += 1
    return out[:n]


#: rows of an arm's motion that the scan tries to clear with one test (:func:`_segment_clear`;
#: 4 and 16 were slower on pick_place's motions, docs/results.md)
SEGMENT = 8


@njit(cache=True)
def _levers(origins, frame, centre, extra, out):  # pragma: no cover (compiled)
    """out[k]: how far a point within ``extra`` of ``centre`` (in frame ``frame`` of
    :func:`_chain`) can be from joint k's pivot (the origin of frame k + 1) in any
    configuration: the lengths of the chain's offsets between them plus the point's
    distance from its frame's origin; 0 for the joints that do not move the frame.  Turning
    joint k by at most dq[k] moves the point by at most sum(out * dq)."""
    reach = math.sqrt(centre[0] ** 2 + centre[1] ** 2 + centre[2] ** 2) + extra
    for k in range(out.shape[0] - 1, -1, -1):
        if k + 1 > frame:
            out[k] = 0.0
            continue
        out[k] = reach
        reach += math.sqrt(origins[k, 0, 3] ** 2 + origins[k, 1, 3] ** 2 + origins[k, 2, 3] ** 2)


@njit(cache=True)
def _segment_motion(j, segment, steps, qa, diff, base, origins, grp_frame, rbox_frame, lever_g,
                    lever_b, q, dq, fm, dg, db):  # pragma: no cover (compiled)
    """The frames ``fm`` of the middle of rows j·segment … (j + 1)·segment - 1 of the arm
    motion qa + (row + 1) / steps · diff, how far each joint turns from there within
    those rows (dq), and how far that moves each group's points (dg) and each robot box's
    (db), a little more than the bound for rounding."""
    i0 = j * segment
    i1 = min(i0 + segment, steps) - 1
    middle, half = (i0 + i1 + 2) / (2.0 * steps), (i1 - i0) / (2.0 * steps)
    for i in range(qa.shape[0]):
        q[i] = qa[i] + middle * diff[i]
        dq[i] = abs(diff[i]) * half
    _chain(q, base, origins, fm)
    for g in range(lever_g.shape[0]):
        dg[g] = _moved(lever_g[g], dq, 0, grp_frame[g])
    for b in range(lever_b.shape[0]):
        db[b] = _moved(lever_b[b], dq, 0, rbox_frame[b])


@njit(cache=True)
def _moved(lever, dq, lo, hi):  # pragma: no cover (compiled)
    """How far turning joints lo … hi - 1 by dq moves a point of ``lever`` (:func:`_levers`),
    plus 1e-9 m: the row test's rounding is far below that."""
    out = 1e-9
    for k in range(lo, hi):
        out += lever[k] * dq[k]
    return out


@njit(cache=True)
def _segment_clear(fm, dg, db, lever_g, lever_b, dq, grp_frame, grp_c, grp_r, grp_lo, grp_hi,
                   grp_world, sph_c, sph_r, pair_a, pair_b, rbox_frame, rbox_T, rbox_h, rbox_r,
                   rbox_pair_b, rbox_pair_g, box_c, box_R, box_h, box_e, gnear, gcount, bnear,
                   bcount, og_c, og_r, og_lo, og_hi, obs_c, obs_r, og_all, gw, sw, Rw, cw,
                   hb):  # pragma: no cover (compiled)
    """Does the scan's row test clear every configuration within the bounds of
    :func:`_segment_motion` (frames ``fm`` at the middle; each group's points within dg[g]
    of where they are there, each robot box's within db[b])?  The row test's sphere and
    box tests with each radius and half extent grown by those bounds (for two parts of
    the robot, by how far the joints between their frames move one against the other):
    where none of them touches, nothing touches in any of those configurations, and the
    row test clears each of them.  False: the rows are tested one by one (so is a
    segment that only the hulls would clear)."""
    G = grp_c.shape[0]
    for g in range(G):
        _apply(fm[grp_frame[g]], grp_c[g], gw[g])
    for g in range(G):
        if not grp_world[g]:
            continue
        F = fm[grp_frame[g]]
        x, y, z, rg = gw[g, 0], gw[g, 1], gw[g, 2], grp_r[g] + dg[g]
        placed = False
        for k in range(gcount[g]):
            m = gnear[g, k]
            if _off_aabb(x, y, z, rg, box_c[m], box_e[m]) or not _sphere_box(
                    gw[g], rg, box_c[m], box_R[m], box_h[m]):
                continue
            if not placed:
                for s in range(grp_lo[g], grp_hi[g]):
                    _apply(F, sph_c[s], sw[s])
                placed = True
            for s in range(grp_lo[g], grp_hi[g]):
                if _sphere_box(sw[s], sph_r[s] + dg[g], box_c[m], box_R[m], box_h[m]):
                    return False
        for o in range(og_c.shape[0] if _meets(x, y, z, rg, og_all, og_all[3]) else 0):
            if not _meets(x, y, z, rg, og_c[o], og_r[o]):
                continue
            if not placed:
                for s in range(grp_lo[g], grp_hi[g]):
                    _apply(F, sph_c[s], sw[s])
                placed = True
            if _touch(sw, sph_r, grp_lo[g], grp_hi[g], obs_c, obs_r, og_lo[o], og_hi[o],
                      dg[g]):
                return False
    for k in range(pair_a.shape[0]):
        a, b = pair_a[k], pair_b[k]
        if grp_frame[a] > grp_frame[b]:
            a, b = b, a
        grow = _moved(lever_g[b], dq, grp_frame[a], grp_frame[b])
        if not _meets(gw[a, 0], gw[a, 1], gw[a, 2], grp_r[a] + grow, gw[b], grp_r[b]):
            continue
        for s in range(grp_lo[a], grp_hi[a]):
            _apply(fm[grp_frame[a]], sph_c[s], sw[s])
        for s in range(grp_lo[b], grp_hi[b]):
            _apply(fm[grp_frame[b]], sph_c[s], sw[s])
        if _touch(sw, sph_r, grp_lo[a], grp_hi[a], sw, sph_r, grp_lo[b], grp_hi[b], grow):
            return False
    for b in range(rbox_T.shape[0]):
        _place(fm[rbox_frame[b]], rbox_T[b], Rw, cw)
        rb = rbox_r[b] + db[b]
        for i in range(3):
            hb[i] = rbox_h[b, i] + db[b]  # holds the box wherever its points go
        for k in range(bcount[b]):
            m = bnear[b, k]
            if _off_aabb(cw[0], cw[1], cw[2], rb, box_c[m], box_e[m]) or not _sphere_box(
                    cw, rb, box_c[m], box_R[m], box_h[m]):
                continue
            if _box_box(cw, Rw, hb, box_c[m], box_R[m], box_h[m]):
                return False
        for u in range(obs_c.shape[0]):
            if _sphere_box(obs_c[u], obs_r[u] + db[b], cw, Rw, rbox_h[b]):
                return False
        for k in range(rbox_pair_b.shape[0]):
            if rbox_pair_b[k] != b:
                continue
            g = rbox_pair_g[k]
            fb, fg = rbox_frame[b], grp_frame[g]
            grow = (_moved(lever_b[b], dq, fg, fb) if fb > fg
                    else _moved(lever_g[g], dq, fb, fg))
            if not _meets(cw[0], cw[1], cw[2], rbox_r[b] + grow, gw[g], grp_r[g]):
                continue
            for s in range(grp_lo[g], grp_hi[g]):
                _apply(fm[grp_frame[g]], sph_c[s], sw[s])
                if _sphere_box(sw[s], sph_r[s] + grow, cw, Rw, rbox_h[b]):
                    return False
    return True


@njit(cache=True)
def _scan(kind, frames, pre, qa, qb, resolution, limit, start, segment, psi_scale, wrist_step,
          wrist_state, base, origins, wrist_lower, wrist_pairs, rf, ri, rm, wf, wi, wm,
          root_frame, root_r, depth, memo_f, memo_i):  # pragma: no cover (compiled)
    """The scan of :func:`first_uncertain` (``kind`` 2: the configurations' ``frames``
    and ``pre`` are given) and of :func:`edge_first` (``kind`` 0: an arm, 1: a base; the
    configurations are made on the way).  Returns (steps, position, proved): proved when
    the configuration at ``position`` certainly collides (:func:`_proved`; never asked for
    ``kind`` 2).  ``rf``, ``ri``, ``rm``: the robot's arrays (``ROBOT_PACK``, :func:`pack`);
    ``wf``, ``wi``, ``wm``: the world's (``WORLD_PACK``).  ``wrist_pairs``: (P, 2) the
    groups of an arm's wrist pairs, or none: a configuration whose wrist cell may hold a
    contact is cleared all the same where those pairs are apart (:func:`_wrist_apart`).
    ``segment``: an arm's rows (wrist cell known free) are cleared ``segment`` at a time
    where :func:`_segment_clear` can (0: row by row)."""
    grp_frame, grp_c, grp_r = _f1(ri, rm[0]), _f2(rf, rm[1]), _f1(rf, rm[2])
    grp_lo, grp_hi, grp_world = _f1(ri, rm[3]), _f1(ri, rm[4]), _f1(ri, rm[5])
    sph_c, sph_r, pair_a, pair_b = _f2(rf, rm[6]), _f1(rf, rm[7]), _f1(ri, rm[8]), _f1(ri, rm[9])
    rbox_frame, rbox_T, rbox_h = _f1(ri, rm[10]), _f3(rf, rm[11]), _f2(rf, rm[12])
    rbox_r, rbox_pair_b, rbox_pair_g = _f1(rf, rm[13]), _f1(ri, rm[14]), _f1(ri, rm[15])
    rbox_solid, hull = _f2(rf, rm[16]), _f2(rf, rm[17])
    grp_hlo, grp_hhi, root_c = _f1(ri, rm[18]), _f1(ri, rm[19]), _f1(rf, rm[20])
    grp_reach, rbox_reach, gaps = _f1(rf, rm[21]), _f1(rf, rm[22]), _f1(rf, rm[23])
    in_frame, in_c, in_r, in_rbox = _f1(ri, rm[24]), _f2(rf, rm[25]), _f1(rf, rm[26]), _f2(
        ri, rm[27])
    box_c, box_R, box_h, box_r = _f2(wf, wm[0]), _f3(wf, wm[1]), _f2(wf, wm[2]), _f1(wf, wm[3])
    box_e, og_c, og_r = _f2(wf, wm[4]), _f2(wf, wm[5]), _f1(wf, wm[6])
    og_lo, og_hi, obs_c, obs_r = _f1(wi, wm[7]), _f1(wi, wm[8]), _f2(wf, wm[9]), _f1(wf, wm[10])
    og_hlo, og_hhi, og_hull = _f1(wi, wm[11]), _f1(wi, wm[12]), _f2(wf, wm[13])
    og_ilo, og_ihi, oin_c, oin_r = _f1(wi, wm[14]), _f1(wi, wm[15]), _f2(wf, wm[16]), _f1(
        wf, wm[17])
    og_all = _f1(wf, wm[18])  # a sphere (centre, radius) holding every group's sphere
    G, S, B = grp_c.shape[0], sph_c.shape[0], box_c.shape[0]
    nil = np.int64(0)  # not the literal 0, which numba would compile _apart for once more
    proof = (in_frame, in_c, in_r, in_rbox, rbox_frame, rbox_T, rbox_solid, box_c, box_R, box_h,
             box_r, depth, og_c, og_r, og_ilo, og_ihi, oin_c, oin_r)
    gw, sw = np.empty((G, 3)), np.empty((S, 3))
    world_frame = np.zeros((3, 4))  # of og_hull's vertices (world coordinates)
    for i in range(3):
        world_frame[i, i] = 1.0
    done = np.zeros(G, dtype=np.bool_)
    R = rbox_T.shape[0]
    # the boxes each group (and each robot box) can reach while the root frame stands
    # still (an arm on a fixed base: found once, then kept in the memo for the next calls
    # with the same root frame); a rigid robot (one frame, moving every configuration)
    # looks at every box near the root
    if memo_i.shape[0] != 1 + B + G + G * B + R + R * B:  # no memo: a fresh one
        memo_f = np.full(12, np.nan)
        memo_i = np.zeros(1 + B + G + G * B + R + R * B, dtype=np.int64)
    nbv, near, gcount, gnear, bcount, bnear = _memo_views(memo_i, G, R, B)
    last = memo_f.reshape((3, 4))
    rw, Rw, cw = np.empty(3), np.empty((3, 3)), np.empty(3)
    nb = nbv[0]
    cand = np.arange(B)
    d = qa.shape[0]
    diff = np.empty(d)
    q = np.empty(d)
    if kind == 2:
        steps = frames.shape[0]
        rows = steps
        order = np.empty(0, dtype=np.int64)
        buf = np.empty((0, 3, 4))
    else:
        top = 0.0
        for i in range(d):
            diff[i] = qb[i] - qa[i]
            top = max(top, abs(diff[i]))
        steps = max(1, math.ceil(top / resolution))
        rows = min(steps, limit)
        order = _check_order(steps, rows)
        buf = np.empty((8 if kind == 0 else 1, 3, 4))
        if kind == 1:
            cand = _planar_candidates(qa, qb, root_c, root_r, box_c, box_e)
    articulated = (frames.shape[1] if kind == 2 else buf.shape[0]) > 1
    ni, nk = wrist_state.shape[0], wrist_state.shape[1]
    # an arm's segments: 0 not tried yet, 1 cleared, 2 tested row by row (after the
    # call's first row: an edge that collides mostly shows it there)
    nseg = (steps + segment - 1) // segment if kind == 0 and 0 < segment < rows else 0
    seg = np.zeros(nseg, dtype=np.int8)
    used = 1 if nseg else 0  # scratch of full size only where segments are tried
    lever_g, lever_b = np.empty((G * used, d)), np.empty((R * used, d))
    fm = np.empty((8 * used, 3, 4))
    dq, dg, db, hb = np.empty(d * used), np.empty(G * used), np.empty(R * used), np.empty(3 * used)
    levers = False  # lever_g, lever_b computed
    for pos in range(start, rows):
        if kind == 2:
            fr = frames[pos]
            if pre[pos] and not (wrist_pairs.shape[0] > 0 and _wrist_apart(
                    fr, wrist_pairs, grp_frame, grp_c, grp_r, grp_lo, grp_hi, sph_c, sph_r, hull,
                    grp_hlo, grp_hhi, sw, rw, Rw, gaps[2])):
                return steps, pos, False
        else:
            fr = buf
            t = (order[pos] + 1) / steps
            for i in range(d):
                q[i] = qa[i] + t * diff[i]
            if kind == 0:
                i5 = min(max(int(math.floor((q[5] - wrist_lower[0]) / wrist_step + 0.5)), 0),
                         ni - 1)
                i6 = min(max(int(math.floor((q[6] - wrist_lower[1]) / wrist_step + 0.5)), 0),
                         nk - 1)
                cell = wrist_state[i5, i6]
                if cell == 0:
                    return steps, -1 - pos, False
                if cell == 1 and nseg and pos > start:
                    j = order[pos] // segment
                    if seg[j] == 0:
                        if not levers:
                            levers = True
                            for g in range(G):
                                _levers(origins, grp_frame[g], grp_c[g], grp_r[g], lever_g[g])
                            for b in range(R):
                                _levers(origins, rbox_frame[b], rbox_T[b, :, 3], rbox_r[b],
                                        lever_b[b])
                        _segment_motion(j, segment, steps, qa, diff, base, origins, grp_frame,
                                        rbox_frame, lever_g, lever_b, q, dq, fm, dg, db)
                        seg[j] = 1 if _segment_clear(
                            fm, dg, db, lever_g, lever_b, dq, grp_frame, grp_c, grp_r, grp_lo,
                            grp_hi, grp_world, sph_c, sph_r, pair_a, pair_b, rbox_frame, rbox_T,
                            rbox_h, rbox_r, rbox_pair_b, rbox_pair_g, box_c, box_R, box_h,
                            box_e, gnear, gcount, bnear, bcount, og_c, og_r, og_lo, og_hi,
                            obs_c, obs_r, og_all, gw, sw, Rw, cw, hb) else 2
                        for i in range(d):  # the row's own configuration again
                            q[i] = qa[i] + t * diff[i]
                    if seg[j] == 1:
                        continue
                _chain(q, base, origins, fr)
                if cell != 1 and not (cell == 2 and wrist_pairs.shape[0] > 0 and _wrist_apart(
                        fr, wrist_pairs, grp_frame, grp_c, grp_r, grp_lo, grp_hi, sph_c, sph_r,
                        hull, grp_hlo, grp_hhi, sw, rw, Rw, gaps[2])):
                    return steps, pos, _proved(kind, fr, *proof)
            else:
                psi = q[2] / psi_scale
                c, s_ = math.cos(psi), math.sin(psi)
                fr[0] = 0.0
                fr[0, 0, 0], fr[0, 0, 1], fr[0, 0, 3] = c, -s_, q[0]
                fr[0, 1, 0], fr[0, 1, 1], fr[0, 1, 3] = s_, c, q[1]
                fr[0, 2, 2] = 1.0
        F0 = fr[root_frame]
        moved = False
        for i in range(3):
            for j in range(4):
                if F0[i, j] != last[i, j]:
                    moved = True
        if moved:  # an arm on a fixed base: once per motion
            for i in range(3):  # element by element, as in _chain
                for j in range(4):
                    last[i, j] = F0[i, j]
            _apply(F0, root_c, rw)
            nb = 0
            for m in cand:
                if root_r == np.inf or (
                        not _off_aabb(rw[0], rw[1], rw[2], root_r, box_c[m], box_e[m])
                        and _sphere_box(rw, root_r, box_c[m], box_R[m], box_h[m])):
                    near[nb] = m
                    nb += 1
            for g in range(G + R if articulated else 0):
                r = grp_reach[g] if g < G else rbox_reach[g - G]
                c = 0
                for k in range(nb):
                    m = near[k]
                    if articulated and r < root_r and not _sphere_box(
                            rw, r, box_c[m], box_R[m], box_h[m]):
                        continue
                    if g < G:
                        gnear[g, c] = m
                    else:
                        bnear[g - G, c] = m
                    c += 1
                if g < G:
                    gcount[g] = c
                else:
                    bcount[g - G] = c
            nbv[0] = nb
        for g in range(G):
            _apply(fr[grp_frame[g]], grp_c[g], gw[g])
            done[g] = False
        for g in range(G):
            if not grp_world[g]:
                continue
            F = fr[grp_frame[g]]
            x, y, z, rg = gw[g, 0], gw[g, 1], gw[g, 2], grp_r[g]
            lst, cnt = (gnear[g], gcount[g]) if articulated else (near, nb)
            for k in range(cnt):
                m = lst[k]
                if _off_aabb(x, y, z, rg, box_c[m], box_e[m]):
                    continue
                if not _sphere_box(gw[g], rg, box_c[m], box_R[m], box_h[m]):
                    continue
                if not done[g]:
                    for s in range(grp_lo[g], grp_hi[g]):
                        _apply(F, sph_c[s], sw[s])
                    done[g] = True
                for s in range(grp_lo[g], grp_hi[g]):
                    if _sphere_box(sw[s], sph_r[s], box_c[m], box_R[m], box_h[m]):
                        if grp_hlo[g] < grp_hhi[g] and _apart(
                                F, hull, grp_hlo[g], grp_hhi[g], F, hull, nil, nil, box_c[m],
                                box_R[m], box_h[m], gaps[0]):
                            break
                        return steps, pos, _proved(kind, fr, *proof)
            for o in range(og_c.shape[0] if _meets(x, y, z, rg, og_all, og_all[3]) else 0):
                if not _meets(x, y, z, rg, og_c[o], og_r[o]):
                    continue
                if not done[g]:
                    for s in range(grp_lo[g], grp_hi[g]):
                        _apply(F, sph_c[s], sw[s])
                    done[g] = True
                touch = _touch(sw, sph_r, grp_lo[g], grp_hi[g], obs_c, obs_r, og_lo[o],
                               og_hi[o], 0.0)
                if touch and not (grp_hlo[g] < grp_hhi[g] and og_hlo[o] < og_hhi[o] and _apart(
                        F, hull, grp_hlo[g], grp_hhi[g], world_frame, og_hull, og_hlo[o],
                        og_hhi[o], cw, Rw, cw, gaps[2])):
                    return steps, pos, _proved(kind, fr, *proof)
        for k in range(pair_a.shape[0]):
            a, b = pair_a[k], pair_b[k]
            dx, dy, dz = gw[a, 0] - gw[b, 0], gw[a, 1] - gw[b, 1], gw[a, 2] - gw[b, 2]
            reach = grp_r[a] + grp_r[b]
            if dx * dx + dy * dy + dz * dz >= reach * reach:
                continue
            Fa, Fb = fr[grp_frame[a]], fr[grp_frame[b]]
            if not done[a]:
                for s in range(grp_lo[a], grp_hi[a]):
                    _apply(Fa, sph_c[s], sw[s])
                done[a] = True
            if not done[b]:
                for s in range(grp_lo[b], grp_hi[b]):
                    _apply(Fb, sph_c[s], sw[s])
                done[b] = True
            touch = False
            bx, by, bz, br = gw[b, 0], gw[b, 1], gw[b, 2], grp_r[b]
            for s in range(grp_lo[a], grp_hi[a]):
                x, y, z, rs = sw[s, 0], sw[s, 1], sw[s, 2], sph_r[s]
                dx, dy, dz = x - bx, y - by, z - bz
                reach = rs + br
                if dx * dx + dy * dy + dz * dz >= reach * reach:  # misses all of b
                    continue
                for u in range(grp_lo[b], grp_hi[b]):
                    dx, dy, dz = x - sw[u, 0], y - sw[u, 1], z - sw[u, 2]
                    reach = rs + sph_r[u]
                    if dx * dx + dy * dy + dz * dz < reach * reach:
                        touch = True
                        break
                if touch:
                    break
            if touch and not (grp_hlo[a] < grp_hhi[a] and grp_hlo[b] < grp_hhi[b] and _apart(
                    Fa, hull, grp_hlo[a], grp_hhi[a], Fb, hull, grp_hlo[b], grp_hhi[b], cw, Rw,
                    cw, gaps[2])):
                return steps, pos, _proved(kind, fr, *proof)
        for b in range(rbox_T.shape[0]):
            _place(fr[rbox_frame[b]], rbox_T[b], Rw, cw)
            lst, cnt = (bnear[b], bcount[b]) if articulated else (near, nb)
            for k in range(cnt):
                m = lst[k]
                if _off_aabb(cw[0], cw[1], cw[2], rbox_r[b], box_c[m], box_e[m]):
                    continue
                if not _sphere_box(cw, rbox_r[b], box_c[m], box_R[m], box_h[m]):
                    continue  # the box's circumsphere misses: so does the box
                if _box_box(cw, Rw, rbox_h[b], box_c[m], box_R[m], box_h[m]) and _face_gap(
                        cw, Rw, rbox_solid[b], box_c[m], box_R[m], box_h[m]) < gaps[3]:
                    return steps, pos, _proved(kind, fr, *proof)
            for u in range(obs_c.shape[0]):
                if _sphere_box(obs_c[u], obs_r[u], cw, Rw, rbox_h[b]):
                    return steps, pos, _proved(kind, fr, *proof)
            for k in range(rbox_pair_b.shape[0]):
                if rbox_pair_b[k] != b:
                    continue
                g = rbox_pair_g[k]
                dx, dy, dz = cw[0] - gw[g, 0], cw[1] - gw[g, 1], cw[2] - gw[g, 2]
                reach = rbox_r[b] + grp_r[g]
                if dx * dx + dy * dy + dz * dz >= reach * reach:
                    continue
                F = fr[grp_frame[g]]
                if not done[g]:
                    for s in range(grp_lo[g], grp_hi[g]):
                        _apply(F, sph_c[s], sw[s])
                    done[g] = True
                for s in range(grp_lo[g], grp_hi[g]):
                    if _sphere_box(sw[s], sph_r[s], cw, Rw, rbox_h[b]):
                        if grp_hlo[g] < grp_hhi[g] and _apart(
                                F, hull, grp_hlo[g], grp_hhi[g], F, hull, nil, nil, cw, Rw,
                                rbox_solid[b], gaps[1]):
                            break
                        return steps, pos, _proved(kind, fr, *proof)
    return steps, rows, False


_NO_STATE = np.empty(0)
_NO_PRE = np.zeros(0, dtype=np.bool_)
_NO_FRAMES = np.empty((0, 1, 3, 4))
_NO_CELLS = np.ones((1, 1), dtype=np.int8)
#: an edge scan's arm chain where there is none: base frame, joint origins, wrist grid
#: origin, wrist pairs
NO_CHAIN = (np.zeros((3, 4)), np.zeros((7, 3, 4)), np.zeros(2), np.zeros((0, 2), np.int64))
_NO_MEMO = np.zeros(0, dtype=np.int64)


def first_uncertain(frames, start, pre, packed, wrist_pairs=None) -> int:
    """The first configuration n >= ``start`` (its frames: frames[n], F × 3 × 4) that may
    collide, or N when none may; ``pre[n]`` marks configurations already in doubt (with
    ``wrist_pairs``, an arm's wrist pairs as :func:`_scan` takes them: in doubt for the
    wrist table only, and cleared where those pairs are apart).
    ``packed``: the robot's arrays (``ROBOT_PACK``) and the world's (``WORLD_PACK``) as
    :func:`pack` lays them out, then the root frame and radius and the proof depth.

    Groups with ``grp_world`` are tested against the world's boxes and sphere groups
    (og_*: bounding sphere and range of obs_c / obs_r); the group pairs (pair_a[k],
    pair_b[k]) against each other; the robot boxes against the world, and robot box
    rbox_pair_b[k] against group rbox_pair_g[k].  Spheres of group g are
    sph_c[grp_lo[g]:grp_hi[g]] in the group's frame.

    Where spheres touch, the geometry they cover decides: group g's convex hull
    (hull[grp_hlo[g]:grp_hhi[g]] in its frame; none when the range is empty) at least
    gaps[0] from a world box, gaps[1] from a robot box (true half extents
    ``rbox_solid``), gaps[2] from another group's hull; a robot box at least gaps[3] from a
    world box along a face normal.  The sphere (root_c in frame root_frame, radius root_r)
    holds the whole robot; spheres with its centre and radii grp_reach, rbox_reach hold
    each group and robot box: boxes they miss are not looked at.
    """
    pairs = NO_CHAIN[3] if wrist_pairs is None else wrist_pairs
    return _scan(2, frames, pre, _NO_STATE, _NO_STATE, 1.0, 0, start, 0, 1.0, 1.0, _NO_CELLS,
                 *NO_CHAIN[:3], pairs, *packed, _NO_STATE, _NO_MEMO)[1]


def edge_first(a, b, resolution, limit, start, kind, psi_scale, wrist_step, wrist_state,
               chain, packed, memo=None, segment=SEGMENT) -> tuple[int, int, bool]:
    """:func:`first_uncertain` over the straight motion a→b as
    :meth:`pipeline.planning.base.Robot.check_motion` checks it, without making its
    states first: the states of :func:`pipeline.planning.base.interpolate` (``steps`` of
    them) in the order of :func:`pipeline.planning.base.check_order`, the first
    ``min(steps, limit)`` of them, from position ``start``.  Returns (steps, the first
    position >= start that may collide, or min(steps, limit) when none may, whether it
    certainly collides: an inner sphere or robot box deep in a world box, or an inner
    sphere deep in a robot box it is tested against).  ``kind`` 0: an arm (``chain``:
    (base frame, joint origins, wrist grid origin, wrist pairs as :func:`_scan` takes
    them): the chain of :func:`arm_frames` on the
    base frame, and the wrist table ``wrist_state`` on a grid of ``wrist_step`` from the
    wrist grid origin: a cell not known free is a doubt; a cell not
    known at all ends the scan with position -1 - k, for the caller to fill it); 1: a base
    (:func:`planar_frames`).  ``memo``: None, or a :func:`near_memo` for this robot and
    world, kept by the caller from call to call (an arm's base stands still over a
    planning call: the boxes near it are found once).  ``segment``: an arm's rows are
    cleared that many at a time where they can be (0: one by one; the same answer)."""
    memo_f, memo_i = (_NO_STATE, _NO_MEMO) if memo is None else memo
    return _scan(kind, _NO_FRAMES, _NO_PRE, a, b, resolution, limit, start, segment,
                 psi_scale, wrist_step, wrist_state, *chain, *packed, memo_f, memo_i)


@njit(cache=True)
def wrist_cells(q, lower, step, state, pre):  # pragma: no cover (compiled)
    """pre[n] = the (q5, q6) grid cell of configuration n is not known free; returns how
    many of those cells are not known at all (state 0: unknown, 1: free, 2: maybe in
    contact)."""
    unknown = 0
    for n in range(q.shape[0]):
        i = min(max(int(math.floor((q[n, 5] - lower[0]) / step + 0.5)), 0), state.shape[0] - 1)
        k = min(max(int(math.floor((q[n, 6] - lower[1]) / step + 0.5)), 0), state.shape[1] - 1)
        pre[n] = state[i, k] != 1
        unknown += state[i, k] == 0
    return unknown
