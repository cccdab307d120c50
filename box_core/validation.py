"""Input checks at the boundary of box_core.

Every public entry point converts its arguments through these helpers, so a bad
matrix fails early with a ``ValueError`` that names the argument and the problem,
instead of surfacing later as a NaN or an IndexError deep inside a selector.
"""

from __future__ import annotations

import numpy as np


def score_matrix(scores, *, name: str = "scores", min_rows: int = 1,
                 feasible=None) -> np.ndarray:
    """Return ``scores`` as a finite float64 (n, m) array, or raise ValueError.

    With a ``feasible`` mask, NaN is accepted where an entry is infeasible (a score store's
    and ``box export``'s convention) and returned as 0: the caller replaces every
    infeasible entry by the failure value anyway.  NaN in a feasible entry is refused."""
    try:
        arr = np.asarray(scores, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric 2-D array: {exc}") from None
    if arr.ndim != 2:
        raise ValueError(f"{name} must be 2-D (instances x constraints), got shape {arr.shape}")
    n, m = arr.shape
    if m < 1:
        raise ValueError(f"{name} has no columns (shape {arr.shape})")
    if n < min_rows:
        raise ValueError(f"{name} needs at least {min_rows} rows, got {n}")
    if feasible is not None:
        mask = boolean_matrix(feasible, arr.shape, name="feasible")
        arr = np.where(np.isnan(arr) & ~mask, 0.0, arr)
    try:
        _require_finite(arr, name)
    except ValueError as exc:
        hint = ("a feasible entry cannot be NaN" if feasible is not None else
                "NaN may mark infeasible entries only when a feasibility mask is given")
        raise ValueError(f"{exc} ({hint})") from None
    return arr


def matching_matrix(values, shape: tuple[int, int], *, name: str, ref: str = "scores"):
    """A float64 array with exactly ``shape`` and finite entries."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != shape:
        raise ValueError(f"{name} has shape {arr.shape} but {ref} has shape {shape}")
    _require_finite(arr, name)
    return arr


def boolean_matrix(values, shape: tuple[int, int], *, name: str, ref: str = "scores"):
    """A bool array with exactly ``shape``; accepts bools or 0/1 numbers."""
    arr = np.asarray(values)
    if arr.shape != shape:
        raise ValueError(f"{name} has shape {arr.shape} but {ref} has shape {shape}")
    if arr.dtype != np.bool_:
        if not np.issubdtype(arr.dtype, np.number) or not np.isin(arr, (0, 1)).all():
            raise ValueError(f"{name} must be boolean (or 0/1), got dtype {arr.dtype}")
        arr = arr.astype(bool)
    return arr


def feature_matrix(features, m: int, *, name: str = "features") -> np.ndarray:
    """Constraint features, one row per constraint: finite float64 (m, p)."""
    arr = np.asarray(features, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[0] != m:
        raise ValueError(
            f"{name} must have one row per constraint: expected ({m}, p), got {arr.shape}"
        )
    _require_finite(arr, name)
    return arr


def instance_features(values, n: int, *, name: str = "instance_features",
                      ref: str = "scores") -> np.ndarray:
    """Instance features, one row per instance: finite float64 (n, q), q >= 0."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric (instances x features) array: {exc}") \
            from None
    if arr.ndim != 2 or arr.shape[0] != n:
        raise ValueError(f"{name} must have one row per instance of {ref}: expected "
                         f"({n}, q), got {arr.shape}")
    _require_finite(arr, name)
    return arr


def feature_row(values, q: int, *, name: str = "new_instance_features") -> np.ndarray:
    """The features of one instance: finite float64 (q,)."""
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric vector: {exc}") from None
    if arr.shape != (q,):
        raise ValueError(f"{name} must have shape ({q},), one value per column of "
                         f"instance_features, got {arr.shape}")
    _require_finite(arr, name)
    return arr


def checks_matrix(values, shape: tuple[int, int], *, name: str = "checks",
                  ref: str = "scores") -> np.ndarray:
    """Collision checks per entry: non-negative whole numbers with exactly ``shape``,
    returned as float64."""
    arr = np.asarray(values)
    if arr.shape != shape:
        raise ValueError(f"{name} has shape {arr.shape} but {ref} has shape {shape}")
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must hold whole numbers of collision checks, "
                         f"got dtype {arr.dtype}")
    arr = arr.astype(np.float64)
    _require_finite(arr, name)
    if (arr < 0).any() or (arr != np.round(arr)).any():
        raise ValueError(f"{name} must hold whole numbers >= 0")
    return arr


def score_vector(values, m: int, *, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (m,):
        raise ValueError(f"{name} must have shape ({m},), got {arr.shape}")
    _require_finite(arr, name)
    return arr


def _require_finite(arr: np.ndarray, name: str) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        where = tuple(int(i) for i in np.argwhere(bad)[0])
        kind = "NaN" if np.isnan(arr[where]) else "inf"
        raise ValueError(
            f"{name} contains {int(bad.sum())} non-finite value(s); "
            f"first is {kind} at index {where}"
        )
