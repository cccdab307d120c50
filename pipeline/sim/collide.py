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
        out[n, 0] = base
        for k in range(7):
            c, s = math.cos(q[n, k]), math.sin(q[n, k])
            for i in range(3):
                p0, p1, p2 = out[n, k, i, 0], out[n, k, i, 1], out[n, k, i, 2]
                o = origins[k]
                a0 = p0 * o[0, 0] + p1 * o[1, 0] + p2 * o[2, 0]
                a1 = p0 * o[0, 1] + p1 * o[1, 1] + p2 * o[2, 1]
                a2 = p0 * o[0, 2] + p1 * o[1, 2] + p2 * o[2, 2]
                out[n, k + 1, i, 3] = p0 * o[0, 3] + p1 * o[1, 3] + p2 * o[2, 3] + out[n, k, i, 3]
                out[n, k + 1, i, 0] = c * a0 + s * a1
                out[n, k + 1, i, 1] = c * a1 - s * a0
                out[n, k + 1, i, 2] = a2


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
def first_uncertain(frames, start, pre, grp_frame, grp_c, grp_r, grp_lo, grp_hi, grp_world,
                    sph_c, sph_r, pair_a, pair_b, rbox_frame, rbox_T, rbox_h, rbox_r,
                    rbox_pair_b, rbox_pair_g, box_c, box_R, box_h, box_r, og_c, og_r, og_lo,
                    og_hi, obs_c, obs_r):  # pragma: no cover (compiled)
    """The first configuration n >= ``start`` (its frames: frames[n], F × 3 × 4) that may
    collide, or N when none may; ``pre[n]`` marks configurations already in doubt.

    Groups with ``grp_world`` are tested against the world's boxes and sphere groups
    (og_*: bounding sphere and range of obs_c / obs_r); the group pairs (pair_a[k],
    pair_b[k]) against each other; the robot boxes against the world, and robot box
    rbox_pair_b[k] against group rbox_pair_g[k].  Spheres of group g are
    sph_c[grp_lo[g]:grp_hi[g]] in the group's frame.
    """
    G = grp_c.shape[0]
    S = sph_c.shape[0]
    gw = np.empty((G, 3))
    sw = np.empty((S, 3))
    Rw = np.empty((3, 3))
    cw = np.empty(3)
    for n in range(start, frames.shape[0]):
        if pre[n]:
            return n
        for g in range(G):
            F = frames[n, grp_frame[g]]
            _apply(F, grp_c[g], gw[g])
            for s in range(grp_lo[g], grp_hi[g]):
                _apply(F, sph_c[s], sw[s])
        for g in range(G):
            if not grp_world[g]:
                continue
            x, y, z, rg = gw[g, 0], gw[g, 1], gw[g, 2], grp_r[g]
            for m in range(box_c.shape[0]):
                dx, dy, dz = x - box_c[m, 0], y - box_c[m, 1], z - box_c[m, 2]
                reach = rg + box_r[m]
                if dx * dx + dy * dy + dz * dz >= reach * reach:
                    continue
                if not _sphere_box(gw[g], rg, box_c[m], box_R[m], box_h[m]):
                    continue
                for s in range(grp_lo[g], grp_hi[g]):
                    if _sphere_box(sw[s], sph_r[s], box_c[m], box_R[m], box_h[m]):
                        return n
            for o in range(og_c.shape[0]):
                dx, dy, dz = x - og_c[o, 0], y - og_c[o, 1], z - og_c[o, 2]
                reach = rg + og_r[o]
                if dx * dx + dy * dy + dz * dz >= reach * reach:
                    continue
                for s in range(grp_lo[g], grp_hi[g]):
                    for u in range(og_lo[o], og_hi[o]):
                        dx = sw[s, 0] - obs_c[u, 0]
                        dy = sw[s, 1] - obs_c[u, 1]
                        dz = sw[s, 2] - obs_c[u, 2]
                        reach = sph_r[s] + obs_r[u]
                        if dx * dx + dy * dy + dz * dz < reach * reach:
                            return n
        for k in range(pair_a.shape[0]):
            a, b = pair_a[k], pair_b[k]
            dx, dy, dz = gw[a, 0] - gw[b, 0], gw[a, 1] - gw[b, 1], gw[a, 2] - gw[b, 2]
            reach = grp_r[a] + grp_r[b]
            if dx * dx + dy * dy + dz * dz >= reach * reach:
                continue
            for s in range(grp_lo[a], grp_hi[a]):
                for u in range(grp_lo[b], grp_hi[b]):
                    dx, dy, dz = sw[s, 0] - sw[u, 0], sw[s, 1] - sw[u, 1], sw[s, 2] - sw[u, 2]
                    reach = sph_r[s] + sph_r[u]
                    if dx * dx + dy * dy + dz * dz < reach * reach:
                        return n
        for b in range(rbox_T.shape[0]):
            _place(frames[n, rbox_frame[b]], rbox_T[b], Rw, cw)
            for m in range(box_c.shape[0]):
                dx, dy, dz = cw[0] - box_c[m, 0], cw[1] - box_c[m, 1], cw[2] - box_c[m, 2]
                reach = rbox_r[b] + box_r[m]
                if dx * dx + dy * dy + dz * dz >= reach * reach:
                    continue
                if _box_box(cw, Rw, rbox_h[b], box_c[m], box_R[m], box_h[m]):
                    return n
            for u in range(obs_c.shape[0]):
                if _sphere_box(obs_c[u], obs_r[u], cw, Rw, rbox_h[b]):
                    return n
            for k in range(rbox_pair_b.shape[0]):
                if rbox_pair_b[k] != b:
                    continue
                g = rbox_pair_g[k]
                dx, dy, dz = cw[0] - gw[g, 0], cw[1] - gw[g, 1], cw[2] - gw[g, 2]
                reach = rbox_r[b] + grp_r[g]
                if dx * dx + dy * dy + dz * dz >= reach * reach:
                    continue
                for s in range(grp_lo[g], grp_hi[g]):
                    if _sphere_box(sw[s], sph_r[s], cw, Rw, rbox_h[b]):
                        return n
    return frames.shape[0]


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
