"""BOX: constraint selection in score space (Kim, Kaelbling, Lozano-Perez, ICRA 2017).

Works on any score matrix D (instances x constraints, higher is better) held as a NumPy
array; depends on numpy and scipy only.
"""

from box_core.failure import failure_value, fill_failures
from box_core.loocv import DEFAULT_SELECTORS, LoocvResult, loocv
from box_core.prior import Prior
from box_core.selectors import SELECTORS, Selector, make_selector
from box_core.summary import Summary, curve_summary

__all__ = [
    "DEFAULT_SELECTORS",
    "SELECTORS",
    "LoocvResult",
    "Prior",
    "Selector",
    "Summary",
    "curve_summary",
    "failure_value",
    "fill_failures",
    "loocv",
    "make_selector",
]
