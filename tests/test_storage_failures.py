"""Issue 24, case 6: every storage failure is one line with exit code 2, and nothing is
created (no store, no Hydra ``outputs/`` folder): missing credentials and an endpoint that
cannot be reached (S3), permission denied, and a truncated ``zarr.json`` (named, and for the
root one called damaged, never "not a score store made by this pipeline").  Exit code 1
stays what ``box status`` says of a damaged store it can read.

Real processes throughout: ``python -m pipeline`` and ``box`` as a user runs them, a real
``moto_server`` for S3, a closed port on 127.0.0.1 for an unreachable endpoint."""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from tests import pipeline_runs as pr
from tests.test_s3_store import BUCKET, s3  # noqa: F401 (the moto_server fixture)
from tests.test_store_disks import _as_nobody, open_dir  # noqa: F401 (open_dir: a fixture)

#: The smallest planar run: 2 x 2 blocks of 3 x 2 entries.
TINY = ("domain=planar", "instances.n=6", "constraints.m=4", "store.block_instances=3",
        "store.block_constraints=2", "progress=false", "cluster.n_workers=1",
        "planner.max_checks=2000")


def pipeline(store, *overrides: str) -> list[str]:
    return [sys.executable, "-m", "pipeline", *TINY, f"store.path={store}", *overrides]


def box(*args: str) -> list[str]:
    return [sys.executable, "-c", "from pipeline.cli import app; app()", *args]


def run(argv: list[str], cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True, cwd=cwd,
                          env={**pr.env(), **(env or {})}, timeout=300)


def one_line(res: subprocess.CompletedProcess, *words: str) -> str:
    """``res`` exited 2 with one line on stderr (pybullet's banner aside) holding ``words``."""
    assert res.returncode == 2, res.stdout + res.stderr
    lines = [ln for ln in res.stderr.strip().splitlines()
             if not ln.startswith("pybullet build time")]
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    for word in words:
        assert word in lines[0], res.stderr
    return lines[0]


def snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A finished tiny store; tests copy it."""
    store = tmp_path_factory.mktemp("tiny") / "tiny.zarr"
    res = run(pipeline(store, "stage=generate"), cwd=store.parent)
    assert res.returncode == 0, res.stderr
    return store


@pytest.fixture
def cwd(tmp_path) -> Path:
    """An empty folder to run in: Hydra would put its ``outputs/`` here."""
    path = tmp_path / "cwd"
    path.mkdir()
    return path


def closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # nothing listens once the socket is closed


# -- S3: an endpoint that cannot be reached, missing credentials ------------------------------
def test_an_unreachable_endpoint_is_one_line_exit_2_and_creates_nothing(cwd):
    endpoint = f"http://127.0.0.1:{closed_port()}"
    env = {"AWS_ENDPOINT_URL": endpoint, "AWS_ACCESS_KEY_ID": "testing",
           "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"}
    url = "s3://bucket/x.zarr"
    for argv in (pipeline(url, "stage=generate"), box("status", url),
                 box("export", url, "-o", str(cwd / "x.npz"))):
        one_line(run(argv, cwd, env), url, f"cannot connect to the storage endpoint {endpoint}",
                 "connection refused")
        assert list(cwd.iterdir()) == []  # no outputs/, no export


def test_missing_credentials_are_one_line_exit_2_and_create_nothing(s3, cwd, tmp_path):  # noqa: F811
    env = {k: v for k, v in pr.env().items()
           if k not in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_SESSION_TOKEN",
                        "AWS_PROFILE")}
    env.update(AWS_SHARED_CREDENTIALS_FILE=str(tmp_path / "none"),
               AWS_CONFIG_FILE=str(tmp_path / "none"),
               AWS_EC2_METADATA_DISABLED="true")  # no instance-metadata credentials either
    url = f"s3://{BUCKET}/nocreds.zarr"
    for argv in (pipeline(url, "stage=generate"), box("status", url)):
        res = subprocess.run(argv, capture_output=True, text=True, cwd=cwd, env=env,
                             timeout=300)
        one_line(res, url, "no usable AWS credentials")
        assert list(cwd.iterdir()) == []
    import s3fs

    listing = s3fs.S3FileSystem(endpoint_url=s3["AWS_ENDPOINT_URL"], skip_instance_cache=True)
    assert not listing.exists(f"{BUCKET}/nocreds.zarr")
    assert not listing.exists(f"{BUCKET}/nocreds.zarr.lock")


def test_a_missing_bucket_is_named_not_taken_for_a_store_in_use(s3, cwd):  # noqa: F811
    """Creating the lease in a bucket that does not exist fails like a lost race for it
    would (the object is "not found"); the run must say which bucket is missing."""
    url = "s3://no-such-bucket/x.zarr"
    line = one_line(run(pipeline(url, "stage=generate"), cwd), "s3://no-such-bucket",
                    "no such bucket")
    assert "in use" not in line


# -- truncated metadata ----------------------------------------------------------------------
def _truncated(tiny: Path, tmp_path: Path, key: str) -> Path:
    """A copy of ``tiny`` whose ``key`` is cut in half."""
    copy = tmp_path / "copy.zarr"
    shutil.copytree(tiny, copy)
    doc = copy / key
    doc.write_bytes(doc.read_bytes()[:doc.stat().st_size // 2])
    return copy


def _refused_everywhere(copy: Path, cwd: Path, *words: str) -> None:
    before = snapshot(copy)
    for argv in (box("status", str(copy)), box("export", str(copy), "-o", str(cwd / "x.npz")),
                 pipeline(copy, "stage=generate")):
        line = one_line(run(argv, cwd), *words)
        assert "not a score store made by this pipeline" not in line
        assert list(cwd.iterdir()) == []
        assert snapshot(copy) == before


def test_a_truncated_array_document_is_named_in_one_line(tiny, tmp_path, cwd):
    copy = _truncated(tiny, tmp_path, "scores/score/zarr.json")
    _refused_everywhere(copy, cwd, f"{copy}/scores/score/zarr.json", "unreadable metadata",
                        "truncated")


def test_a_truncated_root_document_is_damage_not_a_foreign_store(tiny, tmp_path, cwd):
    copy = _truncated(tiny, tmp_path, "zarr.json")
    _refused_everywhere(copy, cwd, f"{copy}/zarr.json", "unreadable metadata", "damaged")


# -- permissions (only an unprivileged user meets them) -------------------------------------
def test_a_store_that_cannot_be_read_is_one_line_exit_2(tiny, open_dir):  # noqa: F811
    copy = open_dir / "private.zarr"
    shutil.copytree(tiny, copy)
    for p in [copy, *copy.rglob("*")]:
        p.chmod(0o755 if p.is_dir() else 0o644)
    (copy / "scores" / "score" / "zarr.json").chmod(0o600)  # root's alone
    before = snapshot(copy)
    res = _as_nobody(pipeline(copy, "stage=generate"), open_dir / "cwd-nobody")
    one_line(res, f"{copy}/scores/score/zarr.json", "permission denied")
    res = _as_nobody(box("status", str(copy)), open_dir / "cwd-nobody")
    one_line(res, f"{copy}/scores/score/zarr.json", "permission denied")
    copy.chmod(0o700)  # not even listed
    res = _as_nobody(pipeline(copy, "stage=generate"), open_dir / "cwd-nobody")
    one_line(res, str(copy), "permission denied")
    assert list((open_dir / "cwd-nobody").iterdir()) == []
    assert snapshot(copy) == before
    assert not (open_dir / "private.zarr.lock").exists()
