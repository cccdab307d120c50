"""When a store's consolidated metadata (the copy of every document in the root one, what
xarray reads) is written again: only after a metadata document changed through the store
(pipeline/store/documents_once.py counts them; ScoreStore.consolidate), so a re-run whose
stages have nothing to do does not rewrite it after each stage; the documents a store
opened for reading was checked with are the ones it reads (ScoreStore.checked); and a
run's store, the only writer under the lock, reads each document once until it writes it."""

from __future__ import annotations

import json
import shutil

import numpy as np
import zarr
from hydra import compose, initialize_config_dir
from zarr.core.buffer import default_buffer_prototype
from zarr.core.sync import sync

from pipeline.configs import CONF_DIR, register_configs
from pipeline.domains import load_domain
from pipeline.store import metadata, status
from pipeline.store.documents_once import DocumentsReadOnce
from pipeline.store.score_store import ScoreStore
from tests import pipeline_runs as pr
from tests.test_metadata_campaign import rerun
from tests.test_metadata_reads import counting_reads


def _counting_consolidations(monkeypatch) -> list[int]:
    """From now on each real ``zarr.consolidate_metadata`` call is counted."""
    calls, real = [0], zarr.consolidate_metadata

    def counted(*args, **kwargs):
        calls[0] += 1
        return real(*args, **kwargs)

    monkeypatch.setattr(zarr, "consolidate_metadata", counted)
    return calls


def test_the_view_counts_changed_documents_not_chunks():
    view = DocumentsReadOnce(zarr.storage.MemoryStore())
    buf = default_buffer_prototype().buffer.from_bytes
    sync(view.set("scores/score/c/0/0", buf(b"x")))
    sync(view.delete("scores/score/c/0/0"))
    assert view.document_changes == 0
    sync(view.set("scores/zarr.json", buf(b"{}")))
    sync(view.set("zarr.json", buf(b"{}")))
    assert view.document_changes == 2
    sync(view.delete_dir("scores"))  # a node removed
    assert view.document_changes == 3
    derived = view.with_read_only(False)  # a view Zarr makes from this one counts here too
    sync(derived.set("raw/zarr.json", buf(b"{}")))
    assert view.document_changes == 4


def test_a_remembering_view_reads_again_what_was_written_through_it():
    memory = zarr.storage.MemoryStore()
    view = DocumentsReadOnce(memory, always=True)
    buf = default_buffer_prototype().buffer.from_bytes
    proto = default_buffer_prototype()

    def read(key, through=view):
        got = sync(through.get(key, proto))
        return None if got is None else got.to_bytes()

    assert read("a/zarr.json") is None  # its absence remembered too
    sync(memory.set("a/zarr.json", buf(b"1")))  # written by something else: not seen
    assert read("a/zarr.json") is None
    sync(view.set("a/zarr.json", buf(b"2")))
    assert read("a/zarr.json") == b"2"
    sync(view.with_read_only(False).set("a/zarr.json", buf(b"3")))  # a view Zarr derived
    assert read("a/zarr.json") == b"3"
    sync(view.set("a/b/zarr.json", buf(b"4")))
    assert read("a/b/zarr.json") == b"4"
    sync(view.delete_dir("a"))
    assert read("a/zarr.json") is None and read("a/b/zarr.json") is None
    sync(memory.set("ab/zarr.json", buf(b"5")))
    assert read("ab/zarr.json") == b"5"
    sync(view.delete_dir("a"))  # "ab" is not inside "a"
    sync(memory.set("ab/zarr.json", buf(b"6")))
    assert read("ab/zarr.json") == b"5"


def test_a_store_consolidates_only_after_a_document_changed(made, tmp_path, monkeypatch):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(made[0], copy)
    calls = _counting_consolidations(monkeypatch)
    store = ScoreStore(copy, read_only=False)
    store.consolidate()
    assert calls[0] == 0  # nothing changed since it was opened
    score = store.array("scores/score")
    score[0, 0] = score[0, 0]  # a chunk written: not part of the consolidated copy
    store.consolidate()
    assert calls[0] == 0
    store.set_attrs(note="x")
    store.consolidate()
    store.consolidate()
    assert calls[0] == 1
    consolidated = zarr.open_group(copy, mode="r", use_consolidated=True)
    assert consolidated.attrs["note"] == "x"
    store.consolidate(force=True)
    assert calls[0] == 2


def _stale_copy(store) -> None:
    root = json.loads((store / "zarr.json").read_text())
    root["consolidated_metadata"]["metadata"]["scores/score"]["attributes"]["long_name"] = "?"
    (store / "zarr.json").write_text(json.dumps(root))
    assert "consolidated copy of scores/score" in status.damaged(status.collect(store))


def test_a_rerun_that_repairs_the_copy_consolidates_once(made, tmp_path, monkeypatch):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(made[0], copy)
    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*pr.SMALL, f"store.path={copy}",
                                                        "stage=generate"])
    calls = _counting_consolidations(monkeypatch)
    _stale_copy(copy)
    assert rerun(cfg) is None
    assert calls[0] == 2  # the repair; the run's settings (stage=generate, not all) recorded
    _stale_copy(copy)
    assert rerun(cfg) is None
    # the repair writes the copy again; the four stages with nothing to do and the run's end
    # leave it (each consolidated once more before)
    assert calls[0] == 3
    assert not status.damaged(status.collect(copy))
    for name, values in pr.matrix(made[0]).items():
        np.testing.assert_array_equal(pr.matrix(copy)[name], values, err_msg=name)


def test_a_runs_store_reads_each_document_once_until_it_writes_it(made, tmp_path,
                                                                  monkeypatch):
    """The store a run prepares under its lock: the check of prepare() and the metadata
    check after it read each document once; a document the run writes is read again."""
    copy = tmp_path / "copy.zarr"
    shutil.copytree(made[0], copy)
    counting = counting_reads(monkeypatch)
    stored = json.loads((copy / "zarr.json").read_text())["attributes"]
    store = ScoreStore.prepare(copy, stored["identity"], stored["config"], overwrite=False)
    assert metadata.check(store, load_domain("planar")) == []
    assert store.zstore._store in counting  # noqa: SLF001 (the storage below the view)
    reads = store.zstore._store.reads  # noqa: SLF001
    documents = {k: n for k, n in reads.items() if k.endswith("zarr.json")}
    assert len(documents) > 20 and max(documents.values()) == 1, documents
    store.set_attrs(note="x")
    assert json.loads(store.read_bytes("zarr.json"))["attributes"]["note"] == "x"
    assert reads["zarr.json"] == 2  # written through the view: read again
    store.consolidate()
    assert metadata.check(store, load_domain("planar")) == []
    fresh = ScoreStore(copy, read_only=True)  # what the run left, read afresh
    assert metadata.check(fresh, load_domain("planar")) == [] and fresh.attrs["note"] == "x"


def test_a_store_opened_for_reading_reads_the_documents_it_was_checked_with(made,
                                                                             monkeypatch):
    counting = counting_reads(monkeypatch)
    store = ScoreStore.checked(made[0])
    assert metadata.check(store, load_domain("planar")) == []
    assert len(counting) == 1  # the check and the store read through one view
    documents = {k: n for k, n in counting[0].reads.items() if k.endswith("zarr.json")}
    assert len(documents) > 20 and max(documents.values()) == 1, documents
