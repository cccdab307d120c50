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


def test_off_a_terminal_progress_lines_count_entries_inside_a_block(tmp_path):
    """Standard output is a pipe here: progress comes as lines, on it and in the run log.
    One block of 40 x 15 entries on one worker: a count between 0 and 600 can only come
    from the entries the worker reports while it computes the block."""
    import re

    res = pr.run(tmp_path / "a.zarr", "stage=generate", "instances.n=40", "constraints.m=15",
                 "store.block_instances=40", "store.block_constraints=15",
                 "cluster.n_workers=1", "progress=true", "progress_every=0.01")
    assert res.returncode == 0, res.stderr
    log = next((tmp_path / "outputs").glob("*/*/__main__.log")).read_text()
    lines = re.findall(r"scores: \d+/600 entries .*", log)
    assert lines == re.findall(r"scores: \d+/600 entries .*", res.stdout)
    counts = [int(re.match(r"scores: (\d+)/", line).group(1)) for line in lines]
    assert any(0 < k < 600 for k in counts), lines
    assert counts == sorted(counts) and lines[-1].startswith("scores: 600/600 entries (100%)")
    assert "took" in lines[-1] and re.search(r"raw: 40/40 entries \(100%\)", res.stdout)
