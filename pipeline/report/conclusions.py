"""The sentence a report opens with: how BOX compares with its strongest competitor.

The numbers are the ones stage ``evaluate`` stored in the store's summary (the ratio of mean
times on the instances both selectors solved, and its interval), so the sentence, the
summary table and the ratio plot can never disagree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from box_core.stats import RATIO_INTERVAL_METHOD
from pipeline.report.data import StoreResults
from pipeline.report.figures import ORACLES, label

#: The selector every other one is compared with.
REFERENCE = "box"


@dataclass(frozen=True)
class Conclusion:
    """BOX against the best non-oracle competitor of one store.

    ``ratio``, ``low`` and ``high`` are the stored mean time of the competitor over BOX's
    (above 1: BOX is faster) and its interval; ``resolved`` says whether the interval
    leaves out 1.  ``sentence`` states it for a reader.
    """

    competitor: str | None
    ratio: float
    low: float
    high: float
    level: float
    paired_rows: int
    resolved: bool
    sentence: str


def competitors(res: StoreResults) -> list[dict]:
    """The summary lines BOX is compared with: no oracle (they see the held-out truth),
    not BOX itself, and only lines with a ratio to BOX."""
    return [line for line in res.summary["selectors"]
            if line["name"] not in (*ORACLES, REFERENCE) and line.get("speedup") is not None]


def paired_rows(res: StoreResults, name: str) -> int:
    """Instances with a feasible constraint that both BOX and ``name`` solved: the rows
    the stored ratio of mean times is computed on."""
    mine = res.first_feasible_time.get(name)
    ref = res.first_feasible_time.get(REFERENCE)
    if mine is None or ref is None:
        return 0
    rows = res.eligible
    return int((~np.isnan(mine[rows]) & ~np.isnan(ref[rows])).sum())


def conclude(res: StoreResults) -> Conclusion:
    """BOX against the competitor with the lowest ratio of mean times to BOX's."""
    level = float(res.summary.get("level", 0.95))
    if res.summary.get("reference") != REFERENCE:
        return Conclusion(None, math.nan, math.nan, math.nan, level, 0, False,
                          f"On {res.label}, BOX was not evaluated, so there is no comparison "
                          "with it.")
    lines = competitors(res)
    if not lines:
        return Conclusion(None, math.nan, math.nan, math.nan, level, 0, False,
                          f"On {res.label}, no selector other than BOX and the oracles was "
                          "evaluated, so BOX is compared with nothing.")
    best = min(lines, key=lambda line: line["speedup"])
    ratio = float(best["speedup"])
    low, high = (math.nan if best[k] is None else float(best[k])
                 for k in ("speedup_low", "speedup_high"))
    rows = paired_rows(res, best["name"])
    resolved = math.isfinite(low) and math.isfinite(high) and (low > 1 or high < 1)
    return Conclusion(best["name"], ratio, low, high, level, rows, resolved,
                      sentence(res.label, label(best["name"]), ratio, low, high, level, rows))


def sentence(where: str, other: str, ratio: float, low: float, high: float, level: float,
             rows: int) -> str:
    """One sentence: BOX's speed against ``other`` from the ratio mean(other) / mean(BOX)
    with its interval, turned round when BOX is the slower one (then the factor is how many
    times longer BOX's mean time is, and the interval's ends swap and invert)."""
    basis = (f"mean time to a first feasible plan over the {_instances(rows)} both solved; "
             f"{level * 100:g} % {RATIO_INTERVAL_METHOD} interval")
    if ratio >= 1:
        factor, lo, hi, word = ratio, low, high, "faster"
    else:
        factor, lo, hi, word = 1 / ratio, _inverse(high), _inverse(low), "slower"
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return (f"On {where}, BOX finds a first feasible plan {_num(factor)}× {word} than "
                f"{other} ({basis}), with no interval from {_instances(rows)}.")
    amount = f"{_num(factor)}× [{_num(lo)}, {_num(hi)}]"
    if ratio == 1:
        head = f"BOX and {other} find a first feasible plan equally fast ({amount})"
    else:
        head = f"BOX finds a first feasible plan {amount} {word} than {other}"
    verdict = ("" if lo > 1 or hi < 1 else
               ", but the interval includes 1: the difference is not resolved on "
               f"{_instances(rows)}")
    return f"On {where}, {head} ({basis}){verdict}."


def _instances(rows: int) -> str:
    return f"{rows} instance{'' if rows == 1 else 's'}"


def _inverse(x: float) -> float:
    return 1 / x if math.isfinite(x) and x > 0 else math.nan


def _num(x: float) -> str:
    """A factor for a sentence: three significant digits."""
    return f"{x:.3g}"
