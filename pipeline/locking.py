"""The run lock: one writing run per store.

* Local stores: ``flock`` on ``<resolved store>.lock``; the kernel releases it when the
  holder dies, so a killed run never keeps it (unlike POSIX record locks, closing another
  descriptor of the file does not drop it).  The lock sits next to the store: inside, zarr
  would see a foreign object.  A lock is only held on the file that is at that path: an
  acquirer checks after locking that the file it locked is still the one there (else it
  locks the new one), and the holder removes the file when it releases it, so removing the
  file by hand cannot let a second run in unnoticed.
* Object stores: a lease object ``<store>.lock`` holding its owner (a random token, host,
  pid) and a heartbeat that a thread renews; it is created with a conditional put (only if
  absent), and a lease whose heartbeat is older than :data:`LEASE_SECONDS`, or whose holder
  ran on this host and is gone, is taken over.

Fencing: a writer calls :meth:`StoreLock.check` before each write (the store does, in
``ScoreStore.write_block`` and when it records a stage).  A holder whose lock file was
removed takes it again unless another run holds it by then; a holder whose lease was taken
over (it was paused, or its heartbeat failed) stops.  Either way a run that is no longer
the only writer stops before writing, with one line.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import threading
import time
import uuid

from pipeline.errors import LockError
from pipeline.location import Location

LOCK_SUFFIX = ".lock"
#: A lease not renewed for this long belongs to a dead run.
LEASE_SECONDS = 60.0


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


class LeaseLock:
    """A lease object next to a store in object storage (see the module docstring)."""

    def __init__(self, location: Location, lease_seconds: float = LEASE_SECONDS):
        self.store = location
        self.fs, self.key = location.sibling(LOCK_SUFFIX).filesystem()
        self.lease_seconds = lease_seconds
        self.token = uuid.uuid4().hex
        self.since = _now()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lost: str | None = None  # why we no longer hold the lease, once we know

    def _lease(self) -> bytes:
        return json.dumps({"owner": self.token, "host": socket.gethostname(),
                           "pid": os.getpid(), "since": self.since,
                           "heartbeat": time.time()}).encode()

    def _read(self) -> dict | None:
        try:
            return json.loads(self.fs.cat_file(self.key))
        except FileNotFoundError:
            return None
        except ValueError:
            return {"owner": "?", "heartbeat": 0.0}  # unreadable: as good as expired

    def _stale(self, lease: dict) -> bool:
        if time.time() - float(lease.get("heartbeat", 0.0)) > self.lease_seconds:
            return True
        if lease.get("host") == socket.gethostname():
            try:
                os.kill(int(lease["pid"]), 0)
            except ProcessLookupError:
                return True  # its holder ran here and is gone
            except (OSError, KeyError, ValueError):
                return False
        return False

    def _create(self) -> bool:
        """Put our lease only if there is none; False when one exists."""
        try:
            self.fs.pipe_file(self.key, self._lease(), mode="create")
        except FileExistsError:
            return False
        except OSError as exc:  # some servers answer 412 without naming the condition
            if exc.errno == errno.EINVAL and self.fs.exists(self.key):
                return False
            raise
        return True

    def acquire(self) -> None:
        for _ in range(3):
            if self._create():
                self._thread = threading.Thread(target=self._beat, daemon=True,
                                                name="store-lease")
                self._thread.start()
                return
            lease = self._read()
            if lease is not None and not self._stale(lease):
                raise _in_use(self.store, _describe(lease))
            if lease is not None:
                self.fs.rm_file(self.key)  # a dead run's lease; the next create decides
        raise _in_use(self.store, "another run took the lease meanwhile")

    def _beat(self) -> None:
        while not self._stop.wait(self.lease_seconds / 4):
            try:
                lease = self._read()
                if lease is None or lease.get("owner") != self.token:
                    self._lost = "its lease was taken over (this run was presumed dead)"
                    return  # stop touching it; check() stops the writer
                self.fs.pipe_file(self.key, self._lease())
            except Exception as exc:  # noqa: BLE001 (any failure to renew: fence the writer)
                self._lost = f"renewing its lease failed ({type(exc).__name__}: {exc})"
                return

    def check(self) -> None:
        """Fencing: stop (LockError) unless the lease is still ours (one read per call)."""
        if self._lost is None:
            try:
                lease = self._read()
            except Exception as exc:  # noqa: BLE001
                lease, why = None, f"its lease cannot be read ({type(exc).__name__}: {exc})"
            else:
                why = "its lease was taken over (this run was presumed dead)"
            if lease is None or lease.get("owner") != self.token:
                self._lost = why
        if self._lost is not None:
            raise _lost(self.store, self._lost)

    def release(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
            lease = self._read()
            if lease is not None and lease.get("owner") == self.token:
                self.fs.rm_file(self.key)

    def held_by_other(self) -> str | None:
        lease = self._read()
        if lease is None or lease.get("owner") == self.token or self._stale(lease):
            return None
        return _describe(lease)


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
        from pipeline.location import locate

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

    def __enter__(self):
        self.acquire()
        return self

    def __exit__(self, *exc):
        self.release()
