"""The direct L-BFGS-B loop (pipeline.planning.lbfgsb) answers as scipy.optimize.minimize
does, bit for bit, on the kind of problem TrajOpt gives it (a bound-constrained convex
quadratic, the dual of its subproblem) and on others."""

import numpy as np
import pytest
import scipy
from scipy.optimize import minimize

from pipeline.planning import lbfgsb
from pipeline.planning.trajopt import LBFGSB


def _minimize(fun, x0, upper, options=LBFGSB):
    """The reference: scipy's own minimize, as TrajOpt called it before."""
    return minimize(fun, x0, jac=True, method="L-BFGS-B", bounds=[(0.0, upper)] * len(x0),
                    options=dict(options)).x


def _quadratic(rng, n, rank):
    a = rng.normal(size=(rank, n))
    q, c = a.T @ a, rng.normal(size=n) * rng.uniform(0.1, 50.0)
    calls = []

    def fun(x):
        calls.append(x.copy())
        qx = q @ x
        return 0.5 * float(x @ qx) + float(c @ x), qx + c

    return fun, c, calls


def test_the_direct_loop_is_used_here():
    """On a scipy with the C routine the probe agrees, so TrajOpt gets the fast loop (were
    it not, every other test here would compare minimize with itself)."""
    if lbfgsb._version() < lbfgsb.FIRST_SCIPY:
        pytest.skip(f"scipy {scipy.__version__} is older than 1.15: the loop is never "
                    "tried there, minimize answers every call")
    assert lbfgsb.direct_available()


@pytest.mark.parametrize("seed", range(40))
def test_direct_loop_gives_minimizes_bits_on_trajopt_like_duals(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 120))
    rank = int(rng.integers(1, n + 8))  # singular Q too: a dual of few joints, many pairs
    fun, c, calls = _quadratic(rng, n, rank)
    upper = float(rng.choice([1.0, 10.0, 1e3]))
    x0 = np.where(c < 0, upper, 0.0)
    direct = lbfgsb.box_lbfgsb(fun, x0, upper, **LBFGSB)
    evaluations = len(calls)
    reference = _minimize(fun, x0, upper)
    assert np.array_equal(direct, reference)
    assert evaluations == len(calls) - evaluations  # the same evaluations, none more
    assert np.all((direct >= 0) & (direct <= upper))


def test_direct_loop_stops_at_maxiter_as_minimize_does():
    rng = np.random.default_rng(5)
    fun, c, _ = _quadratic(rng, 60, 60)
    x0 = np.zeros(60)
    for maxiter in (1, 2, 7):
        options = {**LBFGSB, "maxiter": maxiter}
        assert np.array_equal(lbfgsb.box_lbfgsb(fun, x0, 3.0, **options),
                              _minimize(fun, x0, 3.0, options))


def test_a_start_outside_the_box_is_clipped_as_minimize_clips_it():
    rng = np.random.default_rng(11)
    fun, _, _ = _quadratic(rng, 20, 10)
    x0 = rng.normal(size=20) * 5.0
    assert np.array_equal(lbfgsb.box_lbfgsb(fun, x0, 2.0, **LBFGSB), _minimize(fun, x0, 2.0))


def test_a_box_of_width_zero_goes_to_minimize():
    """minimize answers it without L-BFGS-B: every variable at its bound."""
    fun, _, _ = _quadratic(np.random.default_rng(1), 4, 4)
    assert np.array_equal(lbfgsb.box_lbfgsb(fun, np.ones(4), 0.0, **LBFGSB), np.zeros(4))


def test_an_older_scipy_or_a_failing_probe_sends_every_call_to_minimize(monkeypatch):
    """Before scipy 1.15 the routine takes other arguments: the loop is never tried; and
    where the probe fails (scipy's routine changed), minimize answers every call."""
    fun, c, calls = _quadratic(np.random.default_rng(8), 30, 20)
    x0 = np.where(c < 0, 5.0, 0.0)
    want = _minimize(fun, x0, 5.0)
    for version, probe in (((1, 14), True), ((1, 17), False)):
        monkeypatch.setattr(lbfgsb, "_direct_ok", None)
        monkeypatch.setattr(lbfgsb, "_version", lambda v=version: v)
        monkeypatch.setattr(lbfgsb, "_probe", lambda p=probe: p)
        direct = []
        monkeypatch.setattr(lbfgsb, "_direct", lambda *a, seen=direct: seen.append(a))
        assert not lbfgsb.direct_available()
        assert np.array_equal(lbfgsb.box_lbfgsb(fun, x0, 5.0, **LBFGSB), want)
        assert not direct
