"""The report's learning curve and C tuning as jobs started before the report
(``pipeline.report.jobs``): ``stage=all`` starts them beside ``evaluate``."""

from __future__ import annotations

import json
import os
import threading
import time

import numpy as np
import pytest

import box_core
from pipeline.cluster import available_cores
from pipeline.report.jobs import JobsBeside, LoocvJob, store_jobs
from tests import pipeline_runs as pr

SETTINGS = {"fractions": [0.5, 1.0], "repeats": 2, "c_grid": [0.0, 1.96], "c_folds": 2}


def _jobs(scores, **changed):
    args = {"times": np.ones_like(scores), "feasible": scores < 0, "forbidden": None,
            "seed": 0, "failure_rule": "magnitude", "evaluated": ["box", "static"],
            "settings": SETTINGS, **changed}
    return store_jobs(scores, **args)


def test_a_job_is_known_by_every_input():
    rng = np.random.default_rng(0)
    scores = np.where(rng.random((12, 5)) < 0.5, -rng.random((12, 5)), 0.0)
    curve, tuning = _jobs(scores)
    assert curve.key != tuning.key
    assert [j.key for j in _jobs(scores.copy())] == [curve.key, tuning.key]  # equal arrays
    other = scores.copy()
    other[3, 2] = np.nextafter(other[3, 2], 1.0)
    changed = [_jobs(other), _jobs(scores, seed=1), _jobs(scores, failure_rule="min"),
               _jobs(scores, forbidden=np.eye(12, 5, dtype=bool)),
               _jobs(scores, settings={**SETTINGS, "c_grid": [0.0, 2.0]}),
               _jobs(scores, settings={**SETTINGS, "repeats": 3}),
               _jobs(scores, evaluated=["box"])]
    for jobs in changed:
        assert jobs[0].key != curve.key or jobs[1].key != tuning.key
    assert _jobs(scores, evaluated=["box"])[1].key == tuning.key  # the tuning is BOX's only
    assert curve.kwargs["selectors"] == ["box", "static"]


def test_jobs_beside_give_what_the_function_gives_here_at_the_lowest_priority():
    rng = np.random.default_rng(1)
    scores = np.where(rng.random((15, 6)) < 0.4, -rng.random((15, 6)), 0.0)
    curve, tuning = _jobs(scores)
    beside = JobsBeside(2, niceness=19)
    try:
        beside.start(curve)
        beside.start(tuning)
        priority = LoocvJob(os.nice, 0, {})  # os.nice(0): the process's niceness
        beside.start(priority)
        assert beside.has(curve) and beside.has(tuning)
        here_curve = box_core.learning_curve(scores, **curve.kwargs)
        assert beside.result(curve) == here_curve
        there, here = beside.result(tuning), box_core.tune_c(scores, **tuning.kwargs)
        assert there.sensitivity == here.sensitivity and there.chosen == here.chosen
        np.testing.assert_array_equal(there.tuned, here.tuned)
        assert beside.result(priority) == min(19, os.nice(0) + 19)
    finally:
        beside.close()


def test_closing_stops_a_job_that_still_runs():
    beside = JobsBeside(1)
    beside.start(LoocvJob(time.sleep, 3600, {}))
    closing = threading.Thread(target=beside.close)
    closing.start()
    closing.join(timeout=120)  # a guard against a hang, not a measurement
    assert not closing.is_alive(), "close() waited for the running job"


def test_stage_all_starts_the_report_s_jobs_beside_evaluate_with_the_report_s_numbers(
        made_run, tmp_path):
    """The session's stage=all run took its learning curve and C tuning from the jobs it
    started beside evaluate (it says so: a difference in how their inputs were derived would
    silently compute both again); stage=report on the same store computes them itself (the
    curve in a second process, C here): the same numbers, bit for bit."""
    if available_cores() < 2:
        pytest.skip("one core: stage=all starts nothing beside evaluate")
    store, report, res = made_run
    out = res.stdout + res.stderr
    assert out.count("learning curve and C tuning start now, beside evaluate") == 1
    assert out.index("beside evaluate") < out.index(f"report: {report}")  # before the report
    # ... and the report took both: their inputs, derived before evaluate, are its own
    assert "report: 2 of its 2 leave-one-out jobs were started beside evaluate" in out
    again = pr.run(store, "stage=report", f"report.dir={tmp_path / 'r'}")
    assert again.returncode == 0, again.stderr
    assert "beside evaluate" not in again.stdout + again.stderr
    early = json.loads((report / "report.json").read_text())
    late = json.loads((tmp_path / "r" / "report.json").read_text())
    [(key, a)], [(_, b)] = early.items(), late.items()
    assert a["learning_curve"] == b["learning_curve"] and a["learning_curve"]
    assert a["c_tuning"] == b["c_tuning"] and a["c_tuning"]["chosen"], key
