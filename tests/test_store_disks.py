"""Read-only stores, full disks and symbolic links: re-running a finished store writes
nothing, a store that cannot be written ends with one line, a full disk resumes later, and a
store reached through a link is the same store (same lock)."""

import os
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from pipeline.store import StoreLock
from tests import pipeline_runs as pr


def _snapshot(root: Path) -> dict:
    return {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in sorted(root.rglob("*"))
            if p.is_file()}


def _ours(stderr: str) -> list[str]:
    """The lines of ``stderr`` that the pipeline wrote (pybullet's C library announces
    itself on import; Dask workers log the tasks cancelled when a run stops)."""
    return [line for line in stderr.strip().splitlines()
            if not line.startswith("pybullet build time") and " - distributed." not in line]


def _read_only(root: Path) -> None:
    for p in [root, *root.rglob("*")]:
        p.chmod(p.stat().st_mode & ~(stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH))


def _as_nobody(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``argv`` run as the unprivileged user nobody (writes to read-only files really
    fail), or a skip saying why that is impossible here."""
    setpriv = shutil.which("setpriv")
    if setpriv is None or os.geteuid() != 0:
        pytest.skip("needs root and setpriv to run a command as an unprivileged user")
    cmd = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups", *argv]
    probe = subprocess.run([*cmd[:4], sys.executable, "-c", "import pipeline.stages"],
                           capture_output=True, text=True, env=pr.env(), cwd=cwd)
    if probe.returncode != 0:  # the reason on one line: the error the import ended with
        error = (probe.stderr.strip().splitlines() or ["(no message)"])[-1]
        pytest.skip(f"user nobody cannot import the package here: {error}")
    return subprocess.run(cmd, capture_output=True, text=True, env=pr.env(), cwd=cwd,
                          timeout=600)


@pytest.fixture
def open_dir():
    """A folder every user may read (pytest's tmp_path is private to root)."""
    path = Path(tempfile.mkdtemp(prefix="box-ro-"))
    path.chmod(0o755)
    for cwd in ("cwd", "cwd-nobody"):  # Hydra's output folders land here
        (path / cwd).mkdir()
        (path / cwd).chmod(0o777)
    yield path
    for p in [path, *path.rglob("*")]:
        p.chmod(p.stat().st_mode | stat.S_IWUSR)
    shutil.rmtree(path)


def test_rerunning_a_finished_read_only_store_writes_nothing(made, open_dir):
    copy = open_dir / "ro.zarr"
    shutil.copytree(made[0], copy)
    _read_only(copy)
    before = _snapshot(copy)
    for stage in ("stage=generate", "stage=evaluate"):
        res = pr.run(copy, stage, cwd=open_dir / "cwd")  # as root: nothing may be written
        assert res.returncode == 0, res.stderr
        assert "already complete" in res.stdout and "dask:" not in res.stdout
    assert _snapshot(copy) == before
    assert not (open_dir / "ro.zarr.lock").exists()
    res = _as_nobody(pr.command(copy, "stage=generate"), open_dir / "cwd-nobody")
    assert res.returncode == 0, res.stderr
    assert "scores: already complete" in res.stdout
    assert _snapshot(copy) == before


def test_a_damaged_read_only_store_ends_with_one_line(made, open_dir):
    copy = open_dir / "ro.zarr"
    shutil.copytree(made[0], copy)
    chunk = copy / "scores" / "length" / "c" / "0" / "0"
    chunk.write_bytes(chunk.read_bytes()[:-4] + b"oops")
    _read_only(copy)
    open_dir.chmod(0o555)  # not even the lock file can be made
    before = _snapshot(copy)
    res = _as_nobody(pr.command(copy, "stage=generate"), open_dir / "cwd-nobody")
    assert res.returncode == 2, res.stdout + res.stderr
    assert "read-only" in res.stderr and "Traceback" not in res.stderr
    assert len(_ours(res.stderr)) == 1, res.stderr
    assert _snapshot(copy) == before
    open_dir.chmod(0o755)


def test_a_full_disk_ends_with_one_line_and_resumes_later(made, tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    mount = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=640k", "tmpfs", str(disk)],
                           capture_output=True, text=True)
    if mount.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {mount.stderr.strip()}")
    try:
        store = disk / "full.zarr"
        res = pr.run(store, "stage=generate", cwd=tmp_path)
        assert res.returncode == 2, res.stdout + res.stderr
        assert "no space left on the device" in res.stderr
        assert len(_ours(res.stderr)) == 1, res.stderr
        subprocess.run(["mount", "-o", "remount,size=32m", str(disk)], check=True)
        res = pr.run(store, "stage=generate", cwd=tmp_path)
        assert res.returncode == 0, res.stdout + res.stderr
        assert pr.same_matrix(pr.matrix(made[0]), pr.matrix(store))
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_a_store_through_a_symlink_is_the_same_store(tmp_path):
    real = tmp_path / "real.zarr"
    res = pr.run(real, "stage=instances")
    assert res.returncode == 0, res.stderr
    link = tmp_path / "link.zarr"
    link.symlink_to(real)
    with StoreLock(real):
        res = pr.run(link, "stage=instances", "instances.n=30")
    assert res.returncode == 2 and "in use by a running pipeline" in res.stderr
    res = pr.run(link, "stage=instances", "instances.n=30", "store.mode=overwrite")
    assert res.returncode == 0, res.stderr  # replaces the store the link points to
    assert link.is_symlink() and (real / "zarr.json").exists()
    assert '"n": 30' in (real / "zarr.json").read_text()
