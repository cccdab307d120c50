"""The metadata check reads each ``zarr.json`` once (on object storage every read is a round
trip), and finds the same differences as a check that reads every document every time."""

from __future__ import annotations

import collections
import contextlib
import json
import shutil

import zarr.storage

from pipeline.domains import load_domain
from pipeline.store import metadata
from pipeline.store.location import Location
from pipeline.store.score_store import ScoreStore


class CountingStore(zarr.storage.WrapperStore):
    """A store that counts the reads of each key (it changes nothing); the views Zarr
    derives from it (``with_read_only``) count into the same counter."""

    def __init__(self, store, reads: collections.Counter | None = None):
        super().__init__(store)
        self.reads = collections.Counter() if reads is None else reads

    def _with_store(self, store):
        return type(self)(store, self.reads)

    async def get(self, key, prototype, byte_range=None):
        self.reads[key] += 1
        return await self._store.get(key, prototype, byte_range)


def counting_reads(monkeypatch) -> list[CountingStore]:
    """From now on every store a ScoreStore opens counts the reads that reach it (below
    any document cache); the list holds them in the order they were opened."""
    counting = []
    zarr_store = Location.zarr_store

    def counted(self, read_only):
        counting.append(CountingStore(zarr_store(self, read_only)))
        return counting[-1]

    monkeypatch.setattr(Location, "zarr_store", counted)
    return counting


def _counted(path, monkeypatch) -> tuple[ScoreStore, CountingStore]:
    """A store opened for writing (it remembers documents only within a check's block),
    and the reads that reach its storage from now on (opening it read the root)."""
    counting = counting_reads(monkeypatch)
    store = ScoreStore(path, read_only=False)
    counting[-1].reads.clear()
    return store, counting[-1]


def _reading_every_time(store: ScoreStore, monkeypatch):
    """The check as it was: every document read wherever it is compared."""
    with monkeypatch.context() as patched:
        patched.setattr(ScoreStore, "documents_read_once", lambda self: contextlib.nullcontext())
        return metadata.check(store, load_domain("planar"))


def test_a_check_reads_each_document_once(made, monkeypatch):
    store, counting = _counted(made[0], monkeypatch)
    assert metadata.check(store, load_domain("planar")) == []
    documents = {k: n for k, n in counting.reads.items() if k.endswith("zarr.json")}
    assert len(documents) > 20  # every array's and group's document
    assert max(documents.values()) == 1, {k: n for k, n in documents.items() if n > 1}

    store, counting = _counted(made[0], monkeypatch)
    assert _reading_every_time(store, monkeypatch) == []
    assert max(counting.reads.values()) >= 2  # what the memo saves: compared twice


def test_a_damaged_store_shows_the_same_differences_either_way(made, tmp_path, monkeypatch):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(made[0], copy)
    doc_path = copy / "scores" / "status" / "zarr.json"
    doc = json.loads(doc_path.read_text())
    doc["attributes"]["flag_meanings"] = "edited"
    doc_path.write_text(json.dumps(doc))
    found = metadata.check(ScoreStore(copy, read_only=False), load_domain("planar"))
    assert any(d.node == "scores/status" for d in found)
    assert any("consolidated copy of scores/status" in d.what for d in found)
    assert found == _reading_every_time(ScoreStore(copy, read_only=False), monkeypatch)
    # a store opened for writing remembers documents for one check only: a document
    # written after it is read afresh
    store = ScoreStore(copy, read_only=False)
    metadata.check(store, load_domain("planar"))
    assert not store.zstore.remembers
    with store.documents_read_once():  # a check within a block is part of that block
        metadata.check(store, load_domain("planar"))
        assert store.zstore.remembers
    assert not store.zstore.remembers
    assert ScoreStore(copy, read_only=True).zstore.remembers  # read-only: always
