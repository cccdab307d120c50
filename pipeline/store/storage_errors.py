"""Storage failures as one line: what could not be reached or read, and why.

Every way the storage itself can fail (no credentials, credentials refused, an endpoint
that cannot be reached, permission denied, a ``zarr.json`` that Zarr cannot read:
truncated, not JSON, values Zarr refuses) ends a command with one :class:`StoreError` line
naming the store, object or endpoint, and exit code 2.  Exit code 1 stays reserved for
damage ``box status`` finds in a store it can read.

:func:`storage_error` maps the exceptions that s3fs/aiobotocore/botocore, fsspec and the
OS raise to such a line; :func:`translated` applies it to a block of code;
:func:`check_metadata` reads every ``zarr.json`` of a store once, so that one that cannot
be read is named (Zarr itself raises a bare ``JSONDecodeError`` that names no file).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os

from pipeline.store.errors import StoreError

#: botocore ClientError codes that mean the credentials were refused (not missing).
REFUSED_CREDENTIALS = {"InvalidAccessKeyId", "SignatureDoesNotMatch", "ExpiredToken",
                       "InvalidToken", "TokenRefreshRequired", "AuthFailure"}


def _chain(exc: BaseException):
    """``exc`` and the exceptions it was raised from or while handling, in order."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        yield exc
        exc = exc.__cause__ or exc.__context__


def _botocore():
    try:
        from botocore import exceptions
    except ImportError:  # no S3 support installed: no botocore errors either
        return None
    return exceptions


def _first_line(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    return lines[0] if lines else type(exc).__name__


def _why(exc: BaseException) -> str | None:
    """What went wrong with the storage, in words, or None when ``exc`` is no storage
    failure (a bug, bad input, an interrupted run...)."""
    chain = list(_chain(exc))
    boto = _botocore()
    for e in chain:
        if boto is None:
            break
        if isinstance(e, (boto.NoCredentialsError, boto.PartialCredentialsError,
                          boto.CredentialRetrievalError)):
            return ("no usable AWS credentials found (set AWS_ACCESS_KEY_ID and "
                    "AWS_SECRET_ACCESS_KEY, or AWS_PROFILE, or pass them in "
                    f"store.storage_options): {_first_line(e)}")
        if isinstance(e, boto.ConnectionError):
            url = str(getattr(e, "kwargs", {}).get("endpoint_url") or "")
            endpoint = "/".join(url.split("/", 3)[:3]) if "://" in url else "the endpoint"
            cause = next((c for c in chain if isinstance(c, OSError) and c.errno), None)
            reason = os.strerror(cause.errno).lower() if cause else _first_line(e)
            return (f"cannot connect to the storage endpoint {endpoint} ({reason}); check "
                    "AWS_ENDPOINT_URL or store.storage_options.endpoint_url")
        if isinstance(e, boto.ClientError):
            code = e.response.get("Error", {}).get("Code", "")
            if code in REFUSED_CREDENTIALS:
                return f"the storage refused the credentials ({code}: {_first_line(e)})"
            if code in ("AccessDenied", "403", "AllAccessDisabled"):
                return f"access denied ({_first_line(e)})"
            return f"storage request failed ({_first_line(e)})"
        if isinstance(e, boto.BotoCoreError):
            return f"storage request failed ({_first_line(e)})"
    if any(isinstance(e, PermissionError) for e in chain):
        return "permission denied"  # (named by its file where it has one: storage_error)
    from fsspec.exceptions import FSTimeoutError

    if any(isinstance(e, FSTimeoutError) for e in chain):
        return "the storage did not answer in time"
    return None


def storage_error(exc: BaseException, where) -> StoreError | None:
    """One line for storage failure ``exc`` met at ``where`` (a store, object or URL, as
    users name it), or None when ``exc`` is no storage failure."""
    if isinstance(exc, StoreError):
        return exc
    why = _why(exc)
    if why is None:
        return None
    denied = next((e for e in _chain(exc) if isinstance(e, PermissionError) and e.filename), None)
    return StoreError(f"{denied.filename if denied else where}: {why}")


@contextlib.contextmanager
def translated(where):
    """Run the block; a storage failure in it is raised again as a one-line StoreError."""
    try:
        yield
    except StoreError:
        raise
    except Exception as exc:
        problem = storage_error(exc, where)
        if problem is None:
            raise
        raise problem from None


# -- metadata --------------------------------------------------------------------------------
def metadata_error(path, exc: Exception) -> StoreError:
    """The StoreError for a ``zarr.json`` at ``path`` that cannot be read."""
    if isinstance(exc, FileNotFoundError):
        why = "missing"
    elif isinstance(exc, json.JSONDecodeError):
        why = f"truncated or not JSON: {exc}"
    elif isinstance(exc, UnicodeDecodeError):
        why = "not UTF-8 text"
    else:
        why = f"not valid Zarr metadata: {_first_line(exc)}"
    return StoreError(f"{path}: unreadable metadata ({why}); the store is damaged and "
                      "nothing was changed: restore this file or make the store again")


def parse_metadata(raw: bytes, path) -> dict:
    """The JSON of a ``zarr.json``, checked as Zarr reads it (StoreError naming ``path``
    when Zarr could not read it: truncated, not JSON, or values Zarr refuses, such as a fill
    value its data type cannot hold).  Whether readable values are the ones the store's
    layout needs is :mod:`pipeline.store.metadata`'s to check (and to repair)."""
    from zarr.core.group import GroupMetadata
    from zarr.core.metadata import ArrayV3Metadata

    try:
        doc = json.loads(raw.decode("utf-8"))
        if not isinstance(doc, dict):
            raise ValueError("not a JSON object")
        if doc.get("node_type") == "array":
            ArrayV3Metadata.from_dict(dict(doc))
        elif doc.get("node_type") == "group":
            GroupMetadata.from_dict({k: v for k, v in doc.items() if k != "node_type"})
        else:
            raise ValueError(f"node_type {doc.get('node_type')!r} is neither array nor group")
    except Exception as exc:  # noqa: BLE001 - Zarr raises many types for bad metadata
        raise metadata_error(path, exc) from None
    return doc


def has_nodes(location, names) -> bool:
    """Whether any of the groups or arrays ``names`` (at the top of the store at
    ``location``) has a ``zarr.json``."""
    from zarr.core.sync import sync

    zstore = location.zarr_store(read_only=True)
    with translated(location):
        return any(sync(zstore.exists(f"{name}/zarr.json")) for name in names)


def check_metadata(location, zstore=None) -> None:
    """Read every ``zarr.json`` of the store at ``location`` (a
    :class:`pipeline.store.location.Location`; through ``zstore`` when given): the root's,
    then each group's children's, concurrently per group (in object storage that is one
    listing per group and one request per node, never a listing of the chunks).  StoreError
    naming the first that Zarr cannot read (:func:`parse_metadata`) or the storage failure
    met."""
    from zarr.core.buffer import default_buffer_prototype
    from zarr.core.sync import sync

    if zstore is None:
        zstore = location.zarr_store(read_only=True)

    async def node(prefix: str) -> None:
        key = f"{prefix}zarr.json"
        with translated(location.path / key):
            raw = await zstore.get(key, prototype=default_buffer_prototype())
            if raw is None:
                return  # not a node (a folder of chunks, or a node removed: status says)
            doc = parse_metadata(raw.to_bytes(), location.path / key)
            if doc.get("node_type") != "group":
                return
            children = [c async for c in zstore.list_dir(prefix) if c != "zarr.json"]
        await asyncio.gather(*(node(f"{prefix}{c}/") for c in children))

    sync(node(""))
