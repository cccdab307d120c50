"""Where a store lives: a local folder or a URL that zarr reaches through fsspec.

``store.path`` accepts a local path, ``file:///abs/path`` or a URL of any filesystem that
fsspec knows and whose package is installed (``s3://bucket/runs/x.zarr`` with ``s3fs``,
``gs://`` with ``gcsfs``, ...).  Credentials and endpoints come the way those libraries'
users expect: the standard environment (``AWS_ENDPOINT_URL``, ``AWS_ACCESS_KEY_ID``,
``AWS_SECRET_ACCESS_KEY``, ``AWS_DEFAULT_REGION``, ...) plus ``store.storage_options``, passed
to the filesystem unchanged.  Local paths are resolved (symbolic links followed), so a store
reached through a link is the same store, with the same lock, as its target.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

from pipeline.store.errors import LocationError
from pipeline.store.storage_errors import translated

#: botocore settings for S3 unless configured (``store.storage_options.config_kwargs``, or
#: ``AWS_RETRY_MODE``/``AWS_MAX_ATTEMPTS`` for retries): AWS's "standard" retry mode (3
#: attempts with jittered exponential backoff, for throttling, 5xx answers and connection
#: errors) instead of botocore's "legacy" one (5 attempts; about 9 s before an unreachable
#: endpoint is reported), and a 5 s connect timeout instead of 60 s, so an endpoint that
#: cannot be reached ends the command with one line within seconds.
S3_CONFIG = {"connect_timeout": 5, "retries": {"mode": "standard"}}

#: s3fs reads an object whole in one GET only when its ``max_concurrency`` is 1; above 1 (its
#: default, 10) it first asks for the object's size (a HEAD, and for a missing object a
#: listing too), to split large objects into concurrent ranged reads.  A store's objects
#: are small (documents, compressed chunks of one block), so that split never happens and
#: the extra requests doubled every read's round trips.  ``store.storage_options`` may set
#: another value.
S3_READ_CONCURRENCY = 1


class URL(str):
    """A store URL that reads like a path where callers need one (``.name``, ``/ child``)."""

    @property
    def name(self) -> str:
        return self.rstrip("/").rsplit("/", 1)[-1]

    def __truediv__(self, child: str) -> URL:
        return URL(f"{self.rstrip('/')}/{child}")


@dataclass(frozen=True)
class Location:
    """A store's place: ``local`` (a resolved Path) or ``url`` with its fsspec options."""

    local: Path | None = None
    url: str | None = None
    storage_options: dict = field(default_factory=dict)

    @property
    def path(self) -> Path | URL:
        """How the store is named to users and to code that treats it like a path."""
        return self.local if self.local is not None else URL(self.url)

    def __str__(self) -> str:
        return str(self.path)

    @property
    def name(self) -> str:
        return self.path.name

    # -- zarr and fsspec ------------------------------------------------------------------
    def zarr_store(self, read_only: bool):
        from zarr.storage import FsspecStore, LocalStore

        if self.local is not None:
            return LocalStore(self.local, read_only=read_only)
        return FsspecStore.from_url(self.url, storage_options=self._fsspec_options(),
                                    read_only=read_only)

    def options(self) -> dict:
        """fsspec options: the configured ones, and for s3 the endpoint from the environment
        (``AWS_ENDPOINT_URL_S3`` / ``AWS_ENDPOINT_URL``) when none is configured."""
        opts = dict(self.storage_options)
        if self.scheme in ("s3", "s3a"):
            endpoint = os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get(
                "AWS_ENDPOINT_URL")
            if endpoint and "endpoint_url" not in opts and "endpoint_url" not in opts.get(
                    "client_kwargs", {}):
                opts["endpoint_url"] = endpoint
        return opts

    def _fsspec_options(self) -> dict:
        """:meth:`options`, for s3 with :data:`S3_CONFIG` and :data:`S3_READ_CONCURRENCY`
        where not configured."""
        opts = self.options()
        if self.scheme in ("s3", "s3a"):
            config = dict(opts.get("config_kwargs") or {})
            config.setdefault("connect_timeout", S3_CONFIG["connect_timeout"])
            if not (os.environ.get("AWS_RETRY_MODE") or os.environ.get("AWS_MAX_ATTEMPTS")):
                config.setdefault("retries", S3_CONFIG["retries"])
            opts["config_kwargs"] = config
            opts.setdefault("max_concurrency", S3_READ_CONCURRENCY)
        return opts

    @property
    def scheme(self) -> str:
        return "file" if self.local is not None else urlsplit(self.url).scheme

    def filesystem(self):
        """(fsspec filesystem, path inside it) of a URL location."""
        from fsspec import url_to_fs

        return url_to_fs(self.url, **self._fsspec_options())

    # -- existence (the first touches of the storage: a failure is one StoreError line) -----
    def exists(self) -> bool:
        with translated(self):
            if self.local is not None:
                return self.local.exists() or self.local.is_symlink()
            fs, path = self.filesystem()
            return fs.exists(path)

    def is_empty(self) -> bool:
        """Nothing there (or an empty folder)."""
        with translated(self):
            if self.local is not None:
                return not self.local.exists() or (self.local.is_dir()
                                                   and not any(self.local.iterdir()))
            fs, path = self.filesystem()
            return not fs.exists(path) or not fs.ls(path)

    def sibling(self, suffix: str) -> Location:
        """``<store><suffix>`` next to the store (where its lock lives)."""
        if self.local is not None:
            return Location(local=self.local.with_name(self.local.name + suffix))
        return Location(url=self.url.rstrip("/") + suffix, storage_options=self.storage_options)


def locate(path, storage_options: dict | None = None) -> Location:
    """The Location of ``store.path`` (a refusal names the path and what is wrong)."""
    if isinstance(path, Location):
        return path
    text = str(path)
    parts = urlsplit(text)
    scheme = parts.scheme.lower()
    if scheme == "" or (len(scheme) == 1 and os.name == "nt"):
        return Location(local=Path(text).expanduser().absolute().resolve())
    if scheme == "file":
        if parts.netloc not in ("", "localhost"):
            raise LocationError(f"store.path {text!r}: file URLs name a local path "
                                "(file:///absolute/path)")
        return Location(local=Path(parts.path).resolve())
    try:
        from fsspec import get_filesystem_class

        get_filesystem_class(scheme)
    except ValueError:
        raise LocationError(f"store.path {text!r}: unknown scheme {scheme!r}; give a local "
                            "path, file:///path or a URL fsspec supports (s3://bucket/x.zarr)"
                            ) from None
    except ImportError as exc:
        raise LocationError(f"store.path {text!r}: the {scheme}:// filesystem needs a package "
                            f"that is not installed ({str(exc).splitlines()[0]})") from None
    if not parts.netloc:
        raise LocationError(f"store.path {text!r}: a {scheme}:// URL needs a bucket or host")
    return Location(url=text.rstrip("/"), storage_options=dict(storage_options or {}))
