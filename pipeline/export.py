"""``box export``: a store's score matrix and metadata in formats other tools read."""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import numpy as np

from pipeline.evaluation import own_constraints
from pipeline.store import ScoreStore, StoreError, path_scores, result_key

FORMATS = ("npz", "csv")
STEP = result_key("scores", "step")


def _arrays(store: ScoreStore) -> dict[str, np.ndarray]:
    if not store.has_results("scores"):
        raise StoreError(f"{store.path} has no score matrix yet; run stage=generate first")
    done = store.done("scores")
    def scores(name):
        return store.array(result_key("scores", name))[...]

    feasible = scores("feasible") & done
    length = scores("length")
    arrays = {
        "scores": path_scores(feasible, length),  # what ``box evaluate`` reads
        "feasible": feasible,
        "times": scores("time"),
        "features": store.theta(),
        "length": length,
        "status": scores("status"),
        "checks": scores("checks"),
        "step": (scores("step") if store.has(result_key("scores", "step"))  # older stores
                 else np.full(feasible.shape, -1, dtype="int8")),
        "done": done,
        "instance_seed": store.instance_seeds(),
    }
    own = own_constraints(store)
    if own is not None:  # what ``box evaluate`` hides from each row, as stage=evaluate does
        arrays["forbidden"] = own
    return arrays


def metadata(store: ScoreStore, arrays: dict) -> dict:
    attrs = store.attrs
    from pipeline.planning import Status

    return {"store": str(store.path), "config_hash": attrs.get("config_hash"),
            "config": attrs.get("config"), "versions": attrs.get("versions"),
            "git_revision": attrs.get("git_revision"), "created": attrs.get("created"),
            "stages": attrs.get("stages"), "complete": bool(arrays["done"].all()),
            "status_codes": {s.name: int(s) for s in Status},
            "steps": (store.array(STEP).attrs.get("flag_meanings", "").split()
                      if store.has(STEP) else []),
            "score": "-(path length) where feasible; 0 where infeasible or not computed",
            "times": "seconds per planning call; NaN where not computed",
            "forbidden": "where present: entry (i, j) is a constraint extracted from row i's own "
                         "raw solution, hidden from row i in leave-one-out"}


#: What a csv export folder holds (``--overwrite`` replaces a folder holding no more).
CSV_FILES = ("entries.csv", "constraints.csv", "instances.csv", "metadata.json")


def export(path, fmt: str, out: Path | None = None, overwrite: bool = False) -> tuple[Path, bool]:
    """Write the store at ``path`` as ``fmt``; return (what was written, complete?).

    Refuses (ValueError, nothing written) an existing ``out`` unless ``overwrite``, any
    ``out`` inside a zarr store, and a folder that cannot be written.  The export is written
    under a temporary name beside ``out`` and renamed into place, so an interrupted or
    failed export leaves no partial file and an overwritten one stays whole until then.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; choose {' or '.join(FORMATS)}")
    from pipeline.status import refuse_damaged

    store = ScoreStore.open(path)
    refuse_damaged(store)
    stem = store.path.name.removesuffix(".zarr")
    default = f"{stem}.npz" if fmt == "npz" else f"{stem}-csv"
    out = Path(out).expanduser() if out else Path.cwd() / default
    if fmt == "npz" and out.suffix != ".npz":
        raise ValueError(f"{out}: an npz export needs a path ending in .npz")
    check_target(out, fmt, overwrite)
    arrays = _arrays(store)
    meta = metadata(store, arrays)
    writer = _write_npz if fmt == "npz" else _write_csv
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
        try:
            writer(tmp, store, arrays, meta)
            _replace(tmp, out)
        finally:
            _remove(tmp)
    except OSError as exc:
        raise ValueError(f"-o {out}: cannot write there ({exc.strerror or exc})") from None
    return out, meta["complete"]


def check_target(out: Path, fmt: str, overwrite: bool) -> None:
    """Refuse ``out`` when it lies in a zarr store or exists (without ``overwrite``, or
    when it is not what this export would replace)."""
    store = enclosing_store(out)
    if store is not None:
        raise ValueError(f"-o {out}: inside the zarr store {store}; exports are never "
                         "written into a store")
    if not (out.exists() or out.is_symlink()):
        check_writable_parent(out)
        return
    if not overwrite:
        raise ValueError(f"-o {out} exists; pass --overwrite to replace it")
    if fmt == "npz" and not out.is_file():
        raise ValueError(f"-o {out} exists and is not a file; --overwrite replaces files only")
    if fmt == "csv":
        if not out.is_dir() or out.is_symlink():
            raise ValueError(f"-o {out} exists and is not a directory (a csv export is a "
                             "folder)")
        foreign = sorted(p.name for p in out.iterdir() if p.name not in CSV_FILES)
        if foreign:
            raise ValueError(f"-o {out} holds files a csv export does not write "
                             f"({', '.join(foreign[:3])}); --overwrite replaces only a "
                             "previous export")


def enclosing_store(path: Path) -> Path | None:
    """The Zarr store (any folder with a ``zarr.json``) that ``path`` is or lies in."""
    absolute = Path(path).absolute()
    for folder in (absolute, *absolute.parents):
        if (folder / "zarr.json").is_file():
            return folder
    return None


def check_writable_parent(out: Path) -> None:
    """Refuse ``out`` when its nearest existing ancestor is not a folder we may write in."""
    folder = out.absolute().parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise ValueError(f"-o {out}: {folder} is a file, not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"-o {out}: the folder {folder} is not writable")


def _write_npz(tmp: Path, store, arrays, meta) -> None:
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays, metadata=np.array(json.dumps(meta)))


def _write_csv(out: Path, store, arrays, meta) -> None:
    out.mkdir()
    n, m = arrays["scores"].shape
    with open(out / "entries.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["instance", "constraint", "done", "feasible", "length", "time", "status",
                    "checks", "step"])
        steps = meta["steps"]
        for i in range(n):
            for j in range(m):
                k = int(arrays["step"][i, j])
                w.writerow([i, j, int(arrays["done"][i, j]), int(arrays["feasible"][i, j]),
                            _cell(arrays["length"][i, j]), _cell(arrays["times"][i, j]),
                            int(arrays["status"][i, j]), int(arrays["checks"][i, j]),
                            steps[k] if 0 <= k < len(steps) else ""])
    with open(out / "constraints.csv", "w", newline="") as f:
        w = csv.writer(f)
        theta = arrays["features"]
        w.writerow(["constraint", *[f"theta{k}" for k in range(theta.shape[1])]])
        for j, row in enumerate(theta):
            w.writerow([j, *(repr(float(x)) for x in row)])
    with open(out / "instances.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["instance", "seed", "spec"])
        specs = store.instance_specs()
        for i, (seed, spec) in enumerate(zip(arrays["instance_seed"], specs, strict=True)):
            w.writerow([i, int(seed), str(spec)])
    (out / "metadata.json").write_text(json.dumps(meta, indent=1))


def _replace(tmp: Path, out: Path) -> None:
    """Move ``tmp`` to ``out``; an old ``out`` folder is set aside first, removed last."""
    if out.is_dir() and not out.is_symlink():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        out.rename(old)
        tmp.rename(out)
        _remove(old)
    else:
        os.replace(tmp, out)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif path.exists() or path.is_symlink():
        path.unlink()


def _cell(x) -> str:
    return "" if np.isnan(x) else repr(float(x))
