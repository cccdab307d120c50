"""The live selector's tries (Selector.propose_try / report): a capped selector run live
tries what the simulation of capped tries (holdout) tries, an uncapped one through the
same loop is propose / update, and misuse is named."""

from __future__ import annotations

import math

import numpy as np
import pytest

import box_core
from tests.test_contextual import internal, problem

CAPPED = "contextual_capped"


def live_tries(sel, scores, checks, ends, overshoot=0):
    """Run ``sel`` against a row as tries.py's rule does (paused iff the stored checks
    exceed the allowance) until ``ends`` tries ended; paused tries report
    ``overshoot`` checks beyond their allowance.  Returns [(column, allowance)]."""
    out, ended = [], 0
    while ended < ends:
        col, allow = sel.propose_try()
        out.append((col, allow))
        if checks[col] > allow:
            sel.report(col, paused=True, checks_used=int(allow) + overshoot)
        else:
            sel.report(col, score=scores[col], checks_used=int(checks[col]))
            ended += 1
    return out


def test_live_capped_tries_are_the_simulated_ones():
    paused = sum(compare_with_holdout(seed) for seed in range(4))
    assert paused  # the examples cover pauses and resumptions


def compare_with_holdout(seed):
    """Checks one example; returns how many of its tries paused."""
    S, F, T, C, X = problem(30, 7, 3, seed)
    Dn = internal(S, F)
    top = np.unravel_index(np.abs(Dn).argmax(), Dn.shape)[0]
    test = 29 if top != 29 else 28  # the training rows keep the score unit
    train = np.setdiff1d(np.arange(30), [test])
    params = {"k": 6, "cap_quantile": 0.5}
    res = box_core.holdout(Dn, train, [test], times=T, feasible=F, checks=C,
                           selectors=(CAPPED,), params={CAPPED: params},
                           instance_features=X, measure_overhead=False, k=7)
    order = res.order[CAPPED][0]
    used = order >= 0
    allowance = res.allowance.get(CAPPED, np.full(order.shape, np.inf)[None])[0]
    want = list(zip(order[used].tolist(), allowance[used].tolist(), strict=True))
    for overshoot in (0, 37):
        sel = box_core.make_selector(CAPPED, Dn[train], times=T[train], feasible=F[train],
                                     checks=C[train], instance_features=X[train],
                                     new_instance_features=X[test], **params)
        got = live_tries(sel, Dn[test], C[test], 7, overshoot)
        assert got == want
        assert sel.capped == math.isfinite(res.settings[CAPPED]["cap"][0])
        assert [j for j, *_ in sel.history] == [j for j, _ in want if C[test, j] <= _]
        with pytest.raises(RuntimeError, match="all 7 constraints"):
            sel.propose_try()
    return sum(1 for j, a in want if C[test, j] > a)


@pytest.mark.parametrize("name, kwargs", [("box", {}), ("eips", {}), ("contextual", {"k": 5})])
def test_uncapped_tries_are_propose_and_update(name, kwargs):
    S, F, T, C, X = problem(25, 6, 2, 3)
    D = internal(S, F)
    args = dict(times=T[:-1], feasible=F[:-1], **kwargs)
    if name == "contextual":
        args.update(instance_features=X[:-1], new_instance_features=X[-1], checks=C[:-1])
    plain = box_core.make_selector(name, D[:-1], **args)
    tries = box_core.make_selector(name, D[:-1], **args)
    assert not tries.capped
    for _ in range(6):
        j = plain.propose()
        assert tries.propose_try() == (j, math.inf)
        plain.update(j, D[-1, j])
        tries.report(j, score=D[-1, j])
    assert tries.history == plain.history


def capped_selector():
    S, F, T, C, X = problem(30, 7, 3, 1)  # its first try is capped
    D = internal(S, F)
    sel = box_core.make_selector(CAPPED, D[:-1], times=T[:-1], feasible=F[:-1], checks=C[:-1],
                                 instance_features=X[:-1], new_instance_features=X[-1],
                                 k=6, cap_quantile=0.5, select_features=0)
    assert sel.capped
    return sel, D[-1]


def test_misuse_is_named():
    sel, truth = capped_selector()
    with pytest.raises(ValueError, match="no try is pending"):
        sel.report(0, score=-1.0)
    col, allow = sel.propose_try()
    assert math.isfinite(allow)
    assert sel.propose_try() == (col, allow)  # asking again: the same try
    other = (col + 1) % sel.m
    for kwargs, message in [
        ({"column": other, "score": -1.0}, f"column {other} was not proposed"),
        ({"column": col, "score": -1.0, "paused": True}, "a paused try has no score"),
        ({"column": col}, "a try that ended needs its score"),
        ({"column": col, "score": math.nan}, "score must be finite"),
        ({"column": col, "paused": True, "checks_used": int(allow) - 1},
         "a paused try has used its allowance"),
        ({"column": col, "paused": True, "checks_used": -3}, "checks_used must be a whole"),
        ({"column": col, "paused": 1}, "paused must be True or False"),
        ({"column": sel.m, "score": -1.0}, "out of range"),
    ]:
        with pytest.raises(ValueError, match=message):
            sel.report(**kwargs)
    assert not sel.tried.any()  # nothing was recorded
    with pytest.raises(RuntimeError, match="use propose_try and report"):
        sel.propose()
    with pytest.raises(RuntimeError, match="use propose_try and report"):
        sel.update(col, -1.0)
    sel.report(col, paused=True)
    assert sel.tried[col] and not sel.history
    assert sel.tries == [(col, allow, None, None)]
    sel.propose_try()
    with pytest.raises(ValueError, match="score must be finite"):
        sel.report(sel.propose_try()[0], score=truth[0] * math.inf)


def test_an_uncapped_try_cannot_pause():
    S, F, T, C, X = problem(10, 4, 2, 0)
    sel = box_core.make_selector("box", internal(S, F)[:-1])
    col, allow = sel.propose_try()
    assert allow == math.inf
    with pytest.raises(ValueError, match="an uncapped try cannot pause"):
        sel.report(col, paused=True)
