"""The run lock: one writing run per store.

* Local stores: ``flock`` on ``<resolved store>.lock``; the kernel releases it when the
  holder dies, so a killed run never keeps it (unlike POSIX record locks, closing another
  descriptor of the file does not drop it).  The lock sits next to the store: inside, zarr
  would see a foreign object.  A lock is only held on the file that is at that path: an
  acquirer checks after locking that the file it locked is still the one there (else it
  locks the new one), and the holder removes the file when it releases it, so removing the
  file by hand cannot let a second run in unnoticed.
* Object stores: a lease object ``<store>.lock`` holding its owner (a random token, host,
  pid), its lifetime (:func:`lease_setting`, 60 s by default) and a heartbeat that a thread
  renews every quarter of it.  A lease whose heartbeat is older than its lifetime, or whose
  holder ran on this host and is gone, is taken over.  In S3 every write of the lease is
  conditional on the version its writer last saw (``If-None-Match: *`` to create it,
  ``If-Match: <ETag>`` to renew, take over or delete it), so the server lets only one of
  two writers through: a holder that was presumed dead can never renew over its successor,
  and two takers of one expired lease never both get it.

Fencing: a writer calls :meth:`StoreLock.check` before each write (the store does, in
``ScoreStore.write_block`` and when it records a stage).  A holder whose lock file was
removed takes it again unless another run holds it by then; a holder whose lease was taken
over (it was paused, or its heartbeat failed) stops.  Either way a run that is no longer
the only writer stops before writing, with one line.  A check and the writes after it are
separate requests: a run paused between them for longer than its lease still finishes that
one block or record (no storage here can refuse a write by a stale holder).
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
import socket
import threading
import time
import uuid

from pipeline.store.errors import LockError, StoreError
from pipeline.store.location import Location

LOCK_SUFFIX = ".lock"
#: A lease not renewed for this long belongs to a dead run (the default lifetime).
LEASE_SECONDS = 60.0
#: The environment variable that sets the lifetime of the leases a run takes, in seconds.
LEASE_ENV = "PIPELINE_LEASE_SECONDS"


def lease_setting() -> float:
    """The lifetime of the leases this process takes: ``$PIPELINE_LEASE_SECONDS`` or
    :data:`LEASE_SECONDS`.  A lease records its lifetime and takers judge it by that, so
    runs with different settings still agree on when a lease has expired.  A shorter one
    frees a dead run's store sooner, and is lost by a run paused (or cut off from the
    storage) for longer than it; a run renews its lease every quarter of its lifetime."""
    text = os.environ.get(LEASE_ENV, "").strip()
    if not text:
        return LEASE_SECONDS
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < float("inf"):
        raise LockError(f"{LEASE_ENV}={text!r}: give the lifetime of a store's lease in "
                        f"seconds (a number > 0; default {LEASE_SECONDS:g})")
    return value


def _in_use(location: Location, holder: str) -> LockError:
    return LockError(f"store {location} is in use by a running pipeline ({holder}); "
                     "wait for it or stop it first")


def _now() -> str:
    import datetime as dt

    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


class FileLock:
    """``flock`` on ``<resolved store path>.lock``."""

    def __init__(self, location: Location):
        self.store = location
        self.path = location.local.with_name(location.local.name + LOCK_SUFFIX)
        self._fd: int | None = None

    def acquire(self) -> None:
        for _ in range(100):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = os.read(fd, 4096).decode(errors="replace").strip() or "another process"
                os.close(fd)
                raise _in_use(self.store, holder) from None
            if self._is_at_path(fd):
                break
            os.close(fd)  # the file was removed after we opened it: lock the one there now
        else:
            raise _in_use(self.store, "its lock file keeps being replaced")
        os.ftruncate(fd, 0)
        os.write(fd, f"pid {os.getpid()} on {socket.gethostname()} since {_now()}".encode())
        self._fd = fd

    def _is_at_path(self, fd: int) -> bool:
        """Whether the open file ``fd`` is the file at the lock's path."""
        try:
            there = os.stat(self.path)
        except FileNotFoundError:
            return False
        mine = os.fstat(fd)
        return (there.st_dev, there.st_ino) == (mine.st_dev, mine.st_ino)

    def check(self) -> None:
        """Fencing: the lock file was removed or replaced since we locked it?  Take the
        file there again, or stop (LockError) when another run holds it."""
        if self._fd is None or self._is_at_path(self._fd):
            return
        os.close(self._fd)
        self._fd = None
        try:
            self.acquire()
        except LockError:
            raise _lost(self.store, "its lock file was removed and another run locked it "
                                    "since") from None

    def release(self) -> None:
        if self._fd is not None:
            if self._is_at_path(self._fd):
                os.unlink(self.path)  # while locked: an acquirer that opened it retries
            os.close(self._fd)  # closing drops the lock
            self._fd = None

    def held_by_other(self) -> str | None:
        """Who holds the lock, or None (opens the file read-only: works on read-only
        stores, and creates nothing)."""
        try:
            fd = os.open(self.path, os.O_RDONLY)
        except FileNotFoundError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError:
            return os.read(fd, 4096).decode(errors="replace").strip() or "another process"
        finally:
            os.close(fd)
        return None


class _Conflict(Exception):
    """A conditional write or delete was refused: the object is not the one we named."""


def _is_conflict(exc: BaseException) -> bool:
    """Whether a storage error means "precondition failed" (412, s3fs: EINVAL or
    FileExistsError), "no such object" (an If-Match on an object gone) or "conflicting
    conditional write" (409)."""
    if isinstance(exc, FileExistsError | FileNotFoundError):
        return True
    text = str(exc)
    return (isinstance(exc, OSError) and exc.errno in (errno.EINVAL, errno.EBUSY)) or \
        "PreconditionFailed" in text or "ConditionalRequestConflict" in text


class _S3Object:
    """The lease object in S3 (s3fs), read with its ETag and written only conditionally:
    ``If-None-Match: *`` creates it only where there is none, ``If-Match: <ETag>`` replaces
    or deletes it only while it is the version that ETag names.  The server decides, so of
    two writers that saw the same version only one succeeds."""

    def __init__(self, fs, key: str):
        self.fs = fs
        self.bucket, self.path, _ = fs.split_path(key)

    def get(self) -> tuple[bytes, str] | None:
        """(content, ETag) of the object, read in one request, or None."""
        from fsspec.asyn import sync

        async def read():
            try:
                resp = await self.fs._call_s3("get_object", Bucket=self.bucket, Key=self.path)
            except FileNotFoundError:
                return None
            try:
                return await resp["Body"].read(), resp["ETag"]
            finally:
                resp["Body"].close()

        return sync(self.fs.loop, read)

    def put(self, data: bytes, if_match: str | None) -> str:
        """Write ``data`` where the object is the version ``if_match`` (None: where there is
        none); its new ETag, or _Conflict."""
        condition = {"IfMatch": if_match} if if_match else {"IfNoneMatch": "*"}
        try:
            out = self.fs.call_s3("put_object", Bucket=self.bucket, Key=self.path, Body=data,
                                  **condition)
        except OSError as exc:
            if if_match is None and isinstance(exc, FileNotFoundError):
                # creating "where there is none" cannot miss its object: the bucket is missing
                raise StoreError(f"s3://{self.bucket}: no such bucket ({exc}); create it "
                                 "first, or name another one in store.path") from None
            if _is_conflict(exc):
                raise _Conflict(str(exc)) from None
            raise
        return out["ETag"]

    def delete(self, if_match: str) -> None:
        """Delete the object if it is still the version ``if_match``, else leave it."""
        try:
            self.fs.call_s3("delete_object", Bucket=self.bucket, Key=self.path,
                            IfMatch=if_match)
        except OSError as exc:
            if not _is_conflict(exc):
                raise


class _FsObject:
    """The lease object in another fsspec filesystem: the same protocol, its conditions
    checked by reading first (a version is the MD5 of the content, which is unique per
    write), so not atomic: only a server's conditional writes (:class:`_S3Object`) make
    two holders impossible."""

    def __init__(self, fs, key: str):
        self.fs, self.key = fs, key

    def get(self) -> tuple[bytes, str] | None:
        try:
            data = self.fs.cat_file(self.key)
        except FileNotFoundError:
            return None
        return data, hashlib.md5(data).hexdigest()

    def put(self, data: bytes, if_match: str | None) -> str:
        if if_match is None:
            try:
                self.fs.pipe_file(self.key, data, mode="create")
            except FileExistsError:
                raise _Conflict("it exists") from None
        else:
            there = self.get()
            if there is None or there[1] != if_match:
                raise _Conflict("it changed")
            self.fs.pipe_file(self.key, data)
        return hashlib.md5(data).hexdigest()

    def delete(self, if_match: str) -> None:
        there = self.get()
        if there is not None and there[1] == if_match:
            self.fs.rm_file(self.key)


class LeaseLock:
    """A lease object next to a store in object storage (see the module docstring).

    The lease is only ever written conditionally on the version its writer last saw
    (:class:`_S3Object`): created only where there is none, renewed only while it is the
    version this holder wrote last, taken over only while it is the expired version the
    taker read, and deleted only while it is ours.  So a holder paused past its lease (or
    whose renewals failed) can never renew over its successor, and of two takers of one
    expired lease only one gets it."""

    def __init__(self, location: Location, lease_seconds: float | None = None):
        self.store = location
        fs, key = location.sibling(LOCK_SUFFIX).filesystem()
        self.object = _S3Object(fs, key) if hasattr(fs, "call_s3") else _FsObject(fs, key)
        self.lease_seconds = lease_seconds if lease_seconds is not None else lease_setting()
        self.token = uuid.uuid4().hex
        self.since = _now()
        self._etag: str | None = None  # the version of the lease we wrote last
        self._renewed = 0.0  # when (time.monotonic) that write succeeded
        self._mutex = threading.Lock()  # one renewal at a time (heartbeat and check)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lost: str | None = None  # why we no longer hold the lease, once we know
        #: whose expired lease :meth:`acquire` replaced (its holder, in words), if any
        self.took_over: str | None = None

    def _lease(self) -> bytes:
        return json.dumps({"owner": self.token, "host": socket.gethostname(),
                           "pid": os.getpid(), "since": self.since, "heartbeat": time.time(),
                           "lease_seconds": self.lease_seconds}).encode()

    def _read(self) -> tuple[dict, str] | None:
        """(lease, its version), or None where there is none."""
        found = self.object.get()
        if found is None:
            return None
        data, etag = found
        try:
            lease = json.loads(data)
        except ValueError:
            lease = None
        if not isinstance(lease, dict):
            lease = {"owner": "?", "heartbeat": 0.0}  # unreadable: as good as expired
        return lease, etag

    def _stale(self, lease: dict) -> bool:
        """Expired by the lifetime its holder declared (older leases: ours), or held by a
        process of this host that is gone.  A paused holder is alive: only time expires
        its lease."""
        try:
            seconds = float(lease.get("lease_seconds", self.lease_seconds))
            age = time.time() - float(lease.get("heartbeat", 0.0))
        except (TypeError, ValueError):
            return True
        if age > seconds:
            return True
        if lease.get("host") == socket.gethostname():
            try:
                os.kill(int(lease["pid"]), 0)
            except ProcessLookupError:
                return True  # its holder ran here and is gone
            except (OSError, KeyError, ValueError):
                return False
        return False

    def acquire(self) -> None:
        for _ in range(3):
            found = None
            try:
                self._etag = self.object.put(self._lease(), if_match=None)
            except _Conflict:
                found = self._read()
                if found is None:
                    continue  # released meanwhile: create it again
                lease, etag = found
                if not self._stale(lease):
                    raise _in_use(self.store, _describe(lease)) from None
                try:  # a dead run's lease: replace that very version, or another taker did
                    self._etag = self.object.put(self._lease(), if_match=etag)
                except _Conflict:
                    continue
                self.took_over = _describe(lease)
            self._renewed = time.monotonic()
            self._thread = threading.Thread(target=self._beat, daemon=True, name="store-lease")
            self._thread.start()
            return
        raise _in_use(self.store, "another run took the lease meanwhile")

    def renew(self) -> None:
        """Write a new heartbeat where the lease is still the version we wrote last; when it
        is not (taken over, or removed) or the write fails, the lease is lost for good and
        :meth:`check` stops the writer."""
        with self._mutex:
            if self._lost is not None:
                return
            if self._etag is None:
                self._lost = "it holds no lease (never taken, or released)"
                return
            try:
                self._etag = self.object.put(self._lease(), if_match=self._etag)
            except _Conflict:
                self._lost = "its lease was taken over (this run was presumed dead)"
            except Exception as exc:  # noqa: BLE001 (any failure to renew: fence the writer)
                self._lost = f"renewing its lease failed ({type(exc).__name__}: {exc})"
            else:
                self._renewed = time.monotonic()

    def _beat(self) -> None:
        while not self._stop.wait(self.lease_seconds / 4) and self._lost is None:
            self.renew()

    def check(self) -> None:
        """Fencing: stop (LockError) unless the lease is still ours.  One request: where the
        heartbeat is late (this process was paused, or its heartbeat thread stalled) the
        lease is renewed first, conditionally, so a run never writes on a lease that may
        have expired; otherwise it is read."""
        if self._lost is None:
            if time.monotonic() - self._renewed > self.lease_seconds / 2:
                self.renew()
            else:
                try:
                    found = self._read()
                except Exception as exc:  # noqa: BLE001
                    self._lost = f"its lease cannot be read ({type(exc).__name__}: {exc})"
                else:
                    if found is None or found[0].get("owner") != self.token:
                        self._lost = "its lease was taken over (this run was presumed dead)"
        if self._lost is not None:
            raise _lost(self.store, self._lost)

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        with self._mutex:
            if self._etag is not None and self._lost is None:
                self.object.delete(if_match=self._etag)  # only while it is ours
            self._etag = None

    def held_by_other(self) -> str | None:
        found = self._read()
        if found is None or found[0].get("owner") == self.token or self._stale(found[0]):
            return None
        return _describe(found[0])


def _lost(location: Location, why: str) -> LockError:
    return LockError(f"store {location}: this run is no longer its only writer: {why}; it "
                     "stops before writing again (finished blocks are kept; re-run the same "
                     "command to resume once the other run ends)")


def _describe(lease: dict) -> str:
    age = time.time() - float(lease.get("heartbeat", 0.0))
    return (f"pid {lease.get('pid', '?')} on {lease.get('host', '?')} since "
            f"{lease.get('since', '?')}, heartbeat {age:.0f} s ago")


class StoreLock:
    """The lock of the store at ``location`` (a path, URL or Location)."""

    def __init__(self, location):
        from pipeline.store.location import locate

        location = locate(location)
        self._impl = FileLock(location) if location.local is not None else LeaseLock(location)

    @property
    def path(self):
        return getattr(self._impl, "path", None)

    def acquire(self) -> None:
        self._impl.acquire()

    def release(self) -> None:
        self._impl.release()

    def check(self) -> None:
        """Fencing: LockError when this holder is no longer the only writer."""
        self._impl.check()

    def held_by_other(self) -> str | None:
        return self._impl.held_by_other()

    @property
    def took_over(self) -> str | None:
        """Whose expired lease this lock replaced when it was taken (a run presumed dead),
        in words; None otherwise (and always for a local store: the kernel frees the
        lock of a process that ends)."""
        return getattr(self._impl, "took_over", None)

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()
