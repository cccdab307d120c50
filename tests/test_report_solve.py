"""stage=report and stage=solve on small planar stores, run as a user runs them."""

from __future__ import annotations

import json
import re
import shutil

import matplotlib.image
import numpy as np
import pytest
import zarr

import box_core
from pipeline.evaluation import store_loocv
from pipeline.store import ScoreStore
from tests import pipeline_runs as pr


def md_table(text: str, heading: str, nth: int = 0) -> list[list[str]]:
    """Rows (header first) of the nth Markdown table after ``heading``."""
    part = text.split(heading, 1)[1]
    tables = re.findall(r"((?:^\|.*\|\n)+)", part, flags=re.M)
    lines = tables[nth].strip().splitlines()
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    return [rows[0], *rows[2:]]


def matrix(store):
    g = zarr.open_group(store, mode="r", use_consolidated=False)
    feasible = g["scores/feasible"][...]
    scores = np.where(feasible, -np.nan_to_num(g["scores/length"][...]), 0.0)
    return g, scores, feasible, g["scores/time"][...]


def own_columns(g):
    """(n, m): column j was extracted from row i's raw solution (planar: every column)."""
    source = g["constraints/source_instance"][...]
    return source[None, :] == np.arange(g["scores/feasible"].shape[0])[:, None]


def test_evaluate_hides_each_instance_s_own_constraints_unless_told_not_to(made, tmp_path):
    store, _ = made
    g = zarr.open_group(store, mode="r", use_consolidated=False)
    own = own_columns(g)
    assert own.any(axis=1).sum() >= 10  # planar constraints come from raw solutions
    m = own.shape[1]
    names = list(g["evaluation/selector"][...])
    # the stored orders stop where nothing stored can change (-1 after); the run through
    # every try is store_loocv's without until_best
    opened = ScoreStore.open(store)
    full = store_loocv(opened, opened.stage_info("evaluate")["settings"],
                       int(opened.attrs.get("config", {}).get("seed", 0)),
                       until_best=False, measure_overhead=False)
    for name in ("box", "eips", "fastest", "rand"):
        order = g["evaluation/order"][names.index(name)]
        made = order >= 0
        assert order.shape[1] == m - 1 and made[:, 0].all()
        assert (made[:, :-1] >= made[:, 1:]).all()  # a prefix of the tries, then -1
        assert (full.order[name] >= 0).all() and full.order[name].shape[1] == m - 1
        assert (order[made] == full.order[name][made]).all(), name
        tried = np.zeros(own.shape, bool)
        np.put_along_axis(tried, full.order[name], True, axis=1)
        assert not (tried & own).any(), name
    assert g.attrs["stages"]["evaluate"]["leakage"]["hidden"] is True
    copy = tmp_path / "leaky.zarr"
    shutil.copytree(store, copy)
    res = pr.run(copy, "stage=evaluate", "evaluate.exclude_own_constraints=false")
    assert res.returncode == 0, res.stderr
    g = zarr.open_group(copy, mode="r", use_consolidated=False)
    assert g["evaluation/order"].shape[2] == m
    assert g.attrs["stages"]["evaluate"]["leakage"] == {
        "own_constraint_rows": int(own.any(axis=1).sum()), "hidden": False}
    res = pr.run(copy, "stage=report", "report.renders=0", "report.repeats=1",
                 f"report.dir={tmp_path / 'r'}")
    assert res.returncode == 0, res.stderr
    assert "Leave-one-out WITH leakage" in (tmp_path / "r" / "report.md").read_text()


def test_report_writes_every_figure_and_a_self_contained_page(made):
    _, report = made
    for stem in ("fig3_first_feasible", "fig4_score_vs_time", "fig_learning_curve",
                 "fig_c_sensitivity", "fig_time_distribution", "fig_ratio_to_box"):
        for fmt in ("png", "svg"):
            assert (report / f"{stem}.{fmt}").stat().st_size > 5000
    renders = sorted((report / "renders").glob("*.png"))
    assert len(renders) == 3
    page = (report / "report.html").read_text()
    sources = re.findall(r'src="([^"]*)"', page)
    assert len(sources) == 6 + 3 and all(s.startswith("data:image/png;base64,") for s in sources)
    md = (report / "report.md").read_text()
    for stem in ("fig3_first_feasible.png", "fig4_score_vs_time.png", "renders/store0-"):
        assert stem in md


def test_report_tables_hold_the_store_s_numbers(made):
    store, report = made
    md = (report / "report.md").read_text()
    g, scores, feasible, times = matrix(store)
    dataset = md_table(md, "## Datasets")
    assert dataset[1][3:6] == ["24", "15", f"{feasible.mean():.1%}"]
    assert dataset[1][6] == f"{int(feasible.any(axis=1).sum())}/24"

    rows = {r[0]: r for r in md_table(md, "## Time to first feasible plan")[1:]}
    assert set(rows) == {"BOX", "CONTEXTUAL", "CONTEXTUAL+CAPS", "EIPS", "STATIC", "RAND", "DOO",
                         "PEM-BO", "ORACLE", "FASTEST", "RAWPLANNER"}
    assert float(rows["FASTEST"][2]) <= min(float(r[2]) for r in rows.values())
    assert "Leave-one-out without leakage" in md
    direct = box_core.loocv(scores, feasible=feasible, times=times, selectors=("box", "static"),
                            features=g["constraints/theta"][...], measure_overhead=False,
                            forbidden=own_columns(g))
    for name in ("box", "static"):
        line = direct.summary().line(name)
        row = rows[name.upper()]
        assert row[1] == f"{line.found}/{line.rows}"
        assert row[5] == f"{line.mean_tries:.3g}"  # tries do not depend on measured overhead
    eligible = feasible.any(axis=1)
    raw = np.where(g["raw/feasible"][...], g["raw/time"][...], np.nan)[eligible]
    assert float(rows["RAWPLANNER"][2]) == pytest.approx(np.nanmean(raw), rel=1e-3)


def test_report_learning_curve_and_c_tables_are_recomputable(made):
    store, report = made
    md = (report / "report.md").read_text()
    g, scores, feasible, times = matrix(store)
    own = own_columns(g)
    curve = box_core.learning_curve(scores, times=times, feasible=feasible,
                                    selectors=("box", "eips", "static"), seed=0, forbidden=own)
    table = md_table(md, "## Learning curve")[1:]
    assert len(table) == len(curve) == 12
    for row, point in zip(table, curve, strict=True):
        assert row[0] == point.selector.upper() and int(row[2]) == point.n_train
        assert float(row[3]) == pytest.approx(point.mean, rel=1e-3)
    tuning = box_core.tune_c(scores, times=times, feasible=feasible, seed=0, forbidden=own)
    sens = md_table(md, "## Sensitivity to C")[1:]
    assert [float(r[0]) for r in sens] == list(tuning.grid)
    for row, c in zip(sens, tuning.grid, strict=True):
        assert float(row[1]) == pytest.approx(tuning.sensitivity[c][0], rel=1e-3)
    tuned = md_table(md, "## Sensitivity to C", nth=1)[1]
    assert tuned[3] == ", ".join(f"{c:g}" for c in tuning.chosen)


def test_report_puts_several_stores_side_by_side_and_refuses_unevaluated_ones(made, tmp_path):
    store, _ = made
    other = tmp_path / "b.zarr"
    res = pr.run(other, "stage=generate", "planner.max_checks=1500")
    assert res.returncode == 0, res.stderr
    res = pr.run(other, "stage=report", f"report.stores=[{store},{other}]",
                 f"report.dir={tmp_path / 'r'}")
    assert res.returncode == 2
    assert "no evaluation yet" in res.stderr and str(other) in res.stderr
    assert not (tmp_path / "r" / "report.md").exists()
    res = pr.run(other, "stage=evaluate", "planner.max_checks=1500")
    assert res.returncode == 0, res.stderr
    res = pr.run(other, "stage=report", f"report.stores=[{store},{other}]", "report.renders=1",
                 f"report.dir={tmp_path / 'r'}")
    assert res.returncode == 0, res.stderr
    md = (tmp_path / "r" / "report.md").read_text()
    assert len(md_table(md, "## Datasets")) == 3
    # panels of the same domain and planner are told apart by the settings that differ
    panels = re.findall(r"### planar / rrt_connect \(max_checks=(\d+)\) \(24 x", md)
    assert len(panels) == 2 and "1500" in panels and len(set(panels)) == 2
    one = matplotlib.image.imread(made[1] / "fig3_first_feasible.png").shape[1]
    two = matplotlib.image.imread(tmp_path / "r" / "fig3_first_feasible.png").shape[1]
    assert two > 1.7 * one


def test_report_refuses_a_path_that_is_not_a_store(tmp_path):
    (tmp_path / "x.zarr").mkdir()
    (tmp_path / "x.zarr" / "notes.txt").write_text("mine")
    res = pr.run(tmp_path / "s.zarr", "stage=report", f"report.stores=[{tmp_path / 'x.zarr'}]")
    assert res.returncode == 2 and "not a score store" in res.stderr
    assert not (tmp_path / "s.zarr").exists()


# -- solve ------------------------------------------------------------------------------------
def solve(store, out, *extra):
    return pr.run(store, "stage=solve", "solve.n=4", "solve.max_evaluations=15",
                  f"solve.dir={out}", *extra)


def test_solve_runs_fresh_instances_live_and_saves_the_best_plans(made, tmp_path):
    store, _ = made
    res = solve(store, tmp_path / "s1")
    assert res.returncode == 0, res.stderr
    doc = json.loads((tmp_path / "s1" / "solve.json").read_text())
    seeds = [r["seed"] for r in doc["records"]]
    stored = zarr.open_array(store / "instances" / "seed", mode="r")[...]
    assert len(seeds) == 4 and not set(seeds) & set(stored.tolist())
    assert doc["training_rows"] == 24
    methods = {"BOX": "box", "CONTEXTUAL": "contextual", "CONTEXTUAL+CAPS": "contextual_capped",
               "EIPS": "eips", "STATIC": "static", "RAWPLANNER": "rawplanner"}
    for (name, key), row in zip(methods.items(), doc["table"]["rows"], strict=True):
        solved = sum(r["selectors"][key]["first_feasible_time"] is not None
                     for r in doc["records"])
        assert row[0] == name and row[1] == f"{solved}/4"
        assert name in res.stdout
    for k, rec in enumerate(doc["records"]):
        box = rec["selectors"]["box"]
        assert 1 <= len(box["tries"]) <= 15
        assert len({t["constraint"] for t in box["tries"]}) == len(box["tries"])
        if any(r["first_feasible_time"] is not None for r in rec["selectors"].values()):
            saved = np.load(tmp_path / "s1" / "plans" / f"instance{k:03d}.npz")
            assert saved["path"].shape[1] == 2 and float(saved["score"]) < 0
            assert (tmp_path / "s1" / "plans" / f"instance{k:03d}.png").exists()
    # the same command again: the same instances and the same constraints tried
    again = solve(store, tmp_path / "s2")
    assert again.returncode == 0, again.stderr
    doc2 = json.loads((tmp_path / "s2" / "solve.json").read_text())
    for a, b in zip(doc["records"], doc2["records"], strict=True):
        assert a["seed"] == b["seed"]
        for name in ("box", "eips", "static"):
            assert [t["constraint"] for t in a["selectors"][name]["tries"]] == \
                   [t["constraint"] for t in b["selectors"][name]["tries"]]


def test_solve_refuses_an_incomplete_store_unless_asked(made, tmp_path):
    store, _ = made
    copy = tmp_path / "part.zarr"
    shutil.copytree(store, copy)
    part = ScoreStore(copy)  # as the coordinator leaves it after an interruption
    stages = dict(part.attrs["stages"])
    for stage in ("scores", "evaluate"):
        stages.pop(stage)
    part.set_attrs(stages=stages)
    done = zarr.open_array(copy / "scores" / "done", mode="r+")
    mask = done[...]
    mask[6:12] = False  # one row block not computed yet, as after an interruption
    done[...] = mask
    before = pr.matrix(copy)
    res = solve(copy, tmp_path / "s")
    assert res.returncode == 2
    assert "incomplete" in res.stderr and "solve.use_incomplete=true" in res.stderr
    res = solve(copy, tmp_path / "s", "solve.use_incomplete=true", "solve.n=2")
    assert res.returncode == 0, res.stderr
    assert json.loads((tmp_path / "s" / "solve.json").read_text())["training_rows"] == 18
    assert pr.same_matrix(before, pr.matrix(copy))


@pytest.mark.parametrize("extra, message", [
    (("solve.selectors=[oracle]",), "oracle"),
    (("solve.selectors=[fastest]",), "fastest"),
    (("solve.selectors=[nope]",), "unknown selector"),
    (("solve.n=0",), "solve.n"),
])
def test_solve_refuses_bad_settings(made, tmp_path, extra, message):
    res = solve(made[0], tmp_path / "s", *extra)
    assert res.returncode == 2 and message in res.stderr


def test_solve_refuses_a_missing_store_without_creating_it(tmp_path):
    res = solve(tmp_path / "none.zarr", tmp_path / "s")
    assert res.returncode == 2 and "no store" in res.stderr
    assert not (tmp_path / "none.zarr").exists()
