"""Issue 24's cases 1, 2 and 7, as a user meets them: a metadata document or an integrity
table edited or deleted by hand, then ``box status`` and the re-run, in real processes."""

from __future__ import annotations

import json
import resource
import shutil
import subprocess
import sys

import zarr
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.store import LAYOUT_VERSION
from tests import pipeline_runs as pr

runner = CliRunner()

#: Address space allowed to a reader of a crafted store: far below what its claims need.
READER_BYTES = 4 << 30


def _copy(made, tmp_path):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(made[0], copy)
    return copy


def _edit(store, node: str, change) -> None:
    path = store / node / "zarr.json"
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc, indent=2))


def _limited():
    resource.setrlimit(resource.RLIMIT_AS, (READER_BYTES, READER_BYTES))


def box(*args: str) -> subprocess.CompletedProcess:
    """``box ARGS`` in its own process with at most READER_BYTES of address space."""
    return subprocess.run([sys.executable, "-c", "from pipeline.cli import app; app()", *args],
                          capture_output=True,
                          text=True, env=pr.env(), preexec_fn=_limited, timeout=600)


def _status(store) -> tuple[int, str]:
    res = runner.invoke(app, ["status", str(store), "--json"])
    return res.exit_code, res.output


def test_case_1_a_huge_shape_in_a_document_costs_readers_nothing(made, tmp_path):
    copy = _copy(made, tmp_path)
    _edit(copy, "integrity/scores", lambda d: d.update(shape=[100000, 100000, 10]))
    res = box("status", str(copy))
    assert res.returncode == 1, res.stderr + res.stdout
    assert "integrity/scores/zarr.json (shape)" in res.stdout
    for args in (["export", str(copy), "-o", str(tmp_path / "x.npz")],
                 ["evaluate", str(copy)], ["show", str(copy), "-i", "0"]):
        res = box(*args)
        lines = res.stderr.strip().splitlines()
        assert res.returncode == 1 and len(lines) == 1, res.stderr
        assert "integrity/scores/zarr.json (shape)" in lines[0]
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "rewrote from the layout: integrity/scores/zarr.json (shape)" in res.stdout
    assert _status(copy)[0] == 0
    assert pr.same_matrix(pr.matrix(made[0]), pr.matrix(copy))


def test_case_2_lost_input_tables_are_rebuilt_without_recomputing_results(made, tmp_path):
    copy = _copy(made, tmp_path)
    shutil.rmtree(copy / "integrity" / "instances")
    shutil.rmtree(copy / "integrity" / "constraints")
    code, out = _status(copy)
    assert code == 1 and "integrity/instances" in out and "integrity/constraints" in out
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "integrity table is missing" in res.stdout
    assert "inputs changed" not in res.stdout  # raw and scores kept: their inputs held
    assert "raw: already complete" in res.stdout and "scores: already complete" in res.stdout
    assert _status(copy)[0] == 0
    assert pr.same_matrix(pr.matrix(made[0]), pr.matrix(copy))


def test_case_2_an_edited_chunk_grid_is_rewritten_and_what_it_hid_recomputed(made, tmp_path):
    copy = _copy(made, tmp_path)
    _edit(copy, "scores/score",
          lambda d: d["chunk_grid"]["configuration"].update(chunk_shape=[3, 5]))
    code, out = _status(copy)
    assert code == 1 and "scores/score/zarr.json (chunk_grid)" in out
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "scores/score/zarr.json (chunk_grid)" in res.stdout
    assert _status(copy)[0] == 0
    assert pr.same_matrix(pr.matrix(made[0]), pr.matrix(copy))


def test_case_7_swapped_flag_meanings_are_named_and_restored(made, tmp_path):
    copy = _copy(made, tmp_path)
    original = (copy / "scores/status/zarr.json").read_text()

    def swap(doc):
        words = doc["attributes"]["flag_meanings"].split()
        words[0], words[1] = words[1], words[0]
        doc["attributes"]["flag_meanings"] = " ".join(words)

    _edit(copy, "scores/status", swap)
    code, out = _status(copy)
    assert code == 1 and "scores/status/zarr.json (attribute flag_meanings)" in out
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert (copy / "scores/status/zarr.json").read_text() == original
    assert _status(copy)[0] == 0


def test_case_7_a_lowered_layout_version_never_adopts_unverified_chunks(made, tmp_path):
    copy = _copy(made, tmp_path)
    _edit(copy, "", lambda d: d["attributes"].update(layout_version=1))
    shutil.rmtree(copy / "integrity")
    a, b = copy / "scores/score/c/0/0", copy / "scores/score/c/1/1"
    data = a.read_bytes()
    a.write_bytes(b.read_bytes())  # two chunks swapped: each decodes, neither is right
    b.write_bytes(data)
    code, out = _status(copy)
    # (layout 4: the instance features of layout 5 count only with a record covering them)
    assert code == 1 and "layout_version is 1 but the arrays are those of layout 4" in out
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "migrated" not in res.stdout
    assert "integrity table is missing: every block is computed again" in res.stdout
    assert _status(copy)[0] == 0
    assert zarr.open_group(copy, mode="r").attrs["layout_version"] == LAYOUT_VERSION
    assert pr.same_matrix(pr.matrix(made[0]), pr.matrix(copy))
