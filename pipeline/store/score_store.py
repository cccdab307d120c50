"""The score store: :class:`ScoreStore` opens, creates and identifies a store, holds its
root attributes (stage records, environments table), and reaches its arrays and metadata
documents; its writers, integrity checks and readers are its parts in
:mod:`pipeline.store.blocks`, :mod:`pipeline.store.verification` and
:mod:`pipeline.store.readers`.  The layout itself is declared in :mod:`pipeline.store.layout`.

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
from importlib import metadata
from pathlib import Path

import numpy as np
import zarr

from pipeline.store.blocks import BlockWrites
from pipeline.store.documents_once import DocumentsReadOnce
from pipeline.store.errors import StoreError
from pipeline.store.layout import (
    BLOCK_DIMS,
    CODECS,
    ENVIRONMENT,
    ENVIRONMENTS,
    FORMAT,
    INTEGRITY,
    LAYOUT_VERSION,
    result_key,
)
from pipeline.store.location import Location, locate
from pipeline.store.readers import Readers
from pipeline.store.verification import Verification

WRITE_CONFIG = {"write_empty_chunks": True}


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


def _root_attrs(location: Location, zstore=None) -> dict:
    """The root attributes of the Zarr group at ``location`` (read through ``zstore`` when
    given): a storage failure raises a StoreError, a missing or unreadable root document
    what Zarr raises."""
    from pipeline.store.storage_errors import translated

    if zstore is None:
        zstore = location.zarr_store(read_only=True)
    with translated(location):
        return dict(zarr.open_group(store=zstore, mode="r", use_consolidated=False,
                                    zarr_format=3).attrs)


def check_is_ours(path, zstore=None) -> None:
    """StoreError (one line) unless ``path`` holds a store of ours whose every ``zarr.json``
    can be read (:func:`pipeline.store.storage_errors.check_metadata`).  A root document that
    cannot be read, or says another format, beside the groups of a score store is named
    as such: the store is ours, damaged (or not ours, but it is left untouched either way).
    ``zstore``: the Zarr store to read it through (a read-only :class:`DocumentsReadOnce`
    view then keeps the documents it checked for the store object that reads them next)."""
    from pipeline.store.storage_errors import check_metadata, has_nodes, metadata_error

    location = locate(path)
    if location.local is not None and location.local.exists() and not location.local.is_dir():
        raise StoreError(f"{location} is not a score store made by this pipeline; "
                         "left untouched")
    if not location.exists():
        raise StoreError(f"no store at {location}")
    try:
        attrs, unreadable = _root_attrs(location, zstore), None
    except StoreError:
        raise
    except Exception as exc:  # noqa: BLE001 (Zarr raises many types for a bad root)
        attrs, unreadable = {}, exc
    if attrs.get("format") != FORMAT:
        if has_nodes(location, [*BLOCK_DIMS, INTEGRITY]):
            if unreadable is not None:
                raise metadata_error(location.path / "zarr.json", unreadable)
            raise StoreError(f"{location}: its root attribute format is "
                             f"{attrs.get('format')!r}, not {FORMAT!r}, though it holds the "
                             "groups of a score store; left untouched")
        raise StoreError(f"{location} is not a score store made by this pipeline; "
                         "left untouched")
    check_metadata(location, zstore)


class ScoreStore(Readers, BlockWrites, Verification):
    """A store; open it with :meth:`open` (read) or :meth:`prepare` (a run)."""

    def __init__(self, location, read_only: bool = False,
                 zstore: DocumentsReadOnce | None = None):
        self.location = locate(location)
        self.path = self.location.path
        self.read_only = read_only
        # read-only: one consistent set of documents, one request each
        self.zstore = zstore if zstore is not None else DocumentsReadOnce(
            self.location.zarr_store(read_only=read_only), always=read_only)
        self.root = zarr.open_group(store=self.zstore, mode="r" if read_only else "r+",
                                    use_consolidated=False, zarr_format=3)
        self._arrays: dict[str, zarr.Array] = {}
        self._consolidated_at = self.zstore.document_changes
        #: called before every write (blocks, records, attributes, arrays, documents): the
        #: run's lock check (fencing)
        self.fence = lambda: None
        #: only metadata is written (:meth:`in_memory`, the layout a store must have)
        self.metadata_only = False

    @classmethod
    def in_memory(cls) -> ScoreStore:
        """An empty store in memory that records arrays' metadata but no values: what
        :mod:`pipeline.store.layout` creates to know the documents a store must hold."""
        self = cls.__new__(cls)
        self.location, self.path, self.read_only = None, "(the expected layout)", False
        self.zstore = DocumentsReadOnce(zarr.storage.MemoryStore())
        self.root = zarr.open_group(store=self.zstore, mode="w", use_consolidated=False)
        self._arrays, self.fence, self.metadata_only = {}, lambda: None, True
        self._consolidated_at = 0
        return self

    # -- opening ---------------------------------------------------------------------------
    @classmethod
    def open(cls, path, read_only: bool = True, checked: bool = True) -> ScoreStore:
        """An existing store of ours (for evaluation, export, reports).  ``checked``: its
        metadata documents are checked first (StoreDamaged naming each difference), so a
        reader never allocates what a damaged document claims (status checks them itself)."""
        if read_only:
            store = cls.checked(path)
        else:
            check_is_ours(path)
            store = cls(path, read_only=False)
        if checked:
            from pipeline.store import metadata

            metadata.refuse(store)
        return store

    @classmethod
    def checked(cls, path) -> ScoreStore:
        """The store at ``path`` opened read-only once :func:`check_is_ours` has passed,
        seeing the very documents that check read (each read once)."""
        location = locate(path)
        zstore = DocumentsReadOnce(location.zarr_store(read_only=True), always=True)
        check_is_ours(location, zstore)
        return cls(location, read_only=True, zstore=zstore)

    @classmethod
    def prepare(cls, path, identity: dict, config: dict, overwrite: bool) -> ScoreStore:
        """Create the store, or check that the existing one was made with ``identity`` (or
        one that differs only in keys its planner does not declare: a store made before
        per-planner settings, kept as it is; the caller adopts the stored identity).

        The caller holds the :class:`StoreLock`.  A store with a different identity is
        refused with the differing keys named, or replaced when ``overwrite``; anything
        that is not a store of ours is refused and never modified.  The store is then the
        run's alone, so it remembers each document it read until it writes it
        (:mod:`pipeline.store.documents_once`): the check here and the run's reads that
        follow read each once.
        """
        from pipeline.configs import config_hash, differing_keys

        location = locate(path)
        if not location.is_empty():
            zstore = _run_view(location)
            check_is_ours(location, zstore)
            store = cls(location, zstore=zstore)
            stored = store.attrs.get("identity")
            keys = differing_keys(stored or {}, identity)  # as comparable: configs.comparable
            if stored is not None and not keys:
                return store  # the caller migrates an older layout (pipeline/store/migrate.py)
            if not overwrite:
                raise StoreError(
                    f"store {location} was made with a different config (differing keys: "
                    f"{', '.join(keys)}); use another store.path, or store.mode=overwrite "
                    "to replace it")
        root = zarr.open_group(store=location.zarr_store(read_only=False), mode="w",
                               use_consolidated=False)
        root.require_group(INTEGRITY)
        store = cls(location, zstore=_run_view(location))
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
        """Write root attributes, then their record (:func:`pipeline.store.metadata.root_record`):
        every root attribute the coordinator writes goes through here."""
        self.fence()
        self.root.attrs.update(values)
        self.record_root()

    def record_root(self) -> None:
        """Record a digest of each root attribute in the ``integrity`` group."""
        from pipeline.store.metadata import root_record

        self.root.require_group(INTEGRITY).attrs["root"] = root_record(self.attrs)

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
        """Whether ``key`` is an array (opened and kept, as by :meth:`array`: checks and
        reads that follow ask for the array they tested)."""
        try:
            self.array(key)
        except KeyError:
            return False
        return True

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
                                  compressors=CODECS, overwrite=True, config=WRITE_CONFIG,
                                  attributes=attrs or None)  # one write of its document
        self._arrays[key] = arr
        return arr

    def remove(self, key: str) -> None:
        """Delete a group or array and everything under it (any store kind)."""
        self.fence()
        if key in self.root:
            del self.root[key]
        self._arrays = {k: v for k, v in self._arrays.items()
                        if k != key and not k.startswith(key + "/")}

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
        done = self.done(group)
        array = self.array(result_key(group, ENVIRONMENT))
        if array.shape != done.shape:  # a damaged document: never read what it claims
            raise StoreError(f"{result_key(group, ENVIRONMENT)}: shape {array.shape}, not "
                             f"the store's {done.shape}")
        values = self.whole(result_key(group, ENVIRONMENT))[done]
        found, counts = np.unique(values, return_counts=True)
        return {int(k): int(c) for k, c in zip(found, counts, strict=True)}

    # -- metadata documents ------------------------------------------------------------------
    def document(self, path: str) -> dict:
        """The parsed ``zarr.json`` of node ``path`` ("" for the root) as stored, without
        the consolidated copy of the others (KeyError when there is none, ValueError when
        it is not a JSON object)."""
        key = _doc_key(path)
        raw = self.read_bytes(key)
        if raw is None:
            raise KeyError(key)
        doc = json.loads(raw)
        if not isinstance(doc, dict):
            raise ValueError(f"{key} holds no JSON object")
        doc.pop("consolidated_metadata", None)
        return doc

    def documents(self) -> dict[str, dict]:
        """Every node's parsed ``zarr.json`` by path (for the in-memory layout)."""
        from zarr.core.sync import sync

        async def keys():
            return [k async for k in self.zstore.list() if k.endswith("zarr.json")]

        return {k[:-len("zarr.json")].rstrip("/"): self.document(k[:-len("zarr.json")].rstrip("/"))
                for k in sync(keys())}

    def documents_read_once(self):
        """A block within which each node's ``zarr.json`` is read once (a check compares
        most documents twice: with the layout and with their consolidated copy).  Nothing
        may be written within it; a store opened read-only reads each once anyway
        (:mod:`pipeline.store.documents_once`)."""
        return self.zstore.remembering()

    def read_documents(self, paths) -> None:
        """Where documents are read once, read those of nodes ``paths`` concurrently (on
        object storage each read is a round trip); elsewhere nothing (each is read when
        asked for)."""
        import asyncio

        from zarr.core.buffer import default_buffer_prototype
        from zarr.core.sync import sync

        if not self.zstore.remembers:
            return
        prototype = default_buffer_prototype()

        async def read_all():
            await asyncio.gather(*(self.zstore.get(k, prototype=prototype)
                                   for k in dict.fromkeys(_doc_key(p) for p in paths)))
        sync(read_all())

    def read_bytes(self, key: str) -> bytes | None:
        from zarr.core.buffer import default_buffer_prototype
        from zarr.core.sync import sync

        buf = self.zstore.remembered(key, _UNREAD)
        if buf is _UNREAD:
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
                                    use_consolidated=False, zarr_format=3)

    def consolidate(self, force: bool = False) -> None:
        """Consolidated metadata for readers (xarray); only between runs' stages, and only
        when a metadata document was written or removed through this store object since it
        last consolidated (or was opened), or when ``force``d (a copy found stale):
        chunks are not part of the consolidated copy."""
        if not force and self.zstore.document_changes == self._consolidated_at:
            return
        self.fence()
        with warnings.catch_warnings():  # "not part of the v3 spec yet": known, intended
            warnings.filterwarnings("ignore", message=".*[Cc]onsolidated metadata.*")
            zarr.consolidate_metadata(self.zstore)
        self._consolidated_at = self.zstore.document_changes


#: :meth:`ScoreStore.read_bytes`: a document the view does not remember
_UNREAD = object()


def _run_view(location: Location) -> DocumentsReadOnce:
    """The view of the store of a run that holds its lock (the only writer): it remembers
    every document until it is written through it."""
    return DocumentsReadOnce(location.zarr_store(read_only=False), always=True)


def _doc_key(path: str) -> str:
    return f"{path}/zarr.json" if path else "zarr.json"

