"""A read-only store's view that reads each node's metadata document (``zarr.json``) at most
once.

Opening a store for reading (``box status``, readers, a run's look before it writes) reads
most documents several times: the metadata check compares them, Zarr reads each again when
the node is opened, and a group's listing reads its children's.  In object storage each of
those reads is a round trip.  A :class:`pipeline.store.ScoreStore` opened read-only already
sees its root and the arrays it opened as they were when first read (Zarr's objects keep
their metadata); this view extends that to every document, so a reader sees one consistent
set of documents and makes one request per document.  Chunks are always read from the store.
"""

from __future__ import annotations

import zarr.storage


class DocumentsReadOnce(zarr.storage.WrapperStore):
    """Wraps a read-only store: each ``zarr.json`` (or its absence) is read once."""

    def __init__(self, store) -> None:
        super().__init__(store)
        self._documents: dict[str, object] = {}

    def _with_store(self, store) -> DocumentsReadOnce:
        return type(self)(store)

    async def get(self, key, prototype, byte_range=None):
        if byte_range is not None or not (key == "zarr.json" or key.endswith("/zarr.json")):
            return await self._store.get(key, prototype, byte_range)
        if key not in self._documents:
            self._documents[key] = await self._store.get(key, prototype)
        return self._documents[key]
