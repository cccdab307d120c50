"""Verifying what a store holds against its integrity records: finished blocks, damage
per chunk (missing, corrupted), digests of a stage's inputs and of arrays recorded whole.
A part of :class:`pipeline.store.ScoreStore`."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import zarr

from pipeline.store import integrity
from pipeline.store.integrity import Damage, digest
from pipeline.store.layout import done_key, table_key


class Verification:
    """The store's integrity checks (a mixin of :class:`pipeline.store.ScoreStore`)."""

    def finished_blocks(self, group: str) -> list[tuple[int, ...]]:
        """Blocks whose integrity row is recorded (readable and complete)."""
        table = self.array(table_key(group))
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
        recorded_at = table_key(group)
        table = self.array(recorded_at)
        layout = self.layout(group)
        gone = set(self.missing_arrays(group))
        written = {name: self.chunk_keys(f"{group}/{name}") for name in layout.names
                   if name not in gone}
        done = self._done_blocks(group) if not expect_all else None
        if blocks is None:
            blocks = list(np.ndindex(*table.shape[:-1]))
        checks = []  # (array key, its chunk, recorded digest, block): read below, together
        for block in blocks:
            expected = expect_all or (done is not None and block in done)
            try:
                row = table.blocks[(*block, 0)].reshape(-1)
            except Exception:  # noqa: BLE001
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
        digests = self._chunk_digests({(key, chunk) for key, chunk, _, _ in checks})
        for key, chunk, recorded, block in checks:
            if digests[key, chunk] != recorded:  # None: the chunk does not decode
                damage.add("corrupted", key, block)
        return damage

    def _chunk_digests(self, wanted: set[tuple[str, tuple]]) -> dict:
        """The digest of the values of each (array key, chunk) in ``wanted``, or None where
        the chunk does not decode.  Read by a few threads at once: in object storage every
        read is a round trip (read one after another, ``box status`` of a small store in S3
        took seconds); a chunk that several blocks share (a per-instance array) is read
        once.  Only digests are kept, so a whole store's verification holds no values."""

        def read(item):
            key, chunk = item
            try:
                return item, digest(self.array(key).blocks[chunk])
            except Exception:  # noqa: BLE001 (any decoding failure means corrupt)
                return item, None

        for key in {key for key, _ in wanted}:
            self.array(key)  # opened here, once, not by the threads
        with ThreadPoolExecutor(max_workers=8) as pool:
            return dict(pool.map(read, sorted(wanted)))

    def missing_arrays(self, group: str) -> list[str]:
        """Arrays that the integrity table of ``group`` covers but that are gone."""
        return [name for name in self.layout(group).names if not self.has(f"{group}/{name}")]

    def _done_blocks(self, group: str) -> set:
        """Blocks whose ``done`` mask is all set (that mask's own damage aside)."""
        if not self.has(done_key(group)):
            return set(np.ndindex(*self.grid(group)))  # the mask is gone: all were done
        mask = self.array(done_key(group))
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
                    self.array(table_key(group))[..., k].reshape(-1))
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

