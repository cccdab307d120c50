"""Trajectory optimisation in the manner of TrajOpt (Schulman et al., 2014): sequential convex
optimisation of a joint-space trajectory with an exact (hinge) collision penalty.

The trajectory has ``waypoints`` configurations from the start to the goal (both fixed);
the interior ones are the variables.  Each iteration linearises the signed distance of every
close (link, obstacle) pair at every interior waypoint,

    d(q) ~ d(q0) + g^T (q - q0),   g = n^T J(q0)   (contact normal times the link's
                                                     positional Jacobian at the point)

and solves the convex subproblem

    minimise   sum_t |x_{t+1} - x_t|^2  +  mu * sum_c s_c
    subject to s_c >= margin - d_c - g_c^T (x_t(c) - x0_t(c)),  s_c >= 0,
               joint limits, |x - x0|_inf <= trust radius

plus a proximal term (a QP; solved through its dual, a bound-constrained quadratic in the
hinge multipliers, with scipy's L-BFGS-B).  A step is kept when the true merit (cost plus mu times
the true hinge) improves by at least a quarter of what the model predicted; then the trust
region grows, otherwise it shrinks.  When a penalty round converges with the trajectory
still closer than the margin somewhere, mu is multiplied by ``penalty_scale``.

Initialisation is the straight line in joint space, as in TrajOpt; nothing is random, so the
result is a function of the inputs alone.  The waypoints are only checked at the waypoints
(no swept volumes): the caller re-checks the result densely before calling it feasible.

Cost (issue 27, item 3).  With ``planner.collision=spheres`` (the default) the robot model's
faster distances and checks are used where it offers them (its ``bounded_distances`` and
``certified`` capabilities: for the Panda, pybullet asked only about bodies a sphere bound
cannot rule out, and a sphere pre-check for the dense re-check); the dual
is solved by scipy's L-BFGS-B (:func:`box_lbfgsb`), and the operators of the cost are made
once per size.  None of this changes a bit of a result: ``collision=exact`` and the code
before give the same statuses, checks and paths (tests/test_trajopt.py,
benchmarks/bench_trajopt.py).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from pipeline.planning import lbfgsb
from pipeline.planning.base import DistanceModel, certified, fast_distance_model, recheck
from pipeline.planning.blas import single_thread
from pipeline.planning.interface import Planner
from pipeline.planning.result import PlanResult, Status, path_length
from pipeline.planning.settings import TrajOptSettings

#: Initial weight of the proximal term rho/2 |z - z0|^2 that, with the per-joint step limit,
#: keeps each step where the linearisation holds (halved after a good step, x4 after a bad).
PROXIMAL = 1.0

#: Distances this far inside the margin (metres) still count as clear.
SLACK = 1e-6


@dataclass(frozen=True)
class TrajOptOptions:
    """The optimiser's options; those a user sets default to the ``trajopt_*`` keys of
    :class:`~pipeline.planning.settings.TrajOptSettings` (declared there only)."""

    waypoints: int = TrajOptSettings.trajopt_waypoints
    margin: float = TrajOptSettings.trajopt_margin  # safety margin on signed distance, m
    penalty: float = TrajOptSettings.trajopt_penalty  # initial hinge coefficient mu
    penalty_scale: float = 10.0
    penalty_rounds: int = TrajOptSettings.trajopt_penalty_rounds
    iterations: int = TrajOptSettings.trajopt_iterations  # SQP iterations, over all rounds
    trust_radius: float = TrajOptSettings.trajopt_trust_radius  # radians per joint
    min_trust: float = 1e-3
    tolerance: float = 1e-4  # stop a round when the model predicts less improvement


@dataclass
class TrajOptResult:
    trajectory: np.ndarray  # (waypoints, dof)
    converged: bool  # no pair closer than the margin at any waypoint
    min_distance: float
    iterations: int
    distance_queries: int  # configurations whose distances were computed
    time: float


def straight_line(start: np.ndarray, goal: np.ndarray, count: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, count)[:, None]
    return start + t * (goal - start)


class _Problem:
    """The trajectory's variables, cost and linearised constraints."""

    def __init__(self, start, goal, lower, upper, opts: TrajOptOptions, contacts: DistanceModel):
        self.start, self.goal = np.asarray(start, float), np.asarray(goal, float)
        self.dof = self.start.size
        self.inner = opts.waypoints - 2
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.opts = opts
        self._contacts = contacts
        self.queries = 0
        # cost = |D z - e|^2 with D the finite-difference operator on the interior waypoints
        # (D, 2 D^T and H = 2 D^T D depend on the sizes alone: made once per size)
        n, k = self.inner, self.dof
        self.D, self._2Dt, self.H = _operators(n, k)
        offset = np.zeros((n + 1) * k)
        offset[:k] = self.start
        offset[-k:] = -self.goal
        self.e = offset
        self._2Dte = self._2Dt @ offset  # the linear term of the cost, 2 D^T e
        self._lo = np.tile(self.lower, self.inner)
        self._hi = np.tile(self.upper, self.inner)
        self._factors: dict[float, tuple] = {}  # rho -> Cholesky factor of H + rho I

    def cost(self, z) -> float:
        r = self.D @ z - self.e
        return float(r @ r)

    def linearise(self, z):
        """Distances (K,) of the close pairs at every interior waypoint and at the middle of
        every segment, and their gradients with respect to z (K, n).  A midpoint's
        gradient is shared half and half by the segment's two waypoints (a fixed end takes
        none): a cheap stand-in for TrajOpt's swept-volume distances that keeps segments
        from cutting through thin obstacles between waypoints."""
        k, n = self.dof, self.inner * self.dof
        x = np.vstack([self.start, z.reshape(self.inner, k), self.goal])
        ds, gs = [], []
        points = [(x[t], ((t - 1, 1.0),)) for t in range(1, self.inner + 1)]
        points += [(0.5 * (x[t] + x[t + 1]), ((t - 1, 0.5), (t, 0.5)))
                   for t in range(self.inner + 1)]
        many = getattr(self._contacts, "many", None)
        if many is not None:  # all configurations at once (fast_distance.BoundedDistances)
            answers = many(np.array([q for q, _ in points]))
        else:
            answers = (self._contacts(q) for q, _ in points)
        for (_, weights), (dist, grad) in zip(points, answers, strict=True):
            self.queries += 1
            if not len(dist):
                continue
            grad = np.asarray(grad, float).reshape(len(dist), k)
            G = np.zeros((len(dist), n))
            for t, w in weights:
                if 0 <= t < self.inner:
                    G[:, t * k:(t + 1) * k] = w * grad
            ds.append(np.asarray(dist, float))
            gs.append(G)
        if not ds:
            return np.zeros(0), np.zeros((0, n))
        return np.concatenate(ds), np.vstack(gs)

    def hinge(self, d) -> float:
        return float(np.maximum(0.0, self.opts.margin - d).sum())

    def clear(self, d) -> bool:
        """No pair closer than the margin (up to SLACK: the dual solve is not exact)."""
        return bool((d >= self.opts.margin - SLACK).all())

    def model(self, z, z0, d, G, mu, rho) -> float:
        """The convex model at ``z``: cost, proximal term and the linearised hinge."""
        lin = d + G @ (z - z0)
        return self.cost(z) + 0.5 * rho * float((z - z0) @ (z - z0)) + mu * self.hinge(lin)

    def subproblem(self, z0, d, G, mu, rho, radius):
        """Minimise the convex model around ``z0`` (its step limited to ``radius`` per
        joint and to the joint limits); return the minimiser and the model's value there.

        The model is |Dz - e|^2 + rho/2 |z - z0|^2 + mu sum_c max(0, h_c - G_c z): a
        strictly convex quadratic plus hinges.  Its dual is a quadratic in the hinges'
        multipliers, each bounded to [0, mu], which L-BFGS-B solves exactly for the few
        dozen active pairs; then z = P^-1 (q + G^T lambda).
        """
        factor = self._factors.get(rho)
        if factor is None:
            n = self.inner * self.dof
            factor = self._factors[rho] = cho_factor(self.H + rho * np.eye(n))
        q = self._2Dte + rho * z0
        z = cho_solve(factor, q)
        if len(d):
            h = self.opts.margin - d + G @ z0
            PiG = cho_solve(factor, G.T)  # (n, K)
            Q = G @ PiG
            c_lin = G @ z - h

            def dual(lam):
                Ql = Q @ lam
                return 0.5 * float(lam @ Ql) + float(c_lin @ lam), Ql + c_lin

            lam0 = np.where(c_lin < 0, mu, 0.0)
            z = z + PiG @ box_lbfgsb(dual, lam0, mu)
        lo = np.maximum(self._lo, z0 - radius)
        hi = np.minimum(self._hi, z0 + radius)
        z = np.clip(z, lo, hi)
        return z, self.model(z, z0, d, G, mu, rho)


#: L-BFGS-B's settings for the dual (scipy.optimize.minimize's options)
LBFGSB = {"maxiter": 500, "ftol": 1e-14, "gtol": 1e-10}


def box_lbfgsb(fun, x0: np.ndarray, upper: float) -> np.ndarray:
    """The minimiser of ``fun`` (``x -> (value, gradient)``) over the box [0, upper]^n from
    ``x0`` by scipy's L-BFGS-B with :data:`LBFGSB` (driven directly,
    :mod:`pipeline.planning.lbfgsb`: ``minimize``'s answer, bit for bit)."""
    return lbfgsb.box_lbfgsb(fun, x0, upper, **LBFGSB)


@functools.lru_cache(maxsize=8)
def _operators(n: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(D, 2 D^T, H = 2 D^T D) for ``n`` interior waypoints of ``k`` joints (read-only)."""
    diff = np.zeros(((n + 1) * k, n * k))
    for t in range(n + 1):
        if t < n:
            diff[t * k:(t + 1) * k, t * k:(t + 1) * k] = np.eye(k)
        if t > 0:
            diff[t * k:(t + 1) * k, (t - 1) * k:t * k] -= np.eye(k)
    out = diff, 2 * diff.T, 2 * diff.T @ diff
    for a in out:
        a.flags.writeable = False
    return out


def optimise(start, goal, lower, upper, contacts: DistanceModel,
             opts: TrajOptOptions | None = None, deadline: float | None = None) -> TrajOptResult:
    """Optimise a trajectory from ``start`` to ``goal`` (see the module docstring), with
    one BLAS thread, so that the result is the same in every process of a machine
    (``pipeline/planning/blas.py``)."""
    opts = opts or TrajOptOptions()
    if opts.waypoints < 3:
        raise ValueError(f"trajopt needs at least 3 waypoints, got {opts.waypoints}")
    with single_thread():
        return _optimise(start, goal, lower, upper, contacts, opts, deadline)


def _optimise(start, goal, lower, upper, contacts, opts, deadline) -> TrajOptResult:
    t0 = time.perf_counter()
    p = _Problem(start, goal, lower, upper, opts, contacts)
    z = straight_line(p.start, p.goal, opts.waypoints)[1:-1].reshape(-1)
    mu, radius, iterations = opts.penalty, opts.trust_radius, 0
    rho = PROXIMAL
    d, G = p.linearise(z)
    for _ in range(opts.penalty_rounds):
        while iterations < opts.iterations and radius >= opts.min_trust:
            if deadline is not None and time.perf_counter() > deadline:
                break
            merit = p.cost(z) + mu * p.hinge(d)
            if p.clear(d):
                break
            iterations += 1
            z_new, model = p.subproblem(z, d, G, mu, rho, radius)
            predicted = merit - model
            if predicted < opts.tolerance:
                break
            d_new, G_new = p.linearise(z_new)
            actual = merit - (p.cost(z_new) + mu * p.hinge(d_new))
            if actual >= 0.25 * predicted:
                z, d, G = z_new, d_new, G_new
                radius, rho = min(radius * 1.5, 1.0), rho * 0.5
            else:
                radius, rho = radius * 0.5, rho * 4.0
        if p.clear(d):
            break
        mu *= opts.penalty_scale
        radius = max(radius, opts.trust_radius)
    trajectory = np.vstack([p.start, z.reshape(p.inner, p.dof), p.goal])
    return TrajOptResult(trajectory=trajectory, converged=p.clear(d),
                         min_distance=float(d.min()) if d.size else np.inf,
                         iterations=iterations, distance_queries=p.queries,
                         time=time.perf_counter() - t0)


#: How far beyond the margin pairs are linearised: obstacles slightly outside the margin
#: enter the model before a step can jump past them.
QUERY_BUFFER = 0.03


def options(settings: TrajOptSettings) -> TrajOptOptions:
    """TrajOpt's options from the ``trajopt_*`` planner settings (checked by
    TrajOptSettings)."""
    s = settings
    return TrajOptOptions(waypoints=s.trajopt_waypoints, margin=s.trajopt_margin,
                          penalty=s.trajopt_penalty, penalty_rounds=s.trajopt_penalty_rounds,
                          iterations=s.trajopt_iterations, trust_radius=s.trajopt_trust_radius)


class TrajOpt(Planner):
    """π's motion-planning step by trajectory optimisation, for robots with signed
    distances (``distance_model``).

    Feasible only when the optimised trajectory passes the robot's dense re-check (every
    edge at ``settings.resolution``, the same checks RRT-Connect's edges get); score =
    -(joint-space length).  Its ``checks`` count distance queries and re-checked states;
    it has no check budget (a shared ``budget`` is left untouched).
    """

    name = "trajopt"
    settings_class = TrajOptSettings
    requires = frozenset({"distances"})

    def __init__(self, settings=None):
        super().__init__(settings)
        self.options = options(self.settings)

    def plan(self, robot, start, goal, seed: int = 0, budget=None) -> PlanResult:
        opts = self.options
        checker, contacts = self.models(robot, opts.margin + QUERY_BUFFER)
        deadline = time.perf_counter() + self.settings.wall_cap_s
        res = optimise(start, goal, robot.lower, robot.upper, contacts, opts,
                       deadline=deadline)
        checks = res.distance_queries
        if time.perf_counter() > deadline:
            return PlanResult(Status.TIMEOUT, checks=checks)
        path = res.trajectory
        ok, used = recheck(checker, path, self.settings.resolution)
        checks += used
        if not ok:  # the margin is TrajOpt's target; the dense re-check decides feasibility
            status = Status.PATH_IN_COLLISION if res.converged else Status.NOT_CONVERGED
            return PlanResult(status, checks=checks)
        return PlanResult(Status.OK, path=path, length=path_length(path), checks=checks)

    def models(self, robot, query: float):
        """(the robot model that re-checks the result, the distance model), made once the
        scene is set for the call and before its wall-clock cap starts.  With
        ``planner.collision=spheres`` (the default) they are the robot model's faster
        ones where it offers them (its ``certified`` and ``bounded_distances``
        capabilities: for the Panda, the sphere pre-check and pybullet asked for distances
        only to bodies that may be within ``query``); both give the answers of
        ``collision=exact`` (pybullet everywhere), bit for bit, so the setting changes
        only the cost."""
        if getattr(self.settings, "collision", "exact") != "spheres":
            return robot, robot.distance_model(query)
        return certified(robot), fast_distance_model(robot, query)
