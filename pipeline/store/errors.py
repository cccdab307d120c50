"""The store's error types (one module, so that every store module can raise them)."""


class StoreError(Exception):
    """A store that cannot be used as asked (its message says why; exit code 2)."""


class LocationError(StoreError, ValueError):
    """``store.path`` cannot name a store (unknown scheme, missing filesystem package)."""


class LockError(StoreError):
    """The store is in use by another run."""


class StoreDamaged(Exception):
    """``status`` found damage (the store is readable; a re-run repairs what it can)."""
