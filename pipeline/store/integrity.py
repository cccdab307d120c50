"""Integrity records: what the coordinator wrote, so that any later change is found.

A chunk's existence proves nothing and a CRC32C only proves that a chunk is self-consistent,
so the coordinator records a digest of the *values* of every chunk it writes:

* **block groups** (``instances``, ``raw``, ``constraints``, ``scores``): one row per block
  in the table ``integrity/<group>`` (uint64, shape ``(*block grid, arrays)``, one chunk per
  block): the digest of each array's chunk of that block.  Row all zero: not recorded.
* **whole arrays** (coordinates, ``evaluation/*``): a digest of all values, in the
  ``integrity`` group's attribute ``arrays``.

Verification decodes each recorded chunk (a checksum failure or garbage counts as
``corrupted``), compares its digest (a different value counts as ``corrupted``: a flipped
byte that still decodes, a chunk replaced by another), and checks that the chunk object
exists (``missing``: a deleted chunk reads back as the fill value, which the digest also
catches unless the chunk held nothing but fill).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from pipeline.store.layout import INTEGRITY

GROUP = INTEGRITY
NOT_RECORDED = 0


def digest(values) -> int:
    """A 64-bit digest of an array's values, shape and dtype kind (never 0)."""
    arr = np.asarray(values)
    h = hashlib.blake2b(digest_size=8)
    h.update(repr(arr.shape).encode())
    if arr.dtype.kind in "OUST":
        h.update(b"str")
        for item in arr.reshape(-1):
            text = str(item).encode()
            h.update(len(text).to_bytes(8, "little"))
            h.update(text)
    else:
        h.update(arr.dtype.str.encode())
        h.update(np.ascontiguousarray(arr).tobytes())
    return int.from_bytes(h.digest(), "little") | 1


def combine(digests) -> str:
    """One hex digest of many (the digest of an array from its chunks' digests)."""
    h = hashlib.blake2b(digest_size=8)
    h.update(np.ascontiguousarray(np.asarray(digests, dtype="uint64")).tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class BlockLayout:
    """How a group is cut into blocks: ``dims`` are the block axes (``("instance",)``,
    ``("instance", "constraint")``); an array's chunk of block ``b`` has index ``b[axis]``
    along a block axis and 0 along any other dimension (arrays are chunked by the block
    size along block axes and whole along the others)."""

    group: str
    dims: tuple[str, ...]
    names: tuple[str, ...]

    def chunk_of(self, array_dims, block) -> tuple[int, ...]:
        return tuple(block[self.dims.index(d)] if d in self.dims else 0 for d in array_dims)


@dataclass
class Damage:
    """Damage found in one group: per array, the damaged blocks (chunk indices) by kind."""

    corrupted: dict[str, set] = field(default_factory=dict)
    missing: dict[str, set] = field(default_factory=dict)

    def add(self, kind: str, array: str, block) -> None:
        getattr(self, kind).setdefault(array, set()).add(tuple(block))

    @property
    def blocks(self) -> set:
        return set().union(*self.corrupted.values(), *self.missing.values())

    @property
    def arrays(self) -> list[str]:
        return sorted(self.corrupted.keys() | self.missing.keys())

    def __bool__(self) -> bool:
        return bool(self.corrupted or self.missing)

    def describe(self) -> str:
        parts = []
        for array in self.arrays:
            c, m = len(self.corrupted.get(array, ())), len(self.missing.get(array, ()))
            what = ", ".join(x for x in (f"{c} corrupted" if c else "",
                                         f"{m} missing" if m else "") if x)
            parts.append(f"{array} ({what})")
        return "; ".join(parts)
