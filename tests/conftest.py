"""Fixtures shared by several test modules."""

import pytest

from tests import pipeline_runs as pr


@pytest.fixture(scope="session")
def made_run(tmp_path_factory):
    """The one ``stage=all`` run of the small planar store per session: (store, report
    folder, the finished process, with its output).  Every test that needs this run's D, its
    output or its report shares it; tests must not modify the store (copy it first)."""
    root = tmp_path_factory.mktemp("made")
    store, report = root / "a.zarr", root / "report-a"
    res = pr.run(store, "stage=all", f"report.dir={report}")
    assert res.returncode == 0, res.stderr + res.stdout
    return store, report, res


@pytest.fixture(scope="session")
def made(made_run):
    """A small finished planar store (stage=all, which ends with the report) and its report
    folder.  Tests must not modify it (copy it first)."""
    store, report, _ = made_run
    return store, report
