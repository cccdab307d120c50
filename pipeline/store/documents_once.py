"""A store's view that can read each node's metadata document (``zarr.json``) at most once.

Opening and checking a store reads most documents several times: the metadata check
compares them (with the layout and with their consolidated copy), Zarr reads each again
when the node is opened, and a group's listing reads its children's.  In object storage each
of those reads is a round trip.  While the view remembers, each document (or its absence) is
read once, and again only after it was written or removed through the view.  A
:class:`pipeline.store.ScoreStore` opened read-only remembers for its whole life: it already
sees its root and the arrays it opened as they were when first read (Zarr's objects keep
their metadata), and this extends that to every document, one consistent set.  So does the
store of a run that holds the lock, the store's only writer.  Any other store opened for
writing remembers only within :meth:`DocumentsReadOnce.remembering` (a metadata check).
Chunks are always read.

The view also counts the metadata documents written or removed through it
(:attr:`DocumentsReadOnce.document_changes`): the store's consolidated copy of them is stale
only after one of those (:meth:`pipeline.store.ScoreStore.consolidate`).
"""

from __future__ import annotations

import asyncio
import contextlib

import zarr.storage


class _Shared:
    """What a view shares with the views Zarr derives from it (``with_read_only``)."""

    __slots__ = ("changes", "documents")

    def __init__(self, always: bool) -> None:
        self.documents: dict[str, object] | None = {} if always else None
        self.changes = 0


class DocumentsReadOnce(zarr.storage.WrapperStore):
    """Wraps a store; ``always``: remember every document read, for the view's whole life.

    A document written or removed through the view is read again the next time it is
    asked for; one written by anything else is not, while the view remembers.  So a view
    remembers for its whole life only where nothing else writes the store: a store opened
    read-only (it sees the documents as they were), or one opened for a run that holds
    the store's lock (:meth:`pipeline.store.ScoreStore.prepare`)."""

    def __init__(self, store, always: bool = False, _shared: _Shared | None = None) -> None:
        super().__init__(store)
        self._shared = _Shared(always) if _shared is None else _shared

    def _with_store(self, store) -> DocumentsReadOnce:
        return type(self)(store, _shared=self._shared)

    @property
    def document_changes(self) -> int:
        """How many times a ``zarr.json`` was written or removed, or a node's folder
        removed, through this view (and the views Zarr derived from it)."""
        return self._shared.changes

    @contextlib.asynccontextmanager
    async def _writing(self, key: str | None, folder: bool = False):
        """Around a write of ``key`` (or the removal of the folder ``key``, or of
        everything when ``key`` is None): count it, and forget what it changes once it is
        done (also when it fails: the storage may hold either version)."""
        try:
            yield
        finally:
            shared = self._shared
            if key is None or folder or _is_document(key):
                shared.changes += 1
            if shared.documents is not None:
                if key is None:
                    shared.documents.clear()
                elif folder:
                    inside = key.rstrip("/") + "/" if key.strip("/") else ""
                    for k in [k for k in shared.documents if k.startswith(inside)]:
                        del shared.documents[k]
                else:
                    shared.documents.pop(key, None)

    async def set(self, key, value) -> None:
        async with self._writing(key):
            await self._store.set(key, value)

    async def set_if_not_exists(self, key, value) -> None:
        """Zarr writes each parent group's document this way whenever it creates an array;
        where the view remembers that document as present, nothing is asked of the storage
        (an existence check is a round trip in object storage)."""
        documents = self._shared.documents
        if documents is not None and documents.get(key) is not None:
            return
        async with self._writing(key):
            await self._store.set_if_not_exists(key, value)

    async def _set_many(self, values) -> None:
        await asyncio.gather(*(self.set(key, value) for key, value in values))

    async def delete(self, key) -> None:
        async with self._writing(key):
            await self._store.delete(key)

    async def delete_dir(self, prefix) -> None:
        """Zarr removes a node's folder before it creates a node there (``overwrite``), so
        also where there is none; a folder is removed only if a listing finds something in
        it (in S3 one or two listings, where s3fs's removal of nothing costs five requests).
        """
        async with self._writing(prefix, folder=True):  # a node removed, or its chunks
            async for _ in self._store.list_dir(prefix):
                await self._store.delete_dir(prefix)
                return

    async def clear(self) -> None:
        async with self._writing(None):
            await self._store.clear()

    @property
    def remembers(self) -> bool:
        return self._shared.documents is not None

    @contextlib.contextmanager
    def remembering(self):
        """Within the block each document is read once (until it is written through the
        view).  A block within another, or on a view that always remembers, is part of it."""
        shared = self._shared
        if shared.documents is not None:
            yield
            return
        shared.documents = {}
        try:
            yield
        finally:
            shared.documents = None

    def remembered(self, key: str, default=None):
        """The document ``key`` as remembered (None where it is known to be absent), or
        ``default`` where nothing is remembered for it: a synchronous caller then needs no
        call into Zarr's event loop (a hand-off between threads, about 0.2 ms here)."""
        documents = self._shared.documents
        if documents is None or key not in documents:
            return default
        return documents[key]

    async def get(self, key, prototype, byte_range=None):
        documents = self._shared.documents
        if documents is None or byte_range is not None or not _is_document(key):
            return await self._store.get(key, prototype, byte_range)
        if key not in documents:
            documents[key] = await self._store.get(key, prototype)
        return documents[key]


def _is_document(key: str) -> bool:
    return key == "zarr.json" or key.endswith("/zarr.json")
