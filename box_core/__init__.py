"""BOX: constraint selection in score space (Kim, Kaelbling, Lozano-Perez, ICRA 2017).

Works on any score matrix D (instances x constraints, higher is better) held as a NumPy
array; depends on numpy and scipy only.
"""

from box_core.failure import failure_value, fill_failures
from box_core.loocv import DEFAULT_SELECTORS, LoocvResult, holdout, loocv
from box_core.prior import Prior
from box_core.selectors import (
    SELECTOR_REVISION,
    SELECTORS,
    Selector,
    make_selector,
    tuned_settings,
)
from box_core.summary import Summary, curve_summary
from box_core.tuning import CTuning, learning_curve, tune_c

__all__ = [
    "CTuning",
    "DEFAULT_SELECTORS",
    "SELECTORS",
    "SELECTOR_REVISION",
    "LoocvResult",
    "Prior",
    "Selector",
    "Summary",
    "curve_summary",
    "failure_value",
    "fill_failures",
    "holdout",
    "learning_curve",
    "loocv",
    "make_selector",
    "tuned_settings",
    "tune_c",
]
