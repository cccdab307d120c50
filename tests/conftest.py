"""Fixtures shared by several test modules."""

import pytest

from tests import pipeline_runs as pr


@pytest.fixture(scope="session")
def made(tmp_path_factory):
    """A small finished planar store (stage=all, which ends with the report) and its report
    folder.  Tests must not modify it (copy it first)."""
    root = tmp_path_factory.mktemp("made")
    store, report = root / "a.zarr", root / "report-a"
    res = pr.run(store, "stage=all", f"report.dir={report}")
    assert res.returncode == 0, res.stderr
    return store, report
