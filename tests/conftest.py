"""Fixtures shared by several test modules."""

from pathlib import Path

import pytest

from tests import pipeline_runs as pr

ROOT = Path(__file__).resolve().parents[1]

#: The slowest test files, slowest first (pytest --durations=0 on the 2-core machine,
#: 2026-11-24: from about 120 s down to 30 s each).  pytest-xdist's ``--dist loadfile`` hands
#: each worker the next file in collection order once it is nearly done
#: (``--no-loadscope-reorder`` in pyproject.toml keeps that order), so with the long files
#: first the two workers end together instead of one running a long file alone at the end.
#: Files not listed keep their order, after these.
SLOWEST_FIRST = (
    "tests/test_s3_store.py", "tests/test_domain_contract.py",
    "tests/test_metadata_campaign.py", "tests/test_report_solve.py", "tests/test_pipeline.py",
    "tests/cluster/test_address.py", "tests/test_integrity.py", "tests/test_fencing_s3.py",
    "tests/test_provenance.py", "tests/test_plugins.py", "tests/test_storage_failures.py",
    "tests/test_instance_features.py", "tests/cluster/test_slurm.py",
    "tests/test_bad_inputs.py", "tests/test_store_disks.py", "tests/test_mobile_domains.py",
    "tests/test_store_refusals.py", "tests/test_metadata_cases.py", "tests/test_replay.py",
    "tests/test_dataset.py",
)


def pytest_collection_modifyitems(items):
    missing = [name for name in SLOWEST_FIRST if not (ROOT / name).is_file()]
    if missing:
        raise pytest.UsageError(f"tests/conftest.py: SLOWEST_FIRST names no file {missing}")
    rank = {name: i for i, name in enumerate(SLOWEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))  # stable


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


@pytest.fixture
def second_takes_odd_pieces(monkeypatch):
    """box_core.loocv's ``workers=2`` with this process taking only the even pieces of work
    it gets to first, so the second process surely takes the odd ones (and any even one it
    reaches first).  The list gets, for each second process, the pieces it returned."""
    import importlib

    module = importlib.import_module("box_core.loocv")  # the package's loocv is the function
    real_take, real_result = module._Claims.take, module._ChildResult.result
    taken = []

    def evens(claims, i):
        return i % 2 == 0 and real_take(claims, i)

    def counted(child):
        theirs = real_result(child)
        taken.append(sorted(theirs))
        return theirs

    monkeypatch.setattr(module._Claims, "take", evens)
    monkeypatch.setattr(module._ChildResult, "result", counted)
    return taken
