"""How the store's checks read what they verify (pipeline/store/verification.py): a small
array (an integrity table, a ``done`` mask) whole, chunk by chunk only when one does not
decode, so one damaged chunk is still told apart from the others; the chunks whose digests
are checked, together; and a store opened for reading reads each document once
(pipeline/store/documents_once.py)."""

from __future__ import annotations

import shutil

import numpy as np
import zarr

from pipeline.domains import load_domain
from pipeline.store import metadata
from pipeline.store.layout import CODECS
from pipeline.store.score_store import ScoreStore
from pipeline.store.verification import chunk_values
from tests.test_metadata_reads import counting_reads


def _flip(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def test_chunk_values_reads_whole_and_tells_a_bad_chunk_apart(tmp_path):
    values = np.arange(5 * 4, dtype="uint64").reshape(5, 4)
    arr = zarr.create_array(tmp_path / "a.zarr", shape=(5, 4), chunks=(2, 4), dtype="uint64",
                            fill_value=0, compressors=CODECS)  # the store's: CRC32C checked
    arr[...] = values
    whole = chunk_values(arr)
    assert sorted(whole) == [(0, 0), (1, 0), (2, 0)]
    for (i, _), got in whole.items():
        np.testing.assert_array_equal(got, values[2 * i:2 * i + 2])  # the edge chunk: 1 row
    _flip(tmp_path / "a.zarr" / "c" / "1" / "0")
    damaged = chunk_values(zarr.open_array(tmp_path / "a.zarr", mode="r"))
    assert damaged[(1, 0)] is None
    for chunk in ((0, 0), (2, 0)):
        np.testing.assert_array_equal(damaged[chunk], whole[chunk])
    (tmp_path / "a.zarr" / "c" / "2" / "0").unlink()  # missing: the fill value
    assert (chunk_values(zarr.open_array(tmp_path / "a.zarr", mode="r"))[(2, 0)] == 0).all()


def test_one_damaged_row_of_an_integrity_table_is_that_block_only(made, tmp_path):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(made[0], copy)
    store = ScoreStore(copy, read_only=True)
    assert not store.verify("scores")
    finished = store.finished_blocks("scores")
    assert len(finished) == int(np.prod(store.grid("scores"))) > 1
    _flip(copy / "integrity" / "scores" / "c" / "1" / "1" / "0")
    _flip(copy / "scores" / "score" / "c" / "0" / "2")
    store = ScoreStore(copy, read_only=True)
    damage = store.verify("scores")
    assert damage.corrupted == {"integrity/scores": {(1, 1)}, "scores/score": {(0, 2)}}
    assert not damage.missing
    assert sorted(store.finished_blocks("scores")) == sorted(set(finished) - {(1, 1)})


def test_a_store_opened_for_reading_reads_each_document_once(made, monkeypatch):
    counting = counting_reads(monkeypatch)
    store = ScoreStore(made[0], read_only=True)
    assert metadata.check(store, load_domain("planar")) == []
    for group in ("instances", "raw", "constraints", "scores"):
        assert not store.verify(group)
        for key in store.arrays_under(group):
            store.array(key)
    store.array("scores/score")[...]
    store.array("scores/score")[...]
    reads = counting[0].reads
    documents = {k: n for k, n in reads.items() if k.endswith("zarr.json")}
    assert len(documents) > 20 and max(documents.values()) == 1, documents
    assert reads["scores/score/c/0/0"] == 3  # chunks are read each time: verified, then twice
    # a store opened for writing changes its documents: each is read when it is opened
    assert not ScoreStore(made[0], read_only=False).zstore.remembers
