"""Tables fit the console they are printed on: at 80 columns they leave out their least
important columns (and say so) instead of cutting names and numbers ("selec…")."""

from __future__ import annotations

import io
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console

import box_core
from pipeline.configs import EvaluateConfig
from pipeline.tables import Column, FittedTable, summary_table
from tests import pipeline_runs as pr

BOX = Path(sys.executable).parent / "box"
SELECTORS = ["box", "eips", "static", "rand", "doo", "pembo", "oracle", "fastest"]


@pytest.fixture(scope="module")
def matrix_file(tmp_path_factory):
    from box_core import synthetic

    path = tmp_path_factory.mktemp("tables") / "d.npz"
    synthetic.score_matrix(120, 30, useful=20, seed=0).save(path)
    return path


def _printed(renderable, width: int) -> str:
    console = Console(width=width, record=True, file=io.StringIO())
    console.print(renderable)
    return console.export_text()


def _assert_fits(text: str, width: int) -> None:
    assert "…" not in text
    assert max(len(line) for line in text.splitlines()) <= width, text


def test_the_summary_keeps_every_name_and_number_it_shows_at_80_columns(matrix_file):
    data = np.load(matrix_file)
    summary = box_core.loocv(data["scores"], times=data["times"], feasible=data["feasible"],
                             features=data["features"], selectors=SELECTORS).summary()
    head, *rows = summary.table_rows()
    wide = _printed(summary_table(summary, "a title"), 200)
    assert "left out" not in wide and all(h in wide for h in head)
    narrow = _printed(summary_table(summary, "a title"), 80)
    _assert_fits(narrow, 80)
    kept = ["selector", "found", "mean time", "95% CI", "x box", "95% CI of x"]
    left_out = [h for h in head if h not in kept]
    assert f"left out at this width: {', '.join(left_out)}" in " ".join(narrow.split())
    for row in rows:
        line = next(ln for ln in narrow.splitlines() if ln.startswith(f"│ {row[0]} "))
        cells = [c.strip() for c in line.strip("│").split("│")]
        assert cells == [row[head.index(h)] for h in kept]


def test_a_console_too_narrow_for_the_columns_that_stay_folds_them_and_cuts_nothing():
    table = FittedTable([Column("name", "left"), Column("value", drop=1)],
                        [["a_rather_long_name", "123456789.25"]])
    text = _printed(table, 12)
    _assert_fits(text, 12)
    cells = "".join(text.replace("│", " ").split())
    assert "a_rather_long_name" in cells  # folded across lines, all of it there


def _run_box(*args: str, columns: int = 80) -> subprocess.CompletedProcess:
    env = {**pr.env(), "COLUMNS": str(columns)}
    return subprocess.run([str(BOX), *args], capture_output=True, text=True, env=env,
                          timeout=600)


def test_box_evaluate_fits_80_columns(matrix_file):
    res = _run_box("evaluate", str(matrix_file), "--selectors", ",".join(SELECTORS))
    assert res.returncode == 0, res.stderr
    _assert_fits(res.stdout, 80)
    for name in SELECTORS:
        assert re.search(rf"^│ {name} +│", res.stdout, flags=re.M), name
    assert "left out at this width" in res.stdout
    wide = _run_box("evaluate", str(matrix_file), "--selectors", ",".join(SELECTORS),
                    columns=200)
    assert "left out" not in wide.stdout and "ms/step" in wide.stdout


def test_box_status_fits_80_columns_with_whole_array_names(made):
    from pipeline.store.status import collect

    res = _run_box("status", str(made[0]))
    assert res.returncode == 0, res.stderr
    _assert_fits(res.stdout, 80)
    for name in (a["array"] for a in collect(made[0])["arrays"]):
        assert re.search(rf"^│ {re.escape(name)} +│", res.stdout, flags=re.M), name


def test_stage_evaluate_prints_its_summary_in_80_columns(made, tmp_path):
    store = tmp_path / "a.zarr"
    shutil.copytree(made[0], store)
    res = subprocess.run(pr.command(store, "stage=evaluate", "evaluate.c=1.0"),
                         capture_output=True, text=True, cwd=tmp_path,
                         env={**pr.env(), "COLUMNS": "80"}, timeout=600)
    assert res.returncode == 0, res.stderr
    # the caption wraps where the table's width ends, so words are compared, not lines
    assert "selector" in res.stdout and "left out at this width" in " ".join(res.stdout.split())
    # the run's messages are single lines by design (a path is never broken); its table
    # fits
    table = [ln for ln in res.stdout.splitlines() if set(ln) & set("┏┃┡│└")]
    _assert_fits("\n".join(table), 80)
    names = [ln.split("│")[1].strip() for ln in table if ln.startswith("│ ")]
    assert names == EvaluateConfig().selectors
