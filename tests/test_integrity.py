"""Damage anywhere in a store is found, named, and repaired (or refused) on the next run:
byte flips and deleted chunk files in every group, stale derived data, and the agreement of
``box status`` with ``python -m pipeline stage=status``."""

import json
import shutil

import numpy as np
import pytest
import zarr
from typer.testing import CliRunner

from pipeline.cli import app
from pipeline.store import ScoreStore
from tests import pipeline_runs as pr

runner = CliRunner()

#: One chunk per group (coordinates and integrity records included).
FLIPPED = ["instances/spec/c/1", "raw/constraint/c/1/0", "constraints/theta/c/0/0",
           "scores/time/c/1/2", "scores/instance_seed/c/2", "evaluation/order/c/0/0/0",
           "integrity/scores/c/1/1/0"]
DELETED = ["instances/seed/c/0", "raw/time/c/2", "constraints/source_instance/c/1",
           "scores/feasible/c/0/0", "scores/done/c/3/2", "evaluation/time/c/0",
           "integrity/raw/c/0/0"]


def _flip(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _array(chunk: str) -> str:
    return chunk.split("/c/")[0]


def _copy(made, tmp_path):
    copy = tmp_path / "copy.zarr"
    shutil.copytree(made[0], copy)
    return copy


def _statuses(store):
    """(exit code and damaged arrays) of box status and of stage=status."""
    box = runner.invoke(app, ["status", str(store), "--json"])
    doc = json.loads(box.output)
    stage = pr.run(store, "stage=status")
    return box.exit_code, set(doc["damaged"]), stage.returncode, stage.stdout + stage.stderr


def _inputs(store):
    g = zarr.open_group(store, mode="r", use_consolidated=False)
    return {k: g[k][...] for k in ("instances/seed", "instances/spec", "constraints/theta",
                                    "constraints/source_instance", "raw/constraint")}


@pytest.mark.parametrize("damage, chunks", [("flip", FLIPPED), ("delete", DELETED)])
def test_damage_in_every_group_is_named_then_repaired(made, tmp_path, damage, chunks):
    copy = _copy(made, tmp_path)
    inputs = _inputs(copy)
    for chunk in chunks:
        (_flip if damage == "flip" else (lambda p: p.unlink()))(copy / chunk)
    box_code, named, stage_code, stage_out = _statuses(copy)
    exported = runner.invoke(app, ["export", str(copy), "-o", str(tmp_path / "x.npz")])
    assert exported.exit_code == 2 and "is damaged" in exported.output
    expected = {_array(c) for c in chunks}
    assert box_code == 1 and stage_code == 1
    assert named == expected  # every damaged array, and nothing else
    for array in expected:
        assert array in stage_out  # stage=status names the same arrays
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "repaired" in res.stdout and "recomputing" in res.stdout
    res = pr.run(copy, "stage=evaluate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "evaluate: running again" in res.stdout
    assert _statuses(copy)[0] == 0
    assert pr.same_matrix(pr.matrix(made[0]), pr.matrix(copy))
    for key, values in _inputs(copy).items():
        np.testing.assert_array_equal(values, inputs[key])


def test_an_input_that_cannot_be_regenerated_is_refused_naming_it(made, tmp_path):
    copy = _copy(made, tmp_path)
    table = zarr.open_array(copy / "integrity" / "instances", mode="r+")
    row = table[1]
    row[1] ^= 0x10  # what was recorded for instances/spec block 1 differs from its seeds
    table[1] = row
    _flip(copy / "instances" / "spec" / "c" / "1")
    res = pr.run(copy, "stage=generate")
    assert res.returncode == 2
    assert "instances/spec" in res.stderr and "cannot be repaired" in res.stderr
    assert "Traceback" not in res.stderr


def test_evaluate_reruns_when_its_inputs_or_settings_change(made, tmp_path):
    copy = _copy(made, tmp_path)
    res = pr.run(copy, "stage=evaluate", "evaluate.k=5")
    assert res.returncode == 0, res.stderr
    assert "evaluate: running again: its settings changed" in res.stdout
    attrs = json.loads((copy / "zarr.json").read_text())["attributes"]
    assert attrs["config"]["evaluate"]["k"] == 5  # the root config says what ran last
    assert attrs["stages"]["evaluate"]["settings"]["k"] == 5
    _flip(copy / "scores" / "time" / "c" / "0" / "1")
    res = pr.run(copy, "stage=scores", "evaluate.k=5")
    assert res.returncode == 0 and "recomputing" in res.stdout
    res = pr.run(copy, "stage=evaluate", "evaluate.k=5")
    assert res.returncode == 0, res.stderr
    assert "evaluate: running again: its inputs changed (scores/time)" in res.stdout
    res = pr.run(copy, "stage=evaluate", "evaluate.k=5")
    assert "evaluate: already complete" in res.stdout


def test_evaluate_reruns_when_box_cores_selectors_changed(made, tmp_path):
    """An evaluation stored by an earlier revision of the selectors (or before revisions
    were recorded) is stale: the next run replaces it and records the current one."""
    import box_core

    copy = _copy(made, tmp_path)
    root = copy / "zarr.json"
    doc = json.loads(root.read_text())
    assert doc["attributes"]["stages"]["evaluate"]["selector_revision"] == \
        box_core.SELECTOR_REVISION
    del doc["attributes"]["stages"]["evaluate"]["selector_revision"]
    root.write_text(json.dumps(doc))
    ScoreStore(copy).record_root()  # as an earlier version recorded it (not an edit)
    res = pr.run(copy, "stage=evaluate")
    assert res.returncode == 0, res.stderr
    assert (f"evaluate: running again: box_core's selectors changed (revision 1 -> "
            f"{box_core.SELECTOR_REVISION})") in res.stdout
    doc = json.loads(root.read_text())
    assert doc["attributes"]["stages"]["evaluate"]["selector_revision"] == \
        box_core.SELECTOR_REVISION
