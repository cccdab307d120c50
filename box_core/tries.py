"""Capped, resumable tries, simulated from a score matrix's stored effort.

A planning call can be given an *allowance* of collision checks.  Entry (i, j) of a score
matrix needed ``checks[i, j]`` checks to end (with a plan, or refuted, or out of budget:
such entries hold the budget, just over 20,000 in the project's stores, and are
infeasible).  A try of (i, j) whose cumulative allowance is c:

- ends if ``checks[i, j] <= c``: a plan if the entry is feasible, a failure for good if
  not;
- otherwise it is *paused* at c checks and may be resumed later to a larger allowance,
  continuing where it stopped (OMPL's RRT-Connect keeps its trees between calls).

Its cost is the share of the entry's time its checks take: going from allowance a to c
costs ``times[i, j] * (min(c, checks) - a) / checks`` (all of ``times[i, j]`` for an
entry that needed no check).  An uncapped try has c = inf and costs what is left.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

#: Outcomes of one try
FAILED, FEASIBLE, PAUSED = 0, 1, 2


def outcome_of_try(need, granted, allowance, feasible, times):
    """(outcome, cost) of tries that raise entries' allowances from ``granted`` to
    ``allowance`` (arrays of one shape; ``need`` = the entries' stored checks, None: every
    try ends, at its full time)."""
    if need is None:
        return np.where(feasible, FEASIBLE, FAILED), np.asarray(times, dtype=np.float64)
    need = np.asarray(need, dtype=np.float64)
    ends = need <= allowance
    upto = np.minimum(allowance, need)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(need > 0, (upto - granted) / need, 1.0)
    outcome = np.where(ends, np.where(feasible, FEASIBLE, FAILED), PAUSED)
    return outcome, times * share


@dataclass(eq=False)
class TryTrace:
    """The tries of B instances, (B, K) each, padded with -1 / 0 / False after the last.

    ``order``: the column of each try (a resumed column appears again); ``allowance``: its
    cumulative check allowance (inf: uncapped); ``cost``: its planning seconds (the share);
    ``outcome``: FAILED, FEASIBLE or PAUSED (-1 padding); ``overhead``: the selector's own
    seconds per try.
    """

    order: np.ndarray
    allowance: np.ndarray
    cost: np.ndarray
    outcome: np.ndarray
    overhead: np.ndarray


def padded(trace: TryTrace, width: int) -> TryTrace:
    """``trace`` widened to ``width`` tries with padding (-1 / 0 / -1)."""
    B, w = trace.order.shape
    pads = {"order": -1, "allowance": 0.0, "cost": 0.0, "outcome": -1, "overhead": 0.0}
    out = {}
    for key, pad in pads.items():
        values = getattr(trace, key)
        out[key] = np.full((B, width), pad, dtype=values.dtype)
        out[key][:, :w] = values
    return TryTrace(**out)


def empty_trace(rows: int, width: int = 0) -> TryTrace:
    """A trace of ``rows`` instances and no tries, padded to ``width``."""
    return padded(TryTrace(order=np.zeros((rows, 0), dtype=np.intp),
                           allowance=np.zeros((rows, 0)), cost=np.zeros((rows, 0)),
                           outcome=np.zeros((rows, 0), dtype=np.int8),
                           overhead=np.zeros((rows, 0))), width)


#: the tries a trace holds room for at first; it doubles as tries are made
FIRST_WIDTH = 16


def simulate(policy, scores, feasible, times, checks, ends: int, *,
             until_feasible: bool = False, measure: bool = False, done=None,
             peak=None, full_width: bool = True) -> TryTrace:
    """Run ``policy`` (one with ``propose_tries``, ``record``, ``ended``, ``settled``,
    ``remaining`` and ``keep``, see :class:`box_core.contextual.Contextual`) against its B
    instances' true rows (``scores``, ``feasible``, ``times``, ``checks``: (B, m);
    ``checks`` None: every try ends).  Each instance stops once ``ends`` of its tries have
    ended, or every column it may try has (or, with ``until_feasible``, at its first
    plan; or where ``done(instances, found, peaked)`` says so, given whether each has found
    a plan and ended a try at a column of ``peak`` (B, m)).  Instances that stop leave the
    batch; a settled instance (no observation can change its later choices) gets its
    remaining tries listed at once, uncapped.

    The trace is (B, 2 * the largest number of ended tries allowed) wide (each ended try
    is at most two: a capped try and its resumption); with ``full_width=False`` only as
    wide as the most tries made.  It grows as tries are made (a run that stops at the first
    plan makes a few of its thousands allowed)."""
    B, m = feasible.shape
    limit = np.minimum(ends, m - policy.tried.sum(axis=1))  # ended tries per instance
    width = 2 * int(limit.max(initial=0))
    trace = empty_trace(B, min(width, FIRST_WIDTH))
    granted = np.zeros((B, m))
    here = np.arange(B)  # the instance of each row of the policy's batch
    step = np.zeros(B, dtype=np.intp)  # tries made, per instance
    ended = np.zeros(B, dtype=np.intp)
    found = np.zeros(B, dtype=bool)  # a plan found, per instance
    peaked = np.zeros(B, dtype=bool)  # a try at a column of peak ended, per instance

    def note(inst, cols, allow, spent):
        """Simulate and write down one try of each instance ``inst``."""
        nonlocal trace
        need = None if checks is None else checks[inst, cols]
        outcome, cost = outcome_of_try(need, granted[inst, cols], allow,
                                       feasible[inst, cols], times[inst, cols])
        at = step[inst]
        if at.size and at.max() >= trace.order.shape[1]:
            trace = padded(trace, min(width, 2 * trace.order.shape[1]))
        trace.order[inst, at] = cols
        trace.allowance[inst, at] = allow
        trace.cost[inst, at] = cost
        trace.outcome[inst, at] = outcome
        trace.overhead[inst, at] = spent
        granted[inst, cols] = allow
        step[inst] += 1
        ended[inst] += outcome != PAUSED
        return outcome

    stop = ended[here] >= limit[here]
    while True:
        if stop.any():
            kept = np.flatnonzero(~stop)
            if not kept.size:
                break
            policy.keep(kept)
            here = here[kept]
        clock = time.perf_counter()
        calm = policy.settled() if not until_feasible else np.zeros(here.size, bool)
        for b in np.flatnonzero(calm):  # the rest of its tries, uncapped
            inst = here[b:b + 1]
            cols = policy.remaining(np.array([b]), int(limit[inst[0]] - ended[inst[0]]))[0]
            for col in cols:
                note(inst, np.array([col]), np.inf, 0.0)
        if calm.any():
            spent = (time.perf_counter() - clock) / int(calm.sum())
            for b in np.flatnonzero(calm):
                trace.overhead[here[b], :step[here[b]]][-1:] += spent
            stop = calm
            continue
        cols, allow = policy.propose_tries()
        spent = time.perf_counter() - clock
        need = None if checks is None else checks[here, cols]
        outcome, _ = outcome_of_try(need, granted[here, cols], allow, feasible[here, cols],
                                    times[here, cols])
        clock = time.perf_counter()
        policy.record(cols, outcome, scores[here, cols])
        spent += time.perf_counter() - clock
        note(here, cols, allow, spent / here.size)
        stop = ended[here] >= limit[here]
        if until_feasible:
            stop |= outcome == FEASIBLE
        if done is not None:
            found[here] |= outcome == FEASIBLE
            if peak is not None:
                peaked[here] |= (outcome != PAUSED) & peak[here, cols]
            stop |= done(here, found[here], peaked[here])
    if not measure:
        trace.overhead[:] = 0.0
    used = int(step.max(initial=0))
    if full_width and trace.order.shape[1] < width:
        return padded(trace, width)
    if not full_width and trace.order.shape[1] > used:
        return TryTrace(**{key: values[:, :used] for key, values in vars(trace).items()})
    return trace
