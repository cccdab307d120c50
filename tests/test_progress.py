"""Progress in entries: what running tasks report (``pipeline.entry_progress``) and how a
run shows it (``pipeline.progress``)."""

from __future__ import annotations

import io
import logging
import time
from pathlib import Path

from rich.console import Console

from pipeline.entry_progress import EntryCount, EntryReporter, counting
from pipeline.progress import EntryProgress, duration


def _until(condition, what: str) -> None:
    """Wait for ``condition`` (a guard against hanging, not a time limit on the code)."""
    for _ in range(6000):
        if condition():
            return
        time.sleep(0.05)
    raise AssertionError(f"never saw {what}")


def _reports_then_waits(entries: int, marker: str) -> str:
    """A block task on a worker: attempt 1 reports 7 entries and fails, attempt 2 reports 3
    and finishes; each waits for the test's go-ahead (a Dask Event) after reporting."""
    from distributed import Event

    from pipeline import entry_progress

    entry_progress.REPORT_EVERY_S = 0.0  # report every entry: the test waits on reports
    path = Path(marker)
    attempt = 2 if path.exists() else 1
    path.touch()
    reporter = EntryReporter()
    for _ in range(7 if attempt == 1 else 3):
        reporter.add()
    Event(f"{marker}-{attempt}").wait()
    if attempt == 1:
        raise RuntimeError("the first attempt fails after reporting")
    return "done"


def test_a_retried_task_s_reports_replace_those_of_its_failed_attempt(tmp_path):
    from distributed import Client, Event, LocalCluster

    marker = str(tmp_path / "attempted")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client, \
            counting(client, {"block": 10, "other": 5}) as count:
        future = client.submit(_reports_then_waits, 10, marker, key="block", retries=1,
                               pure=False)
        _until(lambda: count.shown == 7, "the first attempt's 7 entries")
        Event(f"{marker}-1", client=client).set()
        _until(lambda: count.shown == 3, "the retry's 3 entries in place of the 7")
        Event(f"{marker}-2", client=client).set()
        assert future.result() == "done"
        count.finish("block")
        assert (count.finished, count.shown) == (10, 10)


def test_counts_ignore_reports_of_finished_foreign_or_failed_tasks():
    count = EntryCount({"a": 10, "b": 4})
    count.report((0.0, {"key": "a", "done": 6}))
    count.report((0.0, {"key": "b", "done": 9}))  # never more than the block holds
    count.report((0.0, {"key": "another run's", "done": 3}))
    count.report((0.0, "not a report"))
    assert count.shown == 10
    count.finish("a")
    count.report((0.0, {"key": "a", "done": 8}))  # a late report of a finished block
    assert (count.finished, count.shown) == (10, 14)
    count.drop("b")  # failed for good: nothing of it was written
    assert (count.finished, count.shown) == (10, 10)


def test_outside_a_worker_the_reporter_only_counts():
    reporter = EntryReporter()
    reporter.add()
    reporter.add(4)
    assert reporter.done == 5


def _log_lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "pipeline"]


def test_off_a_terminal_lines_go_to_the_console_and_the_log(caplog):
    out = io.StringIO()
    caplog.set_level(logging.INFO, logger="pipeline")
    with EntryProgress("scores", 2400, Console(file=out, width=80), enabled=True,
                       every_s=0.0) as shown:
        shown.update(1234)
        shown.update(2400)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("scores: 1234/2400 entries (51%), ") and " ETA " in lines[0]
    assert lines[-1].startswith("scores: 2400/2400 entries (100%), ") and "took" in lines[-1]
    assert _log_lines(caplog) == lines


def test_on_a_terminal_a_bar_shows_the_entries_and_the_log_gets_the_lines(caplog):
    out = io.StringIO()
    caplog.set_level(logging.INFO, logger="pipeline")
    console = Console(file=out, width=100, force_terminal=True, force_interactive=True)
    with EntryProgress("scores", 2400, console, enabled=True, every_s=0.0) as shown:
        shown.update(1234)
    assert "1234/2400" in out.getvalue() and "scores: " not in out.getvalue()
    assert _log_lines(caplog)[0].startswith("scores: 1234/2400 entries (51%)")


def test_progress_off_shows_nothing(caplog):
    out = io.StringIO()
    caplog.set_level(logging.INFO, logger="pipeline")
    with EntryProgress("scores", 10, Console(file=out), enabled=False, every_s=0.0) as shown:
        shown.update(5)
    assert out.getvalue() == "" and _log_lines(caplog) == []


def test_durations_read_as_a_person_says_them():
    assert [duration(s) for s in (4, 59, 360, 7500)] == ["4 s", "59 s", "6 min", "2 h 05 min"]
