"""box_core.tries.simulate: its traces grow as tries are made, with the same numbers."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import box_core
from box_core import contextual, tries
from tests.test_contextual import problem

FIELDS = ("order", "allowance", "cost", "outcome", "overhead")


def capped_case():
    S, F, T, C, X = problem(40, 12, 3, seed=5)
    return S, dict(times=T, feasible=F, checks=C, instance_features=X,
                   selectors=("contextual_capped",), measure_overhead=False)


@pytest.mark.parametrize("first", [1, 3])
def test_a_trace_that_grows_gives_the_numbers_of_one_made_at_full_width(monkeypatch, first):
    # m = k = 12: traces 24 tries wide, grown from 1 or 3 (several doublings) against made
    # at full width at once; the tuning's inner runs and the held-out rows' tries alike
    S, kwargs = capped_case()
    monkeypatch.setattr(tries, "FIRST_WIDTH", 10**6)
    wide = box_core.loocv(S, **kwargs)
    monkeypatch.setattr(tries, "FIRST_WIDTH", first)
    grown = box_core.loocv(S, **kwargs)
    name = "contextual_capped"
    for field in ("order", "allowance", "try_time", "first_feasible_step",
                  "first_feasible_planning_time", "best_score"):
        np.testing.assert_array_equal(getattr(grown, field)[name],
                                      getattr(wide, field)[name], err_msg=field)
    assert grown.order[name].shape == (S.shape[0], 2 * S.shape[1])
    for key, values in wide.settings[name].items():
        np.testing.assert_array_equal(grown.settings[name][key], values, err_msg=key)


def test_a_trace_without_full_width_is_the_full_one_less_its_padding(monkeypatch):
    # the tuning's runs to the first plan ask for the narrow trace: each is the full-width
    # trace of the same policy cut after the last try made
    S, kwargs = capped_case()
    simulate = tries.simulate
    pairs = []

    def both(policy, *args, full_width=True, **kw):
        twin = copy.deepcopy(policy)
        narrow = simulate(policy, *args, full_width=False, **kw)
        pairs.append((narrow, simulate(twin, *args, full_width=True, **kw)))
        return narrow

    monkeypatch.setattr(contextual, "simulate", both)
    box_core.loocv(S, **kwargs)
    assert pairs
    for narrow, wide in pairs:
        made = int((narrow.order >= 0).sum(axis=1).max(initial=0))
        assert narrow.order.shape[1] == made < wide.order.shape[1]
        for key in FIELDS:
            np.testing.assert_array_equal(getattr(wide, key)[:, :made], getattr(narrow, key))
        assert (wide.order[:, made:] == -1).all() and (wide.outcome[:, made:] == -1).all()
        assert not wide.cost[:, made:].any() and not wide.allowance[:, made:].any()
