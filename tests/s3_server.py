"""A real S3-compatible server process for tests on 127.0.0.1: moto's server app, as its
standalone ``moto_server`` runs it, handling one request at a time
(tests/moto_atomic_server.py), configured the way AWS users expect (environment
variables), readers of stores in it, and a record of the requests this process sends.  Test
modules make their own fixture of :func:`serve` (module-scoped)."""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import zarr

BUCKET = "box-test"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _tail(log, lines: int = 3) -> str:
    """The last lines a process wrote to the file ``log``."""
    log.seek(0)
    return " | ".join(log.read().decode(errors="replace").strip().splitlines()[-lines:])


@contextlib.contextmanager
def serve():
    """The server's environment (AWS_ENDPOINT_URL, credentials) with a fresh bucket
    :data:`BUCKET`, also set in this process's environment (for its readers: zarr, ``box
    status``, ``box export``) while the server runs.  Skips the test when moto or s3fs is
    not installed."""
    if shutil.which("moto_server") is None:
        pytest.skip('moto_server is not installed (pip install -e ".[test]")')
    pytest.importorskip("s3fs", reason='s3fs is not installed (pip install -e ".[test]")')
    port = free_port()
    # moto's server app, one request at a time: S3's atomic conditional writes (see there);
    # its log goes to a file (it logs every request), whose end says why it exited, if it did
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name(
        "moto_atomic_server.py")), "127.0.0.1", str(port)],
                            stdout=subprocess.DEVNULL, stderr=log)
    env = {"AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}", "AWS_ACCESS_KEY_ID": "testing",
           "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1"}
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)
    try:
        deadline = time.monotonic() + 60
        while True:
            assert proc.poll() is None, f"moto_server exited: {_tail(log)}"
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "moto_server did not start listening"
                time.sleep(0.1)
        import s3fs

        s3fs.S3FileSystem(endpoint_url=env["AWS_ENDPOINT_URL"]).mkdir(BUCKET)
        yield env
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        log.close()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _group(url: str) -> zarr.Group:
    from pipeline.store.location import locate

    return zarr.open_group(store=locate(url).zarr_store(read_only=True), mode="r",
                           use_consolidated=False)


def matrix(url: str) -> dict:
    """The deterministic part of D (everything but times) of the store at ``url``."""
    g = _group(url)
    return {name: g[f"scores/{name}"][...] for name in ("score", "feasible", "status", "checks",
                                                         "length", "step")}


def done(url: str) -> int:
    """Entries of ``scores`` whose block is done (0 before the array exists)."""
    try:
        return int(_group(url)["scores/done"][...].sum())
    except Exception:  # noqa: BLE001 (not created yet)
        return 0


@contextlib.contextmanager
def requests_sent():
    """(operation, key) of every request this process sends to S3 while inside, recorded
    where s3fs hands each to botocore (the server answers them all)."""
    import s3fs

    sent: list[tuple[str, str]] = []
    send = s3fs.S3FileSystem._call_s3

    async def recorded(self, method, *args, **kwargs):
        sent.append((method, kwargs.get("Key") or kwargs.get("Prefix") or ""))
        return await send(self, method, *args, **kwargs)

    s3fs.S3FileSystem._call_s3 = recorded
    try:
        yield sent
    finally:
        s3fs.S3FileSystem._call_s3 = send


def read_object(key: str) -> bytes:
    """The bytes of object ``key`` of :data:`BUCKET`."""
    import s3fs

    return s3fs.S3FileSystem(endpoint_url=os.environ["AWS_ENDPOINT_URL"]).cat_file(
        f"{BUCKET}/{key}")
