"""Verifying what a store holds against its integrity records: finished blocks, damage
per chunk (missing, corrupted), digests of a stage's inputs and of arrays recorded whole.
A part of :class:`pipeline.store.ScoreStore`."""

from __future__ import annotations

import contextlib

import numpy as np
import zarr

from pipeline.store import integrity
from pipeline.store.blocks import block_region
from pipeline.store.integrity import Damage, digest
from pipeline.store.layout import ENVIRONMENT, done_key, table_key

#: chunks :meth:`Verification.verify` reads at once
READ_AT_ONCE = 8


class Verification:
    """The store's integrity checks (a mixin of :class:`pipeline.store.ScoreStore`)."""

    #: what :meth:`reading_once` keeps while it is on (None: off)
    _kept: dict | None = None

    @contextlib.contextmanager
    def reading_once(self):
        """Within it, each array's listing of chunks, each ``done`` mask and each environment
        array are read once and kept.  For readers that look at the store as it is at one
        moment (``box status``, ``box export``): status otherwise listed every array twice
        (its chunks checked, then counted), read each mask three times (the blocks done,
        the entries done, the entries per environment) and each environment array twice,
        and in object storage each read is a round trip.  Not for a run, whose own writes
        change them."""
        self._kept = {}
        try:
            yield self
        finally:
            self._kept = None

    def _once(self, what: tuple, read):
        """``read()``, or under :meth:`reading_once` what it gave for ``what`` before."""
        if self._kept is None:
            return read()
        if what not in self._kept:
            self._kept[what] = read()
        return self._kept[what]

    def mask_chunks(self, key: str) -> tuple[np.ndarray | None, dict]:
        """A small array (a ``done`` mask) read whole: (its values, or None when a chunk
        does not decode; each chunk's values, None for those), kept under
        :meth:`reading_once`."""
        return self._once(("values", key), lambda: read_chunks(self.array(key)))

    def whole(self, key: str) -> np.ndarray:
        """The array ``key`` read whole; under :meth:`reading_once`, from the chunks
        :meth:`verify` read when it read every chunk (it keeps those of the environment
        arrays), else in one read."""
        arr = self.array(key)
        chunks = list(np.ndindex(*arr.cdata_shape))
        if self._kept is None or not all(("chunk", key, c) in self._kept for c in chunks):
            return arr[...]
        out = np.empty(arr.shape, dtype=arr.dtype)
        for c in chunks:
            out[block_region(c, arr.chunks)] = self._kept["chunk", key, c]
        return out

    def chunks_written(self, key: str) -> int:
        """How many of the array's chunks exist (Zarr's ``nchunks_initialized``), counted
        in :meth:`chunk_keys`' listing."""
        arr, written = self.array(key), self.chunk_keys(key)
        return sum(arr.metadata.encode_chunk_key(c) in written
                   for c in np.ndindex(*arr.cdata_shape))

    def finished_blocks(self, group: str, rows=None) -> list[tuple[int, ...]]:
        """Blocks whose integrity row is recorded (readable and complete); ``rows``: the
        table's rows as :meth:`table_rows` read them (default: read them now)."""
        rows = self.table_rows(group) if rows is None else rows
        return [block for block, row in rows.items()
                if row is not None and np.all(row != integrity.NOT_RECORDED)]

    def table_rows(self, group: str) -> dict[tuple, np.ndarray | None]:
        """Each block's row of ``group``'s integrity table (None: it does not decode)."""
        table = self.array(table_key(group))
        return {block[:-1]: None if row is None else row.reshape(-1)
                for block, row in chunk_values(table).items()}

    def verify(self, group: str, blocks=None, expect_all: bool = False,
               rows=None) -> Damage:
        """Damage in the recorded ``blocks`` (default: all) of ``group``.  A block without a
        readable record counts as damage of the record when the block should have one:
        its ``done`` mask says so, or ``expect_all`` (a finished group written whole).
        ``rows``: the integrity table's rows, where the caller read them already
        (:meth:`table_rows`).  Each chunk is read once: the ``done`` mask's chunks, read
        whole to know which blocks are done, are not read again for their digests (in
        object storage every read is a round trip)."""
        damage = Damage()
        if not self.has_table(group):
            return self._verify_decoding(group)
        recorded_at = table_key(group)
        table = self.array(recorded_at)
        layout = self.layout(group)
        gone = set(self.missing_arrays(group))
        written = {name: self.chunk_keys(f"{group}/{name}") for name in layout.names
                   if name not in gone}
        read = {}  # (array key, chunk) -> digest of the values read already
        done = self._done_blocks(group, read) if not expect_all else None
        if blocks is None:
            blocks = list(np.ndindex(*table.shape[:-1]))
        checks = []  # (array key, its chunk, recorded digest, block): read below, together
        rows = self.table_rows(group) if rows is None else rows
        for block in blocks:
            expected = expect_all or (done is not None and block in done)
            row = rows.get(tuple(block))  # None: does not decode
            if row is None:
                damage.add("corrupted", recorded_at, block)
                continue
            if not np.all(row != integrity.NOT_RECORDED):
                if expected:
                    damage.add("missing", recorded_at, block)
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
                checks.append((key, chunk, int(row[k]), block))
        digests = {**read, **self._chunk_digests(
            {(key, chunk) for key, chunk, _, _ in checks} - set(read))}
        for key, chunk, recorded, block in checks:
            if digests[key, chunk] != recorded:  # None: the chunk does not decode
                damage.add("corrupted", key, block)
        return damage

    def _chunk_digests(self, wanted: set[tuple[str, tuple]]) -> dict:
        """The digest of the values of each (array key, chunk) in ``wanted``, or None where
        the chunk does not decode.  Read :data:`READ_AT_ONCE` at a time, in one call into
        Zarr's event loop: in object storage every read is a round trip (read one after
        another, ``box status`` of a small store in S3 took seconds), and one call instead
        of one per chunk spares the thread hand-offs that dominate on local disk; a chunk
        that several blocks share (a per-instance array) is read once.  Only digests are
        kept, so a whole store's verification holds no values."""
        import asyncio

        from zarr.core.sync import sync

        arrays = {key: self.array(key).async_array for key in {key for key, _ in wanted}}

        async def read(gate, key, chunk):
            arr = arrays[key]
            block = tuple(slice(c * size, min((c + 1) * size, n))
                          for c, size, n in zip(chunk, arr.chunks, arr.shape, strict=True))
            async with gate:
                try:
                    values = await arr.getitem(block)
                except Exception:  # noqa: BLE001 (any decoding failure means corrupt)
                    return (key, chunk), None
            if self._kept is not None and key.endswith(f"/{ENVIRONMENT}"):
                self._kept["chunk", key, chunk] = values  # small; status reads it next
            return (key, chunk), digest(values)

        async def read_all():
            gate = asyncio.Semaphore(READ_AT_ONCE)
            return await asyncio.gather(*(read(gate, key, chunk)
                                          for key, chunk in sorted(wanted)))

        return dict(sync(read_all())) if wanted else {}

    def missing_arrays(self, group: str) -> list[str]:
        """Arrays that the integrity table of ``group`` covers but that are gone."""
        return [name for name in self.layout(group).names if not self.has(f"{group}/{name}")]

    def _done_blocks(self, group: str, read: dict | None = None) -> set:
        """Blocks whose ``done`` mask is all set (that mask's own damage aside); ``read``
        gets the digest of each of the mask's chunks (None: it does not decode), keyed as
        :meth:`_chunk_digests` keys them."""
        key = done_key(group)
        if not self.has(key):
            return set(np.ndindex(*self.grid(group)))  # the mask is gone: all were done
        values = self.mask_chunks(key)[1]
        if read is not None:
            read.update({(key, chunk): None if v is None else digest(v)
                         for chunk, v in values.items()})
        return {block for block, v in values.items()
                if v is not None and v.all()}  # None: damage of done itself

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

    def chunk_keys(self, key: str) -> frozenset[str]:
        """Chunk keys (relative to the array) that exist in the store (one listing, kept
        under :meth:`reading_once`)."""
        from zarr.core.sync import sync

        prefix = f"{key}/"

        async def collect():
            return frozenset([k[len(prefix):] async for k in self.zstore.list_prefix(prefix)])

        return self._once(("keys", key), lambda: sync(collect()))

    def array_digests(self, keys) -> dict[str, str]:
        """A digest per array (of its recorded chunk digests, or of its values when it is
        outside any block group): what a stage records about its inputs."""
        out, tables = {}, {}  # each group's table read once
        for key in keys:
            group, name = key.split("/", 1)
            if self.has_table(group) and name in self.layout(group).names:
                k = self.layout(group).names.index(name)
                if group not in tables:
                    tables[group] = self.array(table_key(group))[...]
                out[key] = integrity.combine(tables[group][..., k].reshape(-1))
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
        return sorted(f"{group}/{path}" for path, node in self.root[group].members(max_depth=None)
                      if isinstance(node, zarr.Array))


def chunk_values(arr: zarr.Array) -> dict[tuple, np.ndarray | None]:
    """The values of every chunk of a small array (an integrity table, a ``done`` mask) by
    chunk index, None for a chunk that does not decode: the whole array in one read, chunk
    by chunk only when some chunk does not decode (a missing chunk holds the fill value)."""
    return read_chunks(arr)[1]


def read_chunks(arr: zarr.Array) -> tuple[np.ndarray | None, dict[tuple, np.ndarray | None]]:
    """(the whole array, or None when a chunk does not decode; :func:`chunk_values`)."""
    chunks = list(np.ndindex(*arr.cdata_shape))
    try:
        values = arr[...]
    except Exception:  # noqa: BLE001 (one chunk does not decode: find which)
        out = {}
        for chunk in chunks:
            try:
                out[chunk] = arr.blocks[chunk]
            except Exception:  # noqa: BLE001
                out[chunk] = None
        return None, out
    return values, {chunk: values[block_region(chunk, arr.chunks)] for chunk in chunks}
