"""When a store's consolidated metadata (the copy of every document in the root one, what
xarray reads) is written again: only after a metadata document changed through the store
(pipeline/store/documents_once.py counts them; ScoreStore.consolidate), so a re-run whose
stages have nothing to do does not rewrite it after each stage; and the documents a store
opened for reading was checked with are the ones it reads (ScoreStore.checked)."""

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


def test_a_store_opened_for_reading_reads_the_documents_it_was_checked_with(made,
                                                                             monkeypatch):
    counting = counting_reads(monkeypatch)
    store = ScoreStore.checked(made[0])
    assert metadata.check(store, load_domain("planar")) == []
    assert len(counting) == 1  # the check and the store read through one view
    documents = {k: n for k, n in counting[0].reads.items() if k.endswith("zarr.json")}
    assert len(documents) > 20 and max(documents.values()) == 1, documents
