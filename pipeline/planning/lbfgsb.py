"""scipy's L-BFGS-B over a box [0, upper]^n, driven without ``scipy.optimize.minimize``.

TrajOpt solves several hundred small duals per grasp_arm block, each in about a hundred
evaluations of a cheap quadratic.  ``minimize`` wraps every evaluation in layers of
Python (its scalar-function object, the memoised gradient, copies and comparisons of
``x``) that cost more than the evaluation and the L-BFGS-B step together (about half of
TrajOpt's time in grasp_arm, docs/results.md).  :func:`box_lbfgsb` runs the loop that
``minimize(method="L-BFGS-B")`` runs, around the same compiled routine
(``scipy.optimize._lbfgsb.setulb``) with the same arguments, so its iterates and its
answer are those of ``minimize``, bit for bit.

That routine is private to scipy and its signature has changed between releases (scipy
1.15 replaced the Fortran code with C), so the direct loop is used only on scipy 1.15 or
later, and only after a probe problem, solved both ways on first use, gave the same bits;
otherwise every call goes to ``minimize``.  tests/test_lbfgsb.py compares the two on many
problems.
"""

from __future__ import annotations

import numpy as np
import scipy
from scipy.optimize import minimize

try:
    from scipy.optimize._lbfgsb import setulb as _setulb
except ImportError:  # pragma: no cover (a scipy without it: minimize serves every call)
    _setulb = None

#: minimize's defaults for L-BFGS-B that the loop needs (maxcor, maxls, maxfun)
MAXCOR, MAXLS, MAXFUN = 10, 20, 15000

#: the first scipy whose routine takes the arguments the loop passes (the C version)
FIRST_SCIPY = (1, 15)

#: whether the direct loop reproduces ``minimize`` here: None until the probe has run
_direct_ok: bool | None = None


def box_lbfgsb(fun, x0: np.ndarray, upper: float, maxiter: int, ftol: float,
               gtol: float) -> np.ndarray:
    """The minimiser of ``fun`` (``x -> (value, gradient)``) over [0, upper]^n from ``x0``
    by L-BFGS-B with ``minimize``'s options ``maxiter``, ``ftol`` and ``gtol``: what
    ``minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=[(0, upper)] * n,
    options=...).x`` returns."""
    x0 = np.asarray(x0, dtype=float)
    if x0.size and 0 < upper < np.inf and direct_available():
        return _direct(fun, x0, float(upper), maxiter, ftol, gtol)
    return _minimize(fun, x0, upper, maxiter, ftol, gtol)


def _minimize(fun, x0, upper, maxiter, ftol, gtol) -> np.ndarray:
    return minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=[(0.0, upper)] * len(x0),
                    options={"maxiter": maxiter, "ftol": ftol, "gtol": gtol}).x


def _direct(fun, x0, upper, maxiter, ftol, gtol) -> np.ndarray:
    """``minimize``'s L-BFGS-B loop, its evaluations counted and cached as its scalar
    function counts and caches them (one evaluation at x0 first; none again at the same
    x), each evaluation given its own copy of x."""
    n, m = x0.size, MAXCOR
    low, high = np.zeros(n), np.full(n, upper)
    nbd = np.full(n, 2, dtype=np.int32)  # both bounds finite
    x = np.clip(x0, low, high)
    last = x.copy()
    value, grad = fun(last.copy())
    nfev = 1
    f, g = np.array(0.0), np.zeros(n)
    wa = np.zeros(2 * m * n + 5 * n + 11 * m * m + 8 * m)
    iwa = np.zeros(3 * n, dtype=np.int32)
    task, ln_task = np.zeros(2, dtype=np.int32), np.zeros(2, dtype=np.int32)
    lsave, isave, dsave = (np.zeros(4, dtype=np.int32), np.zeros(44, dtype=np.int32),
                           np.zeros(29))
    factr = ftol / np.finfo(float).eps
    iterations = 0
    while True:
        _setulb(m, x, low, high, nbd, f, g, factr, gtol, wa, iwa, task, lsave, isave, dsave,
                MAXLS, ln_task)
        if task[0] == 3:  # evaluate at x
            if not (x == last).all():
                last = x.copy()
                value, grad = fun(last.copy())
                nfev += 1
            # minimize hands setulb a float64 copy of the gradient (setulb reads it only)
            f, g = value, np.array(grad, dtype=np.float64, ndmin=1)
        elif task[0] == 1:  # a new iterate
            iterations += 1
            if iterations >= maxiter:
                task[0], task[1] = 5, 504
            elif nfev > MAXFUN:
                task[0], task[1] = 5, 502
        else:
            return x


def direct_available() -> bool:
    """Whether the direct loop gives ``minimize``'s bits here (probed once; never tried
    on a scipy before :data:`FIRST_SCIPY`, whose Fortran routine takes other arguments)."""
    global _direct_ok
    if _direct_ok is None:
        _direct_ok = _setulb is not None and _version() >= FIRST_SCIPY and _probe()
    return _direct_ok


def _version() -> tuple[int, ...]:
    """scipy's (major, minor), (0,) where its version string says otherwise."""
    try:
        return tuple(int(part) for part in scipy.__version__.split(".")[:2])
    except ValueError:
        return (0,)


def _probe() -> bool:
    """Solve a fixed bound-constrained quadratic both ways: the same bits, or False (also
    when the direct loop fails: scipy's routine is not the one it was written for)."""
    rng = np.random.default_rng(27)
    a = rng.normal(size=(12, 9))
    q, c = a.T @ a, rng.normal(size=9) * 4.0

    def fun(x):
        qx = q @ x
        return 0.5 * float(x @ qx) + float(c @ x), qx + c

    x0 = np.where(c < 0, 2.0, 0.0)
    try:
        direct = _direct(fun, x0, 2.0, 500, 1e-14, 1e-10)
    except Exception:  # noqa: BLE001 (any failure means: not the routine it was written for)
        return False
    return np.array_equal(direct, _minimize(fun, x0, 2.0, 500, 1e-14, 1e-10))
