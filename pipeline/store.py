"""The Zarr v3 score store: layout, identity checks, block writes and integrity checks.

Layout (a contract: users open it with ``xarray.open_zarr(path, group=...)`` or
``xarray.open_datatree(path, engine="zarr")``; docs/store.md describes it for them)::

    /                 attrs: format, layout_version, identity, config_hash, config,
                             versions, git_revision, created, stages, environments
    instances/        seed (instance), spec (instance; JSON text); coordinate instance
    raw/              score length feasible time status checks step tries environment
                      (instance), constraint (instance, feature), done (instance);
                      coordinates instance, instance_seed (instance), feature,
                      feature_units (feature)
    constraints/      theta (constraint, feature), source_instance (constraint);
                      coordinates constraint, feature, feature_units
    scores/           score length feasible time status checks step environment done
                      (instance, constraint); coordinates instance, instance_seed
                      (instance), constraint, constraint_source (constraint)
    evaluation/       order (selector, instance, step), first_feasible_step,
                      first_feasible_time (selector, instance), best_score (selector,
                      instance, time), eligible, optimal_score (instance); coordinates
                      selector, instance, step, time (pipeline/evaluation_store.py)
    integrity/        per block group a table of chunk digests (pipeline/integrity.py)

Every dimension has an index coordinate (``instance`` and ``constraint`` count from 0);
physical quantities carry CF ``units`` and ``long_name`` (times in "seconds", which xarray
leaves as float seconds unless opened with ``decode_timedelta=True``); ``status`` and
``step`` are codes with CF ``flag_values``/``flag_meanings`` that
:func:`pipeline.dataset.with_names` turns into names.

Who writes what (docs/architecture.md, "The store"): workers compute and return arrays;
only the coordinating process writes the store (arrays, ``done`` masks, integrity records,
attributes).  A block is written in the order data chunks, integrity row, ``done``: a run
killed in between leaves a block that is simply computed again.  Every chunk is written
even when it holds only fill values, carries a CRC32C checksum, and has its values' digest
recorded.  ``environment`` holds, for every entry of a block, the index in the root
attribute ``environments`` of the environment (CPU, libraries, source) of the worker that
computed the block (``pipeline/environment.py``; -1: computed before layout 3).
"""

from __future__ import annotations

import datetime as _dt
import errno
import json
import subprocess
import warnings
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import NamedTuple

import numpy as np
import zarr
from zarr.codecs import Crc32cCodec, ZstdCodec

from pipeline import integrity
from pipeline.errors import LockError, StoreDamaged, StoreError  # noqa: F401 (re-exported)
from pipeline.integrity import BlockLayout, Damage, digest
from pipeline.location import Location, locate
from pipeline.locking import LOCK_SUFFIX, StoreLock  # noqa: F401 (re-exported)
from pipeline.planning import Status

FORMAT = "box-planning-score-store"
#: 1: the first layout; 2: integrity tables, coordinates, every chunk written; 3: the
#: environment that computed each block (``environment`` arrays, ``environments`` table);
#: 4: a dataset: index coordinates, units and names, the evaluation along ``selector``.
LAYOUT_VERSION = 4
CODECS = (ZstdCodec(level=3), Crc32cCodec())
WRITE_CONFIG = {"write_empty_chunks": True}


@dataclass(frozen=True)
class Column:
    """One array of a result group: dtype, fill value."""

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

#: Array keys of the layout above; other modules use these (or ``result_key``), never literals.
INSTANCE_SEED = "instances/seed"
INSTANCE_SPEC = "instances/spec"
RAW_CONSTRAINT = "raw/constraint"
THETA = "constraints/theta"
SOURCE_INSTANCE = "constraints/source_instance"
#: The per-entry index into the root attribute ENVIRONMENTS (raw and scores).
ENVIRONMENT = "environment"
ENVIRONMENTS = "environments"
UNKNOWN_ENVIRONMENT = -1


def result_key(group: str, name: str) -> str:
    """The key of result array ``name`` (a RESULT_COLUMNS name or ``done``) of ``group``
    (``raw`` or ``scores``)."""
    return f"{group}/{name}"


def domain_spec_of(config: dict) -> dict:
    """The {"name", "config", "planner"} workers receive, from a plain run config (as a run
    resolves it, and as the store's ``config`` attribute holds it)."""
    domain = dict(config["domain"])
    return {"name": domain.pop("name"), "config": domain, "planner": config["planner"]}


#: The block axes of each block group.
BLOCK_DIMS = {"instances": ("instance",), "raw": ("instance",),
              "constraints": ("constraint",), "scores": ("instance", "constraint")}


class ScoreMatrix(NamedTuple):
    """A store's score matrix as box_core takes it."""

    scores: np.ndarray  # (n, m): -(path length) where feasible, 0 elsewhere
    feasible: np.ndarray  # (n, m) bool
    times: np.ndarray  # (n, m) seconds
    theta: np.ndarray  # (m, p): the constraints' features


def path_scores(feasible, length) -> np.ndarray:
    """Scores as box_core takes them: -(path length) where feasible, 0 elsewhere (the
    failure value replaces those entries at analysis time)."""
    return np.where(feasible, -np.nan_to_num(length, nan=0.0), 0.0)


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


def write_error(location, exc: OSError) -> StoreError:
    """A one-line StoreError for an OSError met while writing the store."""
    if exc.errno == errno.ENOSPC:
        why = "no space left on the device"
    elif exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM) or isinstance(exc,
                                                                             PermissionError):
        why = "the store is read-only (permission denied)"
    else:
        why = (exc.strerror or str(exc)).splitlines()[0]
    return StoreError(f"cannot write store {location}: {why}; finished blocks are kept: fix "
                      "it and re-run the same command to resume")


def _root_attrs(location: Location) -> dict:
    """The root attributes of the Zarr group at ``location``: a storage failure raises a
    StoreError, a missing or unreadable root document what Zarr raises."""
    from pipeline.storage_errors import translated

    with translated(location):
        return dict(zarr.open_group(store=location.zarr_store(read_only=True), mode="r",
                                    use_consolidated=False).attrs)


def check_is_ours(path) -> None:
    """StoreError (one line) unless ``path`` holds a store of ours whose every ``zarr.json``
    can be read (:func:`pipeline.storage_errors.check_metadata`).  A root document that
    cannot be read, or says another format, beside the groups of a score store is named
    as such: the store is ours, damaged (or not ours, but it is left untouched either way)."""
    from pipeline.storage_errors import check_metadata, has_nodes, metadata_error

    location = locate(path)
    if location.local is not None and location.local.exists() and not location.local.is_dir():
        raise StoreError(f"{location} is not a score store made by this pipeline; "
                         "left untouched")
    if not location.exists():
        raise StoreError(f"no store at {location}")
    try:
        attrs, unreadable = _root_attrs(location), None
    except StoreError:
        raise
    except Exception as exc:  # noqa: BLE001 (Zarr raises many types for a bad root)
        attrs, unreadable = {}, exc
    if attrs.get("format") != FORMAT:
        if has_nodes(location, [*BLOCK_DIMS, integrity.GROUP]):
            if unreadable is not None:
                raise metadata_error(location.path / "zarr.json", unreadable)
            raise StoreError(f"{location}: its root attribute format is "
                             f"{attrs.get('format')!r}, not {FORMAT!r}, though it holds the "
                             "groups of a score store; left untouched")
        raise StoreError(f"{location} is not a score store made by this pipeline; "
                         "left untouched")
    check_metadata(location)


class ScoreStore:
    """A store; open it with :meth:`open` (read) or :meth:`prepare` (a run)."""

    def __init__(self, location, read_only: bool = False):
        self.location = locate(location)
        self.path = self.location.path
        self.read_only = read_only
        self.zstore = self.location.zarr_store(read_only=read_only)
        self.root = zarr.open_group(store=self.zstore, mode="r" if read_only else "r+",
                                    use_consolidated=False)
        self._arrays: dict[str, zarr.Array] = {}
        #: called before every write (blocks, records, attributes, arrays, documents): the
        #: run's lock check (fencing)
        self.fence = lambda: None
        #: only metadata is written (:meth:`in_memory`, the layout a store must have)
        self.metadata_only = False

    @classmethod
    def in_memory(cls) -> ScoreStore:
        """An empty store in memory that records arrays' metadata but no values: what
        :mod:`pipeline.layout` creates to know the documents a store must hold."""
        self = cls.__new__(cls)
        self.location, self.path, self.read_only = None, "(the expected layout)", False
        self.zstore = zarr.storage.MemoryStore()
        self.root = zarr.open_group(store=self.zstore, mode="w", use_consolidated=False)
        self._arrays, self.fence, self.metadata_only = {}, lambda: None, True
        return self

    # -- opening ---------------------------------------------------------------------------
    @classmethod
    def open(cls, path, read_only: bool = True, checked: bool = True) -> ScoreStore:
        """An existing store of ours (for evaluation, export, reports).  ``checked``: its
        metadata documents are checked first (StoreDamaged naming each difference), so a
        reader never allocates what a damaged document claims (status checks them itself)."""
        check_is_ours(path)
        store = cls(path, read_only=read_only)
        if checked:
            from pipeline import metadata

            metadata.refuse(store)
        return store

    @classmethod
    def prepare(cls, path, identity: dict, config: dict, overwrite: bool) -> ScoreStore:
        """Create the store, or check that the existing one was made with ``identity``.

        The caller holds the :class:`StoreLock`.  A store with a different identity is
        refused with the differing keys named, or replaced when ``overwrite``; anything
        that is not a store of ours is refused and never modified.
        """
        from pipeline.configs import config_hash, differing_keys

        location = locate(path)
        if not location.is_empty():
            check_is_ours(location)
            store = cls(location)
            stored = store.attrs.get("identity")
            if stored == identity:
                return store  # the caller migrates an older layout (pipeline/migrate.py)
            if not overwrite:
                keys = differing_keys(stored or {}, identity)
                raise StoreError(
                    f"store {location} was made with a different config (differing keys: "
                    f"{', '.join(keys)}); use another store.path, or store.mode=overwrite "
                    "to replace it")
        root = zarr.open_group(store=location.zarr_store(read_only=False), mode="w",
                               use_consolidated=False)
        root.require_group(integrity.GROUP)
        store = cls(location)
        store.set_attrs(
            format=FORMAT, layout_version=LAYOUT_VERSION, identity=identity,
            config_hash=config_hash(identity), config=config, versions=versions(),
            git_revision=git_revision(), created=now(), stages={})
        return store

    # -- attributes and stages -------------------------------------------------------------
    @property
    def attrs(self) -> dict:
        return dict(self.root.attrs)

    def set_attrs(self, **values) -> None:
        """Write root attributes, then their record (:func:`pipeline.metadata.root_record`):
        every root attribute the coordinator writes goes through here."""
        self.fence()
        self.root.attrs.update(values)
        self.record_root()

    def record_root(self) -> None:
        """Record a digest of each root attribute in the ``integrity`` group."""
        from pipeline.metadata import root_record

        self.root.require_group(integrity.GROUP).attrs["root"] = root_record(self.attrs)

    @property
    def layout_version(self) -> int:
        return int(self.attrs.get("layout_version", 1))

    def stage_info(self, stage: str) -> dict | None:
        return self.attrs.get("stages", {}).get(stage)

    def mark_finished(self, stage: str, **info) -> None:
        self.fence()
        stages = dict(self.attrs.get("stages", {}))
        stages[stage] = {"finished": now(), **info}
        self.set_attrs(stages=stages)

    def update_stage(self, stage: str, **info) -> None:
        """Add ``info`` to a finished stage's record."""
        stages = dict(self.attrs.get("stages", {}))
        stages[stage] = {**stages[stage], **info}
        self.set_attrs(stages=stages)

    def forget_stage(self, stage: str) -> None:
        stages = dict(self.attrs.get("stages", {}))
        if stages.pop(stage, None) is not None:
            self.set_attrs(stages=stages)

    # -- arrays ----------------------------------------------------------------------------
    def has(self, key: str) -> bool:
        try:
            return isinstance(self.root[key], zarr.Array)
        except KeyError:
            return False

    def has_group(self, key: str) -> bool:
        try:
            return isinstance(self.root[key], zarr.Group)
        except KeyError:
            return False

    def array(self, key: str, mode: str = "r") -> zarr.Array:  # noqa: ARG002 (kept for callers)
        """The array at ``key`` (opened once per store object; writes keep empty chunks)."""
        arr = self._arrays.get(key)
        if arr is None:
            arr = self.root[key]
            if not isinstance(arr, zarr.Array):
                raise KeyError(key)
            if not self.read_only:
                arr = arr.with_config(WRITE_CONFIG)
            self._arrays[key] = arr
        return arr

    def create(self, key: str, shape, chunks, dtype, fill, dims, **attrs) -> zarr.Array:
        """A new array at ``key`` (replacing any left by an interrupted run)."""
        self.fence()
        group, name = key.rsplit("/", 1)
        parent = self.root.require_group(group)
        arr = parent.create_array(name, shape=tuple(shape), chunks=tuple(chunks), dtype=dtype,
                                  fill_value=fill, dimension_names=tuple(dims),
                                  compressors=CODECS, overwrite=True, config=WRITE_CONFIG)
        if attrs:
            arr.attrs.update(attrs)
        self._arrays[key] = arr
        return arr

    def remove(self, key: str) -> None:
        """Delete a group or array and everything under it (any store kind)."""
        self.fence()
        if key in self.root:
            del self.root[key]
        self._arrays = {k: v for k, v in self._arrays.items()
                        if k != key and not k.startswith(key + "/")}

    def create_results(self, group: str, shape, chunks, dims, domain, extra=(),
                       coords: dict | None = None) -> None:
        """The per-entry result arrays of ``group``, its ``done`` mask, coordinates and
        integrity table.  ``domain``: the store's domain (its planning steps, which ``step``
        indexes, and its units); ``extra``: (name, shape, chunks, dtype, fill, dims, attrs)
        of further result arrays; ``coords``: name -> (dims, values, attrs) of coordinate
        arrays."""
        coords = coords or {}
        names = []
        described = result_attrs(domain)
        for name, col in RESULT_COLUMNS.items():
            self.create(f"{group}/{name}", shape, chunks, col.dtype, col.fill, dims,
                        **described[name])
            names.append(name)
        for name, shp, chk, dtype, fill, dms, attrs in extra:
            self.create(f"{group}/{name}", shp, chk, dtype, fill, dms, **attrs)
            names.append(name)
        self.create_environment(group, shape, chunks, dims)
        names.append(ENVIRONMENT)
        self.create(f"{group}/done", shape, chunks, "bool", False, dims,
                    description="entries whose block finished (written by the coordinator)")
        names.append("done")
        self.write_coords(group, coords, names)
        self.create_table(group, [*names, *coords])

    def create_environment(self, group: str, shape, chunks, dims) -> zarr.Array:
        """``group``'s environment array, every chunk written as -1 (not recorded)."""
        arr = self.create(
            result_key(group, ENVIRONMENT), shape, chunks, "int16", UNKNOWN_ENVIRONMENT, dims,
            description="index into the root attribute 'environments' of the environment "
                        "that computed the entry's block; -1: not recorded (computed before "
                        "layout 3)")
        if not self.metadata_only:
            arr[...] = UNKNOWN_ENVIRONMENT
        return arr

    # -- environments ------------------------------------------------------------------------
    def environments(self) -> list[dict]:
        """The table of environments that computed blocks (``pipeline/environment.py``)."""
        return list(self.attrs.get(ENVIRONMENTS) or [])

    def environment_index(self, record: dict) -> int:
        """The index of ``record`` in the table, added (before any block refers to it) when
        it is new."""
        table = self.environments()
        if record in table:
            return table.index(record)
        self.set_attrs(**{ENVIRONMENTS: [*table, record]})
        return len(table)

    def environments_used(self, group: str) -> dict[int, int]:
        """Entries of ``group`` whose block is done, per environment index (-1: not
        recorded); {} before layout 3."""
        if not self.has(result_key(group, ENVIRONMENT)):
            return {}
        values = self.array(result_key(group, ENVIRONMENT))[...][self.done(group)]
        found, counts = np.unique(values, return_counts=True)
        return {int(k): int(c) for k, c in zip(found, counts, strict=True)}

    def write_coords(self, group: str, coords: dict, data_names) -> None:
        """Coordinate arrays of ``group`` (chunked like the block axes), named in each data
        array's ``coordinates`` attribute so that xarray makes them coordinates."""
        for name, (dims, values, attrs) in coords.items():
            values = np.asarray(values)
            chunks = (self._block_size(group, dims[0], len(values)),)  # 1-D coordinates
            dtype = str if values.dtype.kind in "OUT" else values.dtype
            fill = "" if dtype is str else (np.nan if values.dtype.kind == "f" else 0)
            arr = self.create(f"{group}/{name}", values.shape, chunks, dtype, fill, dims,
                              **attrs)
            if not self.metadata_only:
                arr[...] = values
        listed = " ".join(n for n in coords if n not in dims_of_coords(coords))
        if listed:
            for name in data_names:
                self.array(f"{group}/{name}").attrs["coordinates"] = listed

    def _block_size(self, group: str, dim: str, length: int) -> int:
        if dim in BLOCK_DIMS.get(group, ()):
            ref = self._reference_array(group)
            return ref.chunks[list(ref.metadata.dimension_names).index(dim)]
        return max(length, 1)

    def _reference_array(self, group: str) -> zarr.Array:
        for name in ("done", "theta", "seed"):
            if self.has(f"{group}/{name}"):
                return self.array(f"{group}/{name}")
        raise KeyError(f"{group} has no array to take block sizes from")

    # -- blocks and integrity ------------------------------------------------------------
    def layout(self, group: str) -> BlockLayout:
        table = self.array(f"{integrity.GROUP}/{group}")
        return BlockLayout(group, tuple(table.attrs["block_dims"]),
                           tuple(table.attrs["arrays"]))

    def has_table(self, group: str) -> bool:
        return self.has(f"{integrity.GROUP}/{group}")

    def create_table(self, group: str, names) -> None:
        """An empty integrity table for the block group ``group`` covering ``names``."""
        dims = BLOCK_DIMS[group]
        ref = self._reference_array(group)
        ref_dims = list(ref.metadata.dimension_names)
        grid = tuple(ref.cdata_shape[ref_dims.index(d)] for d in dims)
        self.create(f"{integrity.GROUP}/{group}", (*grid, len(names)),
                    (*(1,) * len(grid), len(names)), "uint64", 0,
                    (*(f"{d}_block" for d in dims), f"{group}_array"),
                    block_dims=list(dims), arrays=list(names),
                    description="digest of each array's chunk per block (0: not recorded)")

    def grid(self, group: str) -> tuple[int, ...]:
        return self.array(f"{integrity.GROUP}/{group}").shape[:-1]

    def _chunk(self, layout: BlockLayout, name: str, block) -> tuple[zarr.Array, tuple]:
        arr = self.array(f"{layout.group}/{name}")
        return arr, layout.chunk_of(arr.metadata.dimension_names, block)

    def write_block(self, group: str, block, arrays: dict[str, np.ndarray]) -> None:
        """Write one finished block: data chunks, then its integrity row, then ``done``."""
        self.fence()
        layout = self.layout(group)
        row = np.zeros(len(layout.names), dtype="uint64")
        done_region = None
        for k, name in enumerate(layout.names):
            arr, chunk = self._chunk(layout, name, block)
            region = block_region(chunk, arr.chunks)
            if name == "done":
                done_region = region
                values = np.ones(_shape(region, arr.shape), dtype=bool)
            elif name in arrays:
                values = np.asarray(arrays[name], dtype=arr.dtype)
                arr[region] = values
            else:  # a coordinate, written at creation
                values = arr.blocks[chunk]
            row[k] = digest(values)
        self.array(f"{integrity.GROUP}/{group}")[tuple(block)] = row
        if done_region is not None:
            self.array(f"{group}/done")[done_region] = True

    def record_blocks(self, group: str, blocks=None) -> None:
        """Record the digests of ``blocks`` (all) as they are now (for groups written
        whole by the coordinator, right after writing them)."""
        layout = self.layout(group)
        table = self.array(f"{integrity.GROUP}/{group}")
        rows = np.zeros(table.shape, dtype="uint64") if blocks is None else table[...]
        for block in (np.ndindex(*table.shape[:-1]) if blocks is None else blocks):
            for k, name in enumerate(layout.names):
                arr, chunk = self._chunk(layout, name, block)
                rows[tuple(block) + (k,)] = digest(arr.blocks[chunk])
        table[...] = rows

    def finished_blocks(self, group: str) -> list[tuple[int, ...]]:
        """Blocks whose integrity row is recorded (readable and complete)."""
        table = self.array(f"{integrity.GROUP}/{group}")
        out = []
        for block in np.ndindex(*table.shape[:-1]):
            try:
                row = table.blocks[(*block, 0)]
            except Exception:  # noqa: BLE001 (an unreadable row: not finished)
                continue
            if np.all(row != integrity.NOT_RECORDED):
                out.append(block)
        return out

    def verify(self, group: str, blocks=None, expect_all: bool = False) -> Damage:
        """Damage in the recorded ``blocks`` (default: all) of ``group``.  A block without a
        readable record counts as damage of the record when the block should have one:
        its ``done`` mask says so, or ``expect_all`` (a finished group written whole)."""
        damage = Damage()
        if not self.has_table(group):
            return self._verify_decoding(group)
        table_key = f"{integrity.GROUP}/{group}"
        table = self.array(table_key)
        layout = self.layout(group)
        gone = set(self.missing_arrays(group))
        written = {name: self.chunk_keys(f"{group}/{name}") for name in layout.names
                   if name not in gone}
        done = self._done_blocks(group) if not expect_all else None
        if blocks is None:
            blocks = list(np.ndindex(*table.shape[:-1]))
        for block in blocks:
            expected = expect_all or (done is not None and block in done)
            try:
                row = table.blocks[(*block, 0)].reshape(-1)
            except Exception:  # noqa: BLE001
                damage.add("corrupted", table_key, block)
                continue
            if not np.all(row != integrity.NOT_RECORDED):
                if expected:
                    damage.add("missing", table_key, block)
                continue  # not finished: nothing to verify
            for k, name in enumerate(layout.names):
                key = f"{group}/{name}"
                if name in gone:
                    damage.add("missing", key, block)
                    continue
                arr, chunk = self._chunk(layout, name, block)
                if arr.metadata.encode_chunk_key(chunk) not in written[name]:
                    damage.add("missing", key, block)
                    continue
                try:
                    values = arr.blocks[chunk]
                except Exception:  # noqa: BLE001 (any decoding failure means corrupt)
                    damage.add("corrupted", key, block)
                    continue
                if digest(values) != int(row[k]):
                    damage.add("corrupted", key, block)
        return damage

    def missing_arrays(self, group: str) -> list[str]:
        """Arrays that the integrity table of ``group`` covers but that are gone."""
        return [name for name in self.layout(group).names if not self.has(f"{group}/{name}")]

    def _done_blocks(self, group: str) -> set:
        """Blocks whose ``done`` mask is all set (that mask's own damage aside)."""
        if not self.has(f"{group}/done"):
            return set(np.ndindex(*self.grid(group)))  # the mask is gone: all were done
        mask = self.array(f"{group}/done")
        out = set()
        for block in np.ndindex(*mask.cdata_shape):
            try:
                if mask.blocks[block].all():
                    out.add(block)
            except Exception:  # noqa: BLE001 (found as damage of done itself)
                continue
        return out

    def _verify_decoding(self, group: str) -> Damage:
        """Layout 1 (no integrity table): chunks of finished blocks must decode."""
        damage = Damage()
        if not self.has_group(group):
            return damage
        g = self.root[group]
        for name, arr in g.arrays():
            for chunk in np.ndindex(*arr.cdata_shape):
                try:
                    arr.blocks[chunk]
                except Exception:  # noqa: BLE001
                    damage.add("corrupted", f"{group}/{name}", chunk)
        return damage

    def chunk_keys(self, key: str) -> set[str]:
        """Chunk keys (relative to the array) that exist in the store."""
        from zarr.core.sync import sync

        prefix = f"{key}/"

        async def collect():
            return {k[len(prefix):] async for k in self.zstore.list_prefix(prefix)}

        return sync(collect())

    def array_digests(self, keys) -> dict[str, str]:
        """A digest per array (of its recorded chunk digests, or of its values when it is
        outside any block group): what a stage records about its inputs."""
        out = {}
        for key in keys:
            group, name = key.split("/", 1)
            if self.has_table(group) and name in self.layout(group).names:
                k = self.layout(group).names.index(name)
                out[key] = integrity.combine(
                    self.array(f"{integrity.GROUP}/{group}")[..., k].reshape(-1))
            else:
                out[key] = f"{digest(self.array(key)[...]):016x}"
        return out

    def verify_whole(self, recorded: dict[str, str]) -> Damage:
        """Damage among arrays recorded whole (``key -> hex digest``): missing arrays,
        chunks that do not decode, values that differ."""
        damage = Damage()
        for key, expected in recorded.items():
            if not self.has(key):
                damage.add("missing", key, ())
                continue
            arr = self.array(key)
            written = self.chunk_keys(key)
            if any(arr.metadata.encode_chunk_key(c) not in written
                   for c in np.ndindex(*arr.cdata_shape)):
                damage.add("missing", key, ())
                continue
            try:
                values = arr[...]
            except Exception:  # noqa: BLE001
                damage.add("corrupted", key, ())
                continue
            if f"{digest(values):016x}" != expected:
                damage.add("corrupted", key, ())
        return damage

    def arrays_under(self, group: str) -> list[str]:
        """Keys of every array under ``group`` (nested groups included)."""
        if not self.has_group(group):
            return []
        return sorted(f"{group}/{path}" for path, _ in self.root[group].members(max_depth=None)
                      if isinstance(self.root[f"{group}/{path}"], zarr.Array))

    # -- the done masks --------------------------------------------------------------------
    def domain_spec(self) -> dict:
        """The {"name", "config", "planner"} the store was made with (what workers receive)."""
        config = self.attrs.get("config") or {}
        if "name" not in (config.get("domain") or {}) or "planner" not in config:
            raise StoreError(f"{self.path}: the store's attributes hold no domain config "
                             "(damaged store?)")
        return domain_spec_of(config)

    def instance_seeds(self) -> np.ndarray:
        return self.array(INSTANCE_SEED)[...]

    def instance_specs(self) -> np.ndarray:
        """The instances' specs (JSON text)."""
        return self.array(INSTANCE_SPEC)[...]

    def has_results(self, group: str) -> bool:
        """Whether result group ``group`` (``raw`` or ``scores``) has been created."""
        return self.has(result_key(group, "done"))

    def source_instances(self) -> np.ndarray:
        """(m,) the instance whose raw solution gave each constraint; -1: fixed."""
        return self.array(SOURCE_INSTANCE)[...]

    def theta(self) -> np.ndarray:
        """(m, p) the constraints' features."""
        return self.array(THETA)[...]

    def score_matrix(self, rows=None) -> ScoreMatrix:
        """The score matrix as box_core wants it.  With ``rows`` (indices or a mask), only
        those rows, unchecked (a partial store's complete rows); without, all rows, and a
        StoreError when an entry is missing or a feasible entry has no path length."""
        def read(key):
            values = self.array(key)[...]
            return values if rows is None else values[rows]

        if rows is None:
            self.require_done("scores")
        feasible, length, times = (read(result_key("scores", name))
                                   for name in ("feasible", "length", "time"))
        if rows is None and np.isnan(times).any():
            raise StoreError(f"{self.path}: {result_key('scores', 'time')} has missing "
                             "entries; is stage scores complete?")
        scores = path_scores(feasible, length)
        if rows is None and np.isnan(length[feasible]).any():
            raise StoreError(f"{self.path}: a feasible entry has no path length (damaged "
                             "store?)")
        return ScoreMatrix(scores, feasible, times, self.theta())

    def done(self, group: str) -> np.ndarray:
        return self.array(f"{group}/done")[...]

    def require_done(self, group: str) -> None:
        """A StoreError naming the unfinished blocks of ``group`` unless every entry's block
        finished: readers never take a missing entry for an infeasible one."""
        finished, pending = self.blocks(group)
        if pending:
            mask = self.done(group)
            shown = ", ".join(str(b) for b in pending[:3]) + (" …" if len(pending) > 3 else "")
            raise StoreError(
                f"{self.path}: {group} has {int((~mask).sum())} of {mask.size} entries in "
                f"{len(pending)} unfinished block(s) ({shown}); finish it with "
                "python -m pipeline stage=generate")

    def blocks(self, group: str) -> tuple[list[tuple[int, ...]], list[tuple[int, ...]]]:
        """(finished, pending) chunk indices of ``group`` according to its ``done`` mask."""
        mask = self.array(f"{group}/done")
        done = mask[...]
        finished, pending = [], []
        for block in np.ndindex(*mask.cdata_shape):
            (finished if done[block_region(block, mask.chunks)].all() else pending).append(block)
        return finished, pending

    def set_done(self, group: str, region: tuple[slice, ...], value: bool = True) -> None:
        self.array(f"{group}/done")[region] = value

    def forget_blocks(self, group: str, blocks) -> None:
        """Mark ``blocks`` as not computed (integrity row cleared first, then ``done``)."""
        table = self.array(f"{integrity.GROUP}/{group}")
        chunks = self.array(f"{group}/done").chunks
        for block in blocks:
            table[tuple(block)] = 0
            self.set_done(group, block_region(block, chunks), False)

    # -- metadata documents ------------------------------------------------------------------
    def document(self, path: str) -> dict:
        """The parsed ``zarr.json`` of node ``path`` ("" for the root) as stored, without
        the consolidated copy of the others (KeyError when there is none, ValueError when
        it is not a JSON object)."""
        raw = self.read_bytes(_doc_key(path))
        if raw is None:
            raise KeyError(_doc_key(path))
        doc = json.loads(raw)
        if not isinstance(doc, dict):
            raise ValueError(f"{_doc_key(path)} holds no JSON object")
        doc.pop("consolidated_metadata", None)
        return doc

    def documents(self) -> dict[str, dict]:
        """Every node's parsed ``zarr.json`` by path (for the in-memory layout)."""
        from zarr.core.sync import sync

        async def keys():
            return [k async for k in self.zstore.list() if k.endswith("zarr.json")]

        return {k[:-len("zarr.json")].rstrip("/"): self.document(k[:-len("zarr.json")].rstrip("/"))
                for k in sync(keys())}

    def read_bytes(self, key: str) -> bytes | None:
        from zarr.core.buffer import default_buffer_prototype
        from zarr.core.sync import sync

        buf = sync(self.zstore.get(key, prototype=default_buffer_prototype()))
        return None if buf is None else buf.to_bytes()

    def write_document(self, path: str, doc: dict) -> None:
        """Replace node ``path``'s ``zarr.json`` with ``doc`` (the arrays opened before
        are forgotten: they would keep the old metadata)."""
        from zarr.core.buffer import default_buffer_prototype
        from zarr.core.sync import sync

        self.fence()
        data = json.dumps(doc, indent=2).encode()
        sync(self.zstore.set(_doc_key(path), default_buffer_prototype().buffer.from_bytes(data)))
        self._arrays.clear()
        self.root = zarr.open_group(store=self.zstore, mode="r" if self.read_only else "r+",
                                    use_consolidated=False)

    def consolidate(self) -> None:
        """Consolidated metadata for readers (xarray); only between runs' stages."""
        self.fence()
        with warnings.catch_warnings():  # "not part of the v3 spec yet": known, intended
            warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
            zarr.consolidate_metadata(self.zstore)


def _doc_key(path: str) -> str:
    return f"{path}/zarr.json" if path else "zarr.json"


def _shape(region: tuple[slice, ...], shape) -> tuple[int, ...]:
    return tuple(len(range(*s.indices(n))) for s, n in zip(region, shape, strict=True))


def flag_attrs(values, meanings, **special) -> dict:
    """CF flag attributes: ``flag_values`` and ``flag_meanings`` decode codes to names;
    ``special`` names the codes outside them (``not_computed=-1``)."""
    return {"flag_values": list(values), "flag_meanings": " ".join(meanings), **special}


#: CF units of times: xarray keeps them float seconds unless ``decode_timedelta=True``.
TIME_UNITS = "seconds"


def result_attrs(domain) -> dict[str, dict]:
    """CF attributes of each result array (RESULT_COLUMNS) of a store of ``domain``."""
    length = {"units": domain.length_units}
    return {
        "score": {"long_name": f"score: minus the {domain.length_name} (NaN: infeasible)",
                  **length},
        "length": {"long_name": domain.length_name, **length},
        "feasible": {"long_name": "a feasible plan was found"},
        "time": {"long_name": "planning time of the call", "units": TIME_UNITS},
        "status": {"long_name": "outcome of the planning call",
                   **flag_attrs([s.value for s in Status], Status.names(), not_computed=-1)},
        "checks": {"long_name": "collision checks used", "units": "1"},
        "step": {"long_name": "planning step that failed",
                 **flag_attrs(list(range(len(domain.steps))), domain.steps, none=-1)},
    }


def dims_of_coords(coords: dict) -> set[str]:
    """Coordinates named like their only dimension (xarray indexes them by themselves)."""
    return {name for name, (dims, _, _) in coords.items() if tuple(dims) == (name,)}


# -- coordinates (what xarray shows along each dimension) -----------------------------------
def index_coord(dim: str, n: int, long_name: str) -> dict:
    """The index coordinate of ``dim``: 0..n-1."""
    return {dim: ((dim,), np.arange(n, dtype="int64"), {"long_name": long_name})}


def instance_coord(seeds) -> dict:
    return {**index_coord("instance", len(seeds), "instance index"),
            "instance_seed": (("instance",), np.asarray(seeds, dtype="int64"),
                              {"long_name": "seed the instance was sampled from"})}


def feature_coord(domain) -> dict:
    """The names and units of θ's features, as the domain declares them."""
    features = domain.theta_features
    return {"feature": (("feature",), np.asarray([f.name for f in features], dtype=str),
                        {"long_name": "feature of a constraint θ"}),
            "feature_units": (("feature",), np.asarray([f.units for f in features], dtype=str),
                              {"long_name": "UDUNITS units of the feature"})}


def source_coord(sources) -> dict:
    return {**index_coord("constraint", len(sources), "constraint index"),
            "constraint_source": (("constraint",), np.asarray(sources, dtype="int64"),
                                  {"long_name": "instance whose raw solution gave the "
                                                "constraint; -1: a fixed set"})}
