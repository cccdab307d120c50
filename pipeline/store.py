"""The Zarr v3 score store: layout, identity checks, the run lock and integrity checks.

Layout (a contract: users open it with ``xarray.open_zarr(path, group=...)``)::

    /                 attrs: format, layout_version, identity, config_hash, config,
                             versions, git_revision, created, stages
    instances/        seed (instance), spec (instance; JSON text)
    raw/              score length feasible time status checks tries (instance),
                      constraint (instance, feature), done (instance)
    constraints/      theta (constraint, feature), source_instance (constraint)
    scores/           score length feasible time status checks (instance, constraint),
                      done (instance, constraint)
    evaluation/       per selector: order, first_feasible_step, first_feasible_time,
                      best_score; time_grid; attrs: summary

Who writes what (DESIGN.md §5): only the coordinating process creates arrays and writes
attributes and ``done`` masks, all before or after the workers' tasks; a task writes
exactly its own whole chunks.  A chunk's existence proves nothing (all-fill chunks are
not written), so completion is read from ``done`` only.  Every chunk carries a CRC32C
checksum; a chunk that fails it is reported by ``status`` and recomputed on resume.
"""

from __future__ import annotations

import datetime as _dt
import fcntl
import json
import os
import shutil
import socket
import subprocess
import warnings
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from pipeline.planning import Status

FORMAT = "box-planning-score-store"
LAYOUT_VERSION = 1
LOCK_SUFFIX = ".lock"
CODECS = (ZstdCodec(level=3), Crc32cCodec())


class StoreError(Exception):
    """A store that cannot be used as asked (its message says why)."""


@dataclass(frozen=True)
class Column:
    """One array of a result group: dtype, fill value, extra trailing dimension if any."""

    dtype: str
    fill: object


#: The per-entry results of a planning call (raw: per instance; scores: per entry).
RESULT_COLUMNS = {
    "score": Column("float64", np.nan),  # -(path length); NaN when infeasible
    "length": Column("float64", np.nan),
    "feasible": Column("bool", False),
    "time": Column("float64", np.nan),  # seconds (the only machine-dependent value)
    "status": Column("int8", -1),  # pipeline.planning.Status; -1 = not computed
    "checks": Column("int64", 0),
    "step": Column("int8", -1),  # index into the domain's steps of the one that failed; -1: none
}


def block_region(block: tuple[int, ...], chunks: tuple[int, ...]) -> tuple[slice, ...]:
    """The index region of chunk ``block`` (clipped by numpy at the array's edge)."""
    return tuple(slice(b * c, (b + 1) * c) for b, c in zip(block, chunks, strict=True))


def now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def default_path(domain: str, planner: str, seed: int) -> Path:
    return Path.cwd() / "data" / f"{domain}-{planner}-seed{seed}.zarr"


def versions() -> dict[str, str]:
    out = {}
    for dist in ("box-planning", "numpy", "scipy", "zarr", "dask", "distributed", "ompl",
                 "pybullet", "hydra-core"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def git_revision() -> str | None:
    try:
        res = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(__file__).parent,
                             capture_output=True, text=True, timeout=5, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return res.stdout.strip() or None


class StoreLock:
    """An exclusive lock on a store for one run (``flock``: released by the kernel when the
    holder dies, so a killed run never keeps it; unlike POSIX record locks it is not
    dropped when the same process closes another descriptor of the file).  The lock file
    sits next to the store (``<store>.lock``): inside, Zarr would warn about a foreign
    object."""

    def __init__(self, path: Path):
        path = Path(path)
        self.path = path.with_name(path.name + LOCK_SUFFIX)
        self._fd: int | None = None

    def acquire(self) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.read(fd, 4096).decode(errors="replace").strip() or "another process"
            os.close(fd)
            raise StoreError(f"store {self.path.with_suffix('')} is in use by a running pipeline "
                             f"({holder}); wait for it or stop it first") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()} on {socket.gethostname()} since {now()}".encode())
        self._fd = fd

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing drops the lock
            self._fd = None

    def held_by_other(self) -> str | None:
        """Who holds the lock, or None when nobody does (does not keep the lock)."""
        if not self.path.exists():
            return None
        fd = os.open(self.path, os.O_RDWR)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return os.read(fd, 4096).decode(errors="replace").strip() or "another process"
        finally:
            os.close(fd)
        return None

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()


def _is_ours(path: Path) -> bool:
    meta = path / "zarr.json"
    try:
        attrs = json.loads(meta.read_text()).get("attributes", {})
    except (OSError, ValueError):
        return False
    return attrs.get("format") == FORMAT


def check_is_ours(path: Path) -> None:
    path = Path(path)
    if not path.exists():
        raise StoreError(f"no store at {path}")
    if not path.is_dir() or not _is_ours(path):
        raise StoreError(f"{path} is not a score store made by this pipeline; left untouched")


class ScoreStore:
    """A store on disk; open it with :meth:`open` (read) or :meth:`prepare` (a run)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        self.root = zarr.open_group(self.path, mode="r+", use_consolidated=False)

    # -- opening ---------------------------------------------------------------------------
    @classmethod
    def open(cls, path) -> ScoreStore:
        """An existing store of ours (for status, evaluation, export)."""
        check_is_ours(Path(path))
        return cls(path)

    @classmethod
    def prepare(cls, path, identity: dict, config: dict, overwrite: bool) -> ScoreStore:
        """Create the store, or check that the existing one was made with ``identity``.

        The caller holds the :class:`StoreLock`.  A store with a different identity is
        refused with the differing keys named, or replaced when ``overwrite``; anything
        that is not a store of ours is refused and never modified.
        """
        from pipeline.configs import config_hash, differing_keys

        path = Path(path)
        if path.exists() and any(path.iterdir()):
            check_is_ours(path)
            store = cls(path)
            stored = store.attrs.get("identity")
            if stored == identity:
                return store
            if not overwrite:
                keys = differing_keys(stored or {}, identity)
                raise StoreError(
                    f"store {path} was made with a different config (differing keys: "
                    f"{', '.join(keys)}); use another store.path, or store.mode=overwrite "
                    "to replace it")
            shutil.rmtree(path)
        path.mkdir(parents=True, exist_ok=True)
        root = zarr.open_group(path, mode="a", use_consolidated=False)
        root.attrs.update({
            "format": FORMAT, "layout_version": LAYOUT_VERSION, "identity": identity,
            "config_hash": config_hash(identity), "config": config, "versions": versions(),
            "git_revision": git_revision(), "created": now(), "stages": {},
        })
        return cls(path)

    # -- attributes and stages -------------------------------------------------------------
    @property
    def attrs(self) -> dict:
        return dict(self.root.attrs)

    def stage_info(self, stage: str) -> dict | None:
        return self.attrs.get("stages", {}).get(stage)

    def mark_finished(self, stage: str, **info) -> None:
        stages = dict(self.attrs.get("stages", {}))
        stages[stage] = {"finished": now(), **info}
        self.root.attrs["stages"] = stages

    def forget_stage(self, stage: str) -> None:
        stages = dict(self.attrs.get("stages", {}))
        if stages.pop(stage, None) is not None:
            self.root.attrs["stages"] = stages

    # -- arrays ----------------------------------------------------------------------------
    def has(self, key: str) -> bool:
        return (self.path / key / "zarr.json").exists()

    def array(self, key: str, mode: str = "r") -> zarr.Array:
        return zarr.open_array(self.path / key, mode=mode)

    def create(self, key: str, shape, chunks, dtype, fill, dims, **attrs) -> zarr.Array:
        """A new array at ``key`` (replacing any left by an interrupted run)."""
        group, name = key.rsplit("/", 1)
        parent = self.root.require_group(group)
        arr = parent.create_array(name, shape=tuple(shape), chunks=tuple(chunks), dtype=dtype,
                                  fill_value=fill, dimension_names=tuple(dims),
                                  compressors=CODECS, overwrite=True)
        if attrs:
            arr.attrs.update(attrs)
        return arr

    def create_results(self, group: str, shape, chunks, dims, steps=()) -> None:
        """The per-entry result arrays of ``group`` plus its ``done`` mask; ``steps``: the
        domain's planning steps, which the ``step`` array indexes."""
        for name, col in RESULT_COLUMNS.items():
            extra = {}
            if name == "status":
                extra = {"flag_values": [s.value for s in Status],
                         "flag_meanings": " ".join(Status.names()),
                         "not_computed": -1}
            elif name == "step":
                extra = {"flag_values": list(range(len(steps))),
                         "flag_meanings": " ".join(steps), "none": -1}
            self.create(f"{group}/{name}", shape, chunks, col.dtype, col.fill, dims, **extra)
        self.create(f"{group}/done", shape, chunks, "bool", False, dims,
                    description="entries whose block finished (written by the coordinator)")

    def done(self, group: str) -> np.ndarray:
        return self.array(f"{group}/done")[...]

    def blocks(self, group: str) -> tuple[list[tuple[int, ...]], list[tuple[int, ...]]]:
        """(finished, pending) chunk indices of ``group`` according to its ``done`` mask."""
        mask = self.array(f"{group}/done")
        done = mask[...]
        finished, pending = [], []
        for block in np.ndindex(*mask.cdata_shape):
            (finished if done[block_region(block, mask.chunks)].all() else pending).append(block)
        return finished, pending

    def set_done(self, group: str, region: tuple[slice, ...], value: bool = True) -> None:
        self.array(f"{group}/done", mode="r+")[region] = value

    def corrupted_blocks(self, group: str, names, blocks) -> list[tuple[int, ...]]:
        """Blocks (chunk indices) among ``blocks`` whose chunk in any of ``names`` fails to
        decode (checksum mismatch, truncated or garbage data)."""
        bad = []
        arrays = [self.array(f"{group}/{n}") for n in names]
        for block in blocks:
            for arr in arrays:
                try:
                    arr.blocks[block]
                except Exception:  # noqa: BLE001 (any decoding failure means corrupt)
                    bad.append(tuple(block))
                    break
        return bad

    def consolidate(self) -> None:
        """Consolidated metadata for readers (xarray); only between runs' stages."""
        with warnings.catch_warnings():  # "not part of the v3 spec yet": known, intended
            warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
            zarr.consolidate_metadata(self.path)
