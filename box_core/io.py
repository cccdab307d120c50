"""Loading score matrices that users bring: NumPy ``.npz`` archives and MATLAB ``.mat`` files."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.io


@dataclass(frozen=True, eq=False)
class MatrixFile:
    scores: np.ndarray
    times: np.ndarray | None = None
    feasible: np.ndarray | None = None
    features: np.ndarray | None = None


def load_matrix(
    path,
    *,
    scores: str = "scores",
    times: str | None = "times",
    feasible: str | None = "feasible",
    features: str | None = "features",
) -> MatrixFile:
    """Read a score matrix and its optional companions from ``path``.

    The keyword arguments name the arrays (``.npz``) or variables (``.mat``) to read;
    ``scores`` must exist, the others are used when present.  Raises FileNotFoundError for
    a missing file and ValueError for an unreadable file or a missing ``scores`` array.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    suffix = path.suffix.lower()
    if suffix not in (".npz", ".mat"):
        raise ValueError(f"{path}: unsupported format {suffix or '(none)'}; use .npz or .mat")
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                arrays = {name: archive[name] for name in archive.files}
        else:
            arrays = {k: v for k, v in scipy.io.loadmat(path).items() if not k.startswith("__")}
    except (OSError, ValueError, NotImplementedError) as exc:
        raise ValueError(f"{path}: cannot read as {suffix} ({exc})") from None
    if scores not in arrays:
        found = ", ".join(sorted(arrays)) or "nothing"
        raise ValueError(f"{path}: no array named {scores!r} (found: {found})")

    def optional(name):
        return None if name is None else arrays.get(name)

    return MatrixFile(
        scores=arrays[scores],
        times=optional(times),
        feasible=optional(feasible),
        features=optional(features),
    )
