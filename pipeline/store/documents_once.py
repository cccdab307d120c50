"""A store's view that can read each node's metadata document (``zarr.json``) at most once.

Opening and checking a store reads most documents several times: the metadata check
compares them (with the layout and with their consolidated copy), Zarr reads each again
when the node is opened, and a group's listing reads its children's.  In object storage each
of those reads is a round trip.  While the view remembers, each document (or its absence) is
read once and nothing may be written.  A :class:`pipeline.store.ScoreStore` opened read-only
remembers for its whole life: it already sees its root and the arrays it opened as they
were when first read (Zarr's objects keep their metadata), and this extends that to every
document, one consistent set.  A store opened for writing remembers only within
:meth:`DocumentsReadOnce.remembering` (a metadata check).  Chunks are always read.

The view also counts the metadata documents written or removed through it
(:attr:`DocumentsReadOnce.document_changes`): the store's consolidated copy of them is stale
only after one of those (:meth:`pipeline.store.ScoreStore.consolidate`).
"""

from __future__ import annotations

import contextlib

import zarr.storage


class DocumentsReadOnce(zarr.storage.WrapperStore):
    """Wraps a store; ``always``: remember every document read, for the view's whole life."""

    def __init__(self, store, always: bool = False, _changes: list[int] | None = None) -> None:
        super().__init__(store)
        self._always = always
        self._documents: dict[str, object] | None = {} if always else None
        self._changes = [0] if _changes is None else _changes  # shared with derived views

    def _with_store(self, store) -> DocumentsReadOnce:
        return type(self)(store, self._always, self._changes)

    @property
    def document_changes(self) -> int:
        """How many times a ``zarr.json`` was written or removed, or a node's folder
        removed, through this view (and the views Zarr derived from it)."""
        return self._changes[0]

    def _changed(self, key: str) -> None:
        if _is_document(key):
            self._changes[0] += 1

    async def set(self, key, value) -> None:
        self._changed(key)
        await self._store.set(key, value)

    async def set_if_not_exists(self, key, value) -> None:
        self._changed(key)
        await self._store.set_if_not_exists(key, value)

    async def _set_many(self, values) -> None:
        values = list(values)
        for key, _ in values:
            self._changed(key)
        await self._store._set_many(values)

    async def delete(self, key) -> None:
        self._changed(key)
        await self._store.delete(key)

    async def delete_dir(self, prefix) -> None:
        self._changes[0] += 1  # a node removed, or its chunks: either way counted
        await self._store.delete_dir(prefix)

    async def clear(self) -> None:
        self._changes[0] += 1
        await self._store.clear()

    @property
    def remembers(self) -> bool:
        return self._documents is not None

    @contextlib.contextmanager
    def remembering(self):
        """Within the block each document is read once; nothing may be written in it.  A
        block within another, or on a view that always remembers, is part of it."""
        if self._documents is not None:
            yield
            return
        self._documents = {}
        try:
            yield
        finally:
            self._documents = None

    async def get(self, key, prototype, byte_range=None):
        documents = self._documents
        if documents is None or byte_range is not None or not _is_document(key):
            return await self._store.get(key, prototype, byte_range)
        if key not in documents:
            documents[key] = await self._store.get(key, prototype)
        return documents[key]


def _is_document(key: str) -> bool:
    return key == "zarr.json" or key.endswith("/zarr.json")
