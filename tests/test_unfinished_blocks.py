"""Readers never take a missing entry for an infeasible one: a block whose ``done`` mask
and data are gone (with its integrity row) is unfinished for ``box evaluate``,
``stage=evaluate`` and the report, which refuse with one line naming it."""

import shutil

import zarr
from typer.testing import CliRunner

from pipeline.cli import app
from tests import pipeline_runs as pr


def _forget_block(store, block=(1, 1)) -> None:
    """Delete block ``block`` of every scores array but ``time``, and its integrity row."""
    g = zarr.open_group(store, mode="r+", use_consolidated=False)
    for name, _ in g["scores"].arrays():
        chunk = store / "scores" / name / "c" / "/".join(map(str, block))
        if name != "time" and g[f"scores/{name}"].ndim == 2 and chunk.exists():
            chunk.unlink()
    g["integrity/scores"][block] = 0


def test_evaluation_refuses_a_store_with_an_unfinished_block(made, tmp_path):
    store = tmp_path / "a.zarr"
    shutil.copytree(made[0], store)
    _forget_block(store)
    res = CliRunner().invoke(app, ["evaluate", str(store)])
    assert res.exit_code == 2, res.output
    line = res.output.strip()
    assert "\n" not in line and "30 of 360 entries in 1 unfinished block(s) ((1, 1))" in line
    res = pr.run(store, "stage=evaluate", "evaluate.k=5", "evaluate.c=1.5")
    assert res.returncode == 2 and "unfinished block(s)" in res.stderr + res.stdout
    res = pr.run(store, "stage=generate")  # the next run computes the block again
    assert res.returncode == 0, res.stderr + res.stdout
    assert pr.same_matrix(pr.matrix(store), pr.matrix(made[0]))
    assert CliRunner().invoke(app, ["evaluate", str(store)]).exit_code == 0
