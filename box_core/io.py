"""Loading score matrices that users bring: NumPy ``.npz`` archives and MATLAB ``.mat`` files.

Everything here treats the file as untrusted: a missing or misnamed array, an unreadable,
truncated or empty file and a pickled object all raise one ``ValueError`` (or
``FileNotFoundError``) whose message names the file and what is wrong; nothing is executed
and no name the user gave is silently replaced by a default.
"""

from __future__ import annotations

import contextlib
import faulthandler
import multiprocessing
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The names each array is looked for under when the caller names none: the project's own
#: names first (``box export`` writes ``times``, a store holds ``scores/time``), then
#: common spellings.  The first present wins.
DEFAULT_NAMES: dict[str, tuple[str, ...]] = {
    "scores": ("scores",),
    "times": ("times", "time"),
    "feasible": ("feasible",),
    "features": ("features", "theta"),
    "forbidden": ("forbidden",),
    "instance_features": ("instance_features",),
    "checks": ("checks",),
}

SUFFIXES = (".npz", ".mat")


@dataclass(frozen=True, eq=False)
class MatrixFile:
    scores: np.ndarray
    times: np.ndarray | None = None
    feasible: np.ndarray | None = None
    features: np.ndarray | None = None
    #: (n x m) bool: columns row i may not try in leave-one-out (``box export`` writes the
    #: constraints extracted from row i's own raw solution here)
    forbidden: np.ndarray | None = None
    #: (n x q) features of each instance (the contextual selectors'; ``box export`` writes
    #: a store's here)
    instance_features: np.ndarray | None = None
    #: (n x m) collision checks each entry used (capped tries)
    checks: np.ndarray | None = None


def load_matrix(
    path,
    *,
    scores: str | None = None,
    times: str | None = None,
    feasible: str | None = None,
    features: str | None = None,
    forbidden: str | None = None,
    instance_features: str | None = None,
    checks: str | None = None,
) -> MatrixFile:
    """Read a score matrix and its optional companions from ``path``.

    Each keyword names the array (``.npz``) or variable (``.mat``) to read.  A name that is
    given must exist (a missing one is an error, never a default).  ``None`` looks for the
    names of :data:`DEFAULT_NAMES`: ``scores`` must then be found, the others are used when
    present.  Raises FileNotFoundError for a missing file and ValueError for anything else
    wrong (unsupported suffix, unreadable/truncated/empty file, pickled objects, missing
    named array, an array that is not a plain numeric or boolean one).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ValueError(f"{path}: unsupported format {suffix or '(none)'}; use .npz or .mat")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: cannot read as {suffix} (the file is empty)")
    wanted = {"scores": scores, "times": times, "feasible": feasible, "features": features,
              "forbidden": forbidden, "instance_features": instance_features, "checks": checks}
    with _opened(path, suffix) as arrays:
        chosen = {role: _pick(path, arrays, role, name) for role, name in wanted.items()}
        if chosen["scores"] is None:
            found = ", ".join(sorted(arrays)) or "nothing"
            raise ValueError(f"{path}: no array named 'scores' (found: {found}); "
                             "name it with --scores-var")
        return MatrixFile(**{role: None if name is None else _plain(path, name, arrays, suffix)
                             for role, name in chosen.items()})


@contextlib.contextmanager
def _opened(path: Path, suffix: str):
    """The file's arrays/variables by name; ``.npz`` members are read on access only, so
    an unrelated damaged or pickled member does not matter."""
    try:
        if suffix == ".npz":
            archive = np.load(path, allow_pickle=False)
            if not isinstance(archive, np.lib.npyio.NpzFile):
                raise ValueError("a single .npy array, not an .npz archive")
        else:
            archive = _read_mat(path)
    except Exception as exc:  # noqa: BLE001 - any parser failure means "cannot read"
        # zipfile, zlib, scipy.io and numpy raise a dozen unrelated types (BadZipFile,
        # MatReadError, EOFError, zlib.error, struct.error, ...) for damaged files.
        raise ValueError(f"{path}: cannot read as {suffix} ({_reason(exc)})") from None
    if suffix == ".npz":
        with archive:
            yield {name: archive for name in archive.files}  # value: where to read it
    else:
        yield archive


def _read_mat(path: Path) -> dict[str, np.ndarray]:
    """The variables of a MAT-file, read in a child process.

    scipy's MAT reader is not hardened against damaged files: some make it crash the
    process (a segmentation fault, found by tests/test_fuzz_box_evaluate.py; see scipy's
    loadmat documentation and scipy PR 25349).  In a child, a crash becomes an error.  The
    child sends back plain arrays only; a cell array or struct comes back as its dtype.
    """
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    receive, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_mat_child, args=(str(path), send), daemon=True)
    child.start()
    send.close()
    try:
        ok, payload = receive.recv()
    except EOFError:
        child.join()
        raise MatCrash(f"the MAT-file reader crashed (exit {child.exitcode}): the file is "
                       "damaged") from None
    finally:
        receive.close()
    child.join()
    if not ok:
        raise MatCrash(payload)
    return {k: (v if isinstance(v, np.ndarray) else np.empty(0, dtype=v))
            for k, v in payload.items()}


class MatCrash(Exception):
    """The child reading a MAT-file failed (its message is one line)."""


def _mat_child(path: str, send) -> None:
    faulthandler.disable()  # a crash is reported by the parent in one line
    os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
    try:
        import scipy.io  # here, in the child: every `box` command would pay its import

        found = {k: np.asarray(v) for k, v in scipy.io.loadmat(path).items()
                 if not k.startswith("__")}
        plain = {k: (v if v.dtype.kind in "biuf" else v.dtype.str) for k, v in found.items()}
        send.send((True, plain))
    except BaseException as exc:  # noqa: BLE001 - reported to the parent as one line
        send.send((False, _reason(exc)))
    finally:
        send.close()


def _pick(path: Path, arrays, role: str, name: str | None) -> str | None:
    """The name to read for ``role``: the given one (which must exist) or the first of
    :data:`DEFAULT_NAMES` present."""
    if name is not None:
        if name not in arrays:
            found = ", ".join(sorted(arrays)) or "nothing"
            raise ValueError(f"{path}: no array named {name!r} for {role} (found: {found})")
        return name
    return next((n for n in DEFAULT_NAMES[role] if n in arrays), None)


def _plain(path: Path, name: str, arrays, suffix: str) -> np.ndarray:
    """Array ``name`` as a numeric or boolean ndarray, refusing objects, text and structs."""
    value = arrays[name]
    if isinstance(value, np.lib.npyio.NpzFile):
        try:
            value = value[name]
        except Exception as exc:  # noqa: BLE001 - a damaged member, see _opened
            raise ValueError(f"{path}: cannot read array {name!r} as {suffix} "
                             f"({_reason(exc)})") from None
    arr = np.asarray(value)
    kind = arr.dtype.kind
    if kind not in "biuf":
        what = {"O": "objects (cell array, struct or pickle)", "U": "text", "S": "bytes",
                "V": "records", "c": "complex numbers"}.get(kind, f"dtype {arr.dtype}")
        raise ValueError(f"{path}: array {name!r} holds {what}; it must hold real numbers "
                         "or booleans")
    return arr


def _reason(exc: BaseException) -> str:
    if isinstance(exc, MatCrash):
        return str(exc)
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
