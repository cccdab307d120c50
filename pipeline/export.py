"""``box export``: a store's score matrix and metadata in formats other tools read.

Every format keeps the store's meaning: a score is -(path length) where the entry is
feasible and NaN elsewhere (never 0, the best score there is), the failure value that
``box evaluate`` puts in their place is stated in the metadata, statuses and failed steps
are given by name in the tabular formats, and ``box evaluate`` reads each export back
(:func:`read_export`) to the same result as the store.

* ``npz``: one array per quantity (what ``box evaluate`` has always read), ``metadata``
  as JSON text;
* ``netcdf``: an xarray Dataset (dimensions instance, constraint, feature, and
  instance_feature when the store holds instance features), metadata in its attributes;
* ``parquet``: one row per entry (instance, constraint, instance_seed, done, feasible,
  score, length, time, status, checks, step, forbidden), metadata (with the constraint
  features, and the instance features' values) in the file's key-value metadata under
  ``box-planning``;
* ``csv``: a folder with the same entry table, the constraints, the instances (with their
  features, a column each) and ``metadata.json``.

Where the store holds instance features, ``npz`` has them as ``instance_features`` (n, q)
and the metadata names them (``instance_features``: names and units; every format).
"""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import numpy as np

from box_core.failure import failure_value
from pipeline.evaluation import own_constraints
from pipeline.store import ScoreStore, StoreError
from pipeline.store.layout import (
    CHECKS,
    CONSTRAINTS,
    FEASIBLE,
    FEATURE,
    FEATURE_UNITS,
    INSTANCE_FEATURE,
    INSTANCE_FEATURE_UNITS,
    LENGTH,
    SCORE,
    SCORES,
    STATUS,
    STEP,
    TIME,
    key,
    result_key,
)

#: format -> the suffix of its file ("" for a folder)
FORMATS = {"npz": ".npz", "netcdf": ".nc", "parquet": ".parquet", "csv": ""}
STEP_KEY = result_key(SCORES, STEP)
#: the key of the metadata in a Parquet file's key-value metadata
PARQUET_KEY = b"box-planning"


def _arrays(store: ScoreStore) -> dict[str, np.ndarray]:
    if not store.has_results(SCORES):
        raise StoreError(f"{store.path} has no score matrix yet; run stage=generate first")
    done = store.done(SCORES)

    def scores(name):
        return store.result(SCORES, name)

    feasible = scores(FEASIBLE) & done
    length = scores(LENGTH)
    arrays = {
        "scores": np.where(feasible, -length, np.nan),  # what ``box evaluate`` reads
        "feasible": feasible,
        "times": scores(TIME),
        "features": store.theta(),
        "length": length,
        "status": scores(STATUS),
        "checks": scores(CHECKS),
        "step": (scores(STEP) if store.has(STEP_KEY)  # older stores
                 else np.full(feasible.shape, -1, dtype="int8")),
        "done": done,
        "instance_seed": store.instance_seeds(),
    }
    described = store.instance_features()
    if described is not None:
        arrays["instance_features"] = described.values
    own = own_constraints(store)
    if own is not None:  # what ``box evaluate`` hides from each row, as stage=evaluate does
        arrays["forbidden"] = own
    return arrays


def metadata(store: ScoreStore, arrays: dict) -> dict:
    attrs = store.attrs
    from pipeline.planning import Status

    feasible = arrays["feasible"]
    failure = (failure_value(np.nan_to_num(arrays["scores"]), feasible) if feasible.any()
               else None)
    described = store.instance_features()
    return {"store": str(store.path), "config_hash": attrs.get("config_hash"),
            "config": attrs.get("config"), "versions": attrs.get("versions"),
            "git_revision": attrs.get("git_revision"), "created": attrs.get("created"),
            "stages": attrs.get("stages"), "complete": bool(arrays["done"].all()),
            "status_codes": {s.name: int(s) for s in Status},
            "steps": (store.array(STEP_KEY).attrs.get("flag_meanings", "").split()
                      if store.has(STEP_KEY) else []),
            "score": "-(path length) where feasible; NaN where infeasible or not computed",
            "failure_value": failure, "failure_rule": "magnitude",
            "failure": "box evaluate scores infeasible entries with failure_value = "
                       "min(feasible scores) - |mean(feasible scores)| (rule 'magnitude')",
            "times": "seconds per planning call; NaN where not computed",
            "forbidden": "where present: entry (i, j) is a constraint extracted from row i's own "
                         "raw solution, hidden from row i in leave-one-out",
            **({"instance_features": {"names": list(described.names),
                                      "units": list(described.units)}}
               if described is not None else {})}


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
        raise ValueError(f"unknown format {fmt!r}; choose {', '.join(FORMATS)}")
    from pipeline.store.status import refuse_damaged

    store = ScoreStore.open(path)
    with store.reading_once():  # the done mask checked is the one exported, read once
        refuse_damaged(store)
        stem = store.path.name.removesuffix(".zarr")
        suffix = FORMATS[fmt]
        out = Path(out).expanduser() if out else Path.cwd() / f"{stem}{suffix or '-csv'}"
        if suffix and out.suffix != suffix:
            raise ValueError(f"{out}: a {fmt} export needs a path ending in {suffix}")
        check_target(out, fmt, overwrite)
        arrays = _arrays(store)
        meta = metadata(store, arrays)
    writer = WRITERS[fmt]
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
    if fmt != "csv" and not out.is_file():
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


def _status_names(codes) -> np.ndarray:
    from pipeline.planning import Status

    names = {int(st): st.name.lower() for st in Status}
    return np.array([names.get(int(c), "not_computed") for c in np.ravel(codes)], dtype=object)


def entry_table(store, arrays, meta):
    """One row per entry, statuses and steps by name (pandas DataFrame)."""
    import pandas as pd

    n, m = arrays["scores"].shape
    steps = meta["steps"]
    step = np.ravel(arrays["step"])
    table = pd.DataFrame({
        "instance": np.repeat(np.arange(n), m), "constraint": np.tile(np.arange(m), n),
        "instance_seed": np.repeat(arrays["instance_seed"], m),
        "done": np.ravel(arrays["done"]), "feasible": np.ravel(arrays["feasible"]),
        "score": np.ravel(arrays["scores"]), "length": np.ravel(arrays["length"]),
        "time": np.ravel(arrays["times"]), "status": _status_names(arrays["status"]),
        "checks": np.ravel(arrays["checks"]),
        "step": np.array([steps[k] if 0 <= k < len(steps) else "" for k in step],
                         dtype=object)})
    if "forbidden" in arrays:
        table["forbidden"] = np.ravel(arrays["forbidden"])
    return table


def _write_csv(out: Path, store, arrays, meta) -> None:
    out.mkdir()
    table = entry_table(store, arrays, meta)
    flags = table.select_dtypes(bool).columns
    table[flags] = table[flags].astype(int)  # 0/1, as spreadsheets and R read them
    table.to_csv(out / "entries.csv", index=False)
    with open(out / "constraints.csv", "w", newline="") as f:
        w = csv.writer(f)
        theta = arrays["features"]
        w.writerow(["constraint", *[f"theta{k}" for k in range(theta.shape[1])]])
        for j, row in enumerate(theta):
            w.writerow([j, *(repr(float(x)) for x in row)])
    with open(out / "instances.csv", "w", newline="") as f:
        w = csv.writer(f)
        described = meta.get("instance_features")
        w.writerow(["instance", "seed", *(described["names"] if described else []), "spec"])
        specs = store.instance_specs()
        features = arrays.get("instance_features", np.zeros((len(specs), 0)))
        for i, (seed, spec) in enumerate(zip(arrays["instance_seed"], specs, strict=True)):
            w.writerow([i, int(seed), *(repr(float(x)) for x in features[i]), str(spec)])
    (out / "metadata.json").write_text(json.dumps(meta, indent=1))


def _write_parquet(out: Path, store, arrays, meta) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pandas(entry_table(store, arrays, meta), preserve_index=False)
    doc = {**meta, "features": arrays["features"].tolist()}
    if "instance_features" in arrays:  # the values too: box evaluate's contextual selectors
        doc["instance_features"] = {**meta["instance_features"],
                                    "values": arrays["instance_features"].tolist()}
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                          PARQUET_KEY: json.dumps(doc).encode()})
    pq.write_table(table, out)


def _write_netcdf(out: Path, store, arrays, meta) -> None:
    """The entry arrays with the store's own attributes (units, long names, flag codes) and
    coordinates (instance, constraint, feature names and units where the store has them)."""
    import xarray as xr

    entry = ("instance", "constraint")
    n, m = arrays["feasible"].shape
    data, stored = {}, {"scores": SCORE, "times": TIME}  # names in the store, where other
    for name in ("scores", "feasible", "times", "length", "status", "checks", "step", "done",
                 "forbidden"):
        if name in arrays:
            at = result_key(SCORES, stored.get(name, name))
            attrs = dict(store.array(at).attrs) if store.has(at) else {}
            attrs.pop("coordinates", None)
            data[name] = xr.Variable(entry, arrays[name], attrs)
    data["scores"].attrs["long_name"] = "score: minus the path length (NaN: infeasible)"
    data["features"] = (("constraint", "feature"), arrays["features"])
    coords = {"instance": np.arange(n), "constraint": np.arange(m),
              "instance_seed": ("instance", arrays["instance_seed"])}
    for name in (FEATURE, FEATURE_UNITS):
        if store.has(key(CONSTRAINTS, name)):
            values = store.array(key(CONSTRAINTS, name))[...]
            coords[name] = ("feature", [str(v) for v in values])
    described = meta.get("instance_features")
    if described:
        data["instance_features"] = (("instance", INSTANCE_FEATURE), arrays["instance_features"])
        coords[INSTANCE_FEATURE] = (INSTANCE_FEATURE, described["names"])
        coords[INSTANCE_FEATURE_UNITS] = (INSTANCE_FEATURE, described["units"])
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update(metadata=json.dumps(meta), failure_rule=meta["failure_rule"],
                    **({"failure_value": meta["failure_value"]}
                       if meta["failure_value"] is not None else {}))
    ds.to_netcdf(out, engine="h5netcdf")


WRITERS = {"npz": _write_npz, "csv": _write_csv, "parquet": _write_parquet,
           "netcdf": _write_netcdf}


def read_export(path: Path):
    """A NetCDF or Parquet export as ``box evaluate`` takes it: (MatrixFile, forbidden)."""
    from box_core.io import MatrixFile

    try:
        if path.suffix == ".nc":
            import xarray as xr

            with xr.open_dataset(path, engine="h5netcdf") as ds:
                get = {k: ds[k].values for k in ds.data_vars}
        else:
            import pyarrow.parquet as pq

            table = pq.read_table(path)
            doc = json.loads((table.schema.metadata or {})[PARQUET_KEY])
            frame = table.to_pandas()
            n, m = int(frame["instance"].max()) + 1, int(frame["constraint"].max()) + 1
            grid = (frame["instance"].to_numpy(), frame["constraint"].to_numpy())

            def matrix(column, fill, dtype):
                out = np.full((n, m), fill, dtype=dtype)
                out[grid] = frame[column].to_numpy(dtype=dtype)
                return out

            get = {"scores": matrix("score", np.nan, float),
                   "feasible": matrix("feasible", False, bool),
                   "times": matrix("time", np.nan, float),
                   "features": np.asarray(doc["features"], dtype=float)}
            if "forbidden" in frame:
                get["forbidden"] = matrix("forbidden", False, bool)
            if "checks" in frame:
                get["checks"] = matrix("checks", 0, np.int64)
            described = doc.get("instance_features") or {}
            if "values" in described:
                get["instance_features"] = np.asarray(described["values"], dtype=float)
    except Exception as exc:  # noqa: BLE001 (any unreadable file: one line)
        raise ValueError(f"{path}: cannot read as a box export ({exc})") from None
    if "scores" not in get:
        raise ValueError(f"{path}: no scores in this file; is it a box export?")
    data = MatrixFile(scores=get["scores"], times=get.get("times"),
                      feasible=get.get("feasible"), features=get.get("features"),
                      instance_features=get.get("instance_features"), checks=get.get("checks"))
    return data, get.get("forbidden")


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
