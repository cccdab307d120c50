"""Hydra's run log (``outputs/<date>/<time>/__main__.log``) records what a run says, the
terminal gets each message once, and a refusal after the run started is logged too."""

from __future__ import annotations

from tests import pipeline_runs as pr


def test_the_run_log_holds_every_stage_message_and_the_terminal_one_copy(tmp_path):
    store = tmp_path / "a.zarr"
    res = pr.run(store, "stage=generate", "instances.n=6", "constraints.m=4")
    assert res.returncode == 0, res.stderr
    logs = list((tmp_path / "outputs").glob("*/*/__main__.log"))
    assert len(logs) == 1
    text = logs[0].read_text()
    for line in ("instances: sampled 6 planar instances", "raw: RAWPLANNER solved",
                 "constraints: ", "scores: 6 x 4 complete"):
        assert line in text and line in res.stdout, line
    assert "[INFO]" not in res.stdout + res.stderr
    assert res.stdout.count("scores: 6 x 4 complete") == 1


def test_a_refusal_after_the_run_started_is_logged(made, tmp_path):
    import shutil

    store = tmp_path / "a.zarr"
    shutil.copytree(made[0], store)
    (store / "scores" / "score" / "c" / "1" / "1").unlink()
    res = pr.run(store, "stage=status")
    assert res.returncode == 1
    text = next((tmp_path / "outputs").glob("*/*/__main__.log")).read_text()
    assert "[ERROR] - damaged: store" in text
