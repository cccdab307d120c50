"""The score given to a failed plan (paper eq. 3).

The paper defines the failure score as d = min(D) - mean(D).  With scores that are negated
path lengths (all negative) the literal formula lands *above* the worst feasible score
(min = -5, mean = -2 gives d = -3), which contradicts its stated purpose, an artificial
scale-sensitive minimum.  The default rule keeps the intent:

    magnitude:  d = min(D_feasible) - |mean(D_feasible)|
    literal:    d = min(D_feasible) - mean(D_feasible)

Both use the feasible entries only, since the infeasible ones have no score yet.
"""

from __future__ import annotations

import numpy as np

from box_core import validation

RULES = ("magnitude", "literal")


def failure_value(scores, feasible, rule: str = "magnitude") -> float:
    """Failure score d for a score matrix and its feasibility mask.

    Entries of ``scores`` where ``feasible`` is False are ignored.  Raises ValueError when
    nothing is feasible (d is undefined) or the rule is unknown.  When the magnitude rule
    would give d equal to the worst feasible score (mean exactly 0), d = min - 1.
    """
    if rule not in RULES:
        raise ValueError(f"unknown failure rule {rule!r}; choose one of {', '.join(RULES)}")
    D = validation.score_matrix(scores)
    F = validation.boolean_matrix(feasible, D.shape, name="feasible")
    if not F.any():
        raise ValueError("no feasible entries: the failure value is undefined")
    values = D[F]
    low, mean = values.min(), values.mean()
    if rule == "literal":
        return float(low - mean)
    gap = abs(mean)
    return float(low - (gap if gap > 0 else 1.0))


def fill_failures(scores, feasible, d: float) -> np.ndarray:
    """A copy of ``scores`` with every infeasible entry replaced by ``d``."""
    return np.where(feasible, scores, d)
