"""Writing the block groups: their arrays, coordinates and integrity tables, each finished
block (data chunks, then its integrity row, then ``done``), groups computed whole, and the
``done`` masks.  A part of :class:`pipeline.store.ScoreStore`."""

from __future__ import annotations

import numpy as np
import zarr

from pipeline.store.errors import StoreError
from pipeline.store.integrity import BlockLayout, digest
from pipeline.store.layout import (
    BLOCK_DIMS,
    ENVIRONMENT,
    RESULT_COLUMNS,
    UNKNOWN_ENVIRONMENT,
    dims_of_coords,
    done_key,
    result_attrs,
    result_key,
    table_key,
)


def block_region(block: tuple[int, ...], chunks: tuple[int, ...]) -> tuple[slice, ...]:
    """The index region of chunk ``block`` (clipped by numpy at the array's edge)."""
    return tuple(slice(b * c, (b + 1) * c) for b, c in zip(block, chunks, strict=True))


def _shape(region: tuple[slice, ...], shape) -> tuple[int, ...]:
    return tuple(len(range(*s.indices(n))) for s, n in zip(region, shape, strict=True))



class BlockWrites:
    """The block groups' writers (a mixin of :class:`pipeline.store.ScoreStore`)."""

    def create_results(self, group: str, shape, chunks, dims, domain, extra=(),
                       coords: dict | None = None) -> None:
        """The per-entry result arrays of ``group``, its ``done`` mask, coordinates and
        integrity table.  ``domain``: the store's domain (its planning steps, which ``step``
        indexes, and its units); ``extra``: (name, shape, chunks, dtype, fill, dims, attrs)
        of further result arrays; ``coords``: name -> (dims, values, attrs) of coordinate
        arrays."""
        coords = coords or {}
        names = []
        described = result_attrs(domain)
        for name, col in RESULT_COLUMNS.items():
            self.create(f"{group}/{name}", shape, chunks, col.dtype, col.fill, dims,
                        **described[name])
            names.append(name)
        for name, shp, chk, dtype, fill, dms, attrs in extra:
            self.create(f"{group}/{name}", shp, chk, dtype, fill, dms, **attrs)
            names.append(name)
        self.create_environment(group, shape, chunks, dims)
        names.append(ENVIRONMENT)
        self.create(done_key(group), shape, chunks, "bool", False, dims,
                    description="entries whose block finished (written by the coordinator)")
        names.append("done")
        self.write_coords(group, coords, names)
        self.create_table(group, [*names, *coords])

    def create_environment(self, group: str, shape, chunks, dims) -> zarr.Array:
        """``group``'s environment array, every chunk written as -1 (not recorded)."""
        arr = self.create(
            result_key(group, ENVIRONMENT), shape, chunks, "int16", UNKNOWN_ENVIRONMENT, dims,
            description="index into the root attribute 'environments' of the environment "
                        "that computed the entry's block; -1: not recorded (computed before "
                        "layout 3)")
        if not self.metadata_only:
            arr[...] = UNKNOWN_ENVIRONMENT
        return arr

    def write_coords(self, group: str, coords: dict, data_names) -> None:
        """Coordinate arrays of ``group`` (chunked like the block axes), named in each data
        array's ``coordinates`` attribute so that xarray makes them coordinates."""
        for name, (dims, values, attrs) in coords.items():
            values = np.asarray(values)
            chunks = (self._block_size(group, dims[0], len(values)),)  # 1-D coordinates
            dtype = str if values.dtype.kind in "OUT" else values.dtype
            fill = "" if dtype is str else (np.nan if values.dtype.kind == "f" else 0)
            arr = self.create(f"{group}/{name}", values.shape, chunks, dtype, fill, dims,
                              **attrs)
            if not self.metadata_only:
                arr[...] = values
        listed = " ".join(n for n in coords if n not in dims_of_coords(coords))
        if listed:
            for name in data_names:
                self.array(f"{group}/{name}").attrs["coordinates"] = listed

    def _block_size(self, group: str, dim: str, length: int) -> int:
        if dim in BLOCK_DIMS.get(group, ()):
            ref = self._reference_array(group)
            return ref.chunks[list(ref.metadata.dimension_names).index(dim)]
        return max(length, 1)

    def _reference_array(self, group: str) -> zarr.Array:
        for name in ("done", "theta", "seed"):
            if self.has(f"{group}/{name}"):
                return self.array(f"{group}/{name}")
        raise KeyError(f"{group} has no array to take block sizes from")

    # -- blocks and integrity ------------------------------------------------------------
    def layout(self, group: str) -> BlockLayout:
        table = self.array(table_key(group))
        return BlockLayout(group, tuple(table.attrs["block_dims"]),
                           tuple(table.attrs["arrays"]))

    def has_table(self, group: str) -> bool:
        return self.has(table_key(group))

    def create_table(self, group: str, names) -> None:
        """An empty integrity table for the block group ``group`` covering ``names``."""
        dims = BLOCK_DIMS[group]
        ref = self._reference_array(group)
        ref_dims = list(ref.metadata.dimension_names)
        grid = tuple(ref.cdata_shape[ref_dims.index(d)] for d in dims)
        self.create(table_key(group), (*grid, len(names)),
                    (*(1,) * len(grid), len(names)), "uint64", 0,
                    (*(f"{d}_block" for d in dims), f"{group}_array"),
                    block_dims=list(dims), arrays=list(names),
                    description="digest of each array's chunk per block (0: not recorded)")

    def grid(self, group: str) -> tuple[int, ...]:
        return self.array(table_key(group)).shape[:-1]

    def _chunk(self, layout: BlockLayout, name: str, block) -> tuple[zarr.Array, tuple]:
        arr = self.array(f"{layout.group}/{name}")
        return arr, layout.chunk_of(arr.metadata.dimension_names, block)

    def write_block(self, group: str, block, arrays: dict[str, np.ndarray]) -> None:
        """Write one finished block: data chunks, then its integrity row, then ``done``."""
        self.fence()
        layout = self.layout(group)
        row = np.zeros(len(layout.names), dtype="uint64")
        done_region = None
        for k, name in enumerate(layout.names):
            arr, chunk = self._chunk(layout, name, block)
            region = block_region(chunk, arr.chunks)
            if name == "done":
                done_region = region
                values = np.ones(_shape(region, arr.shape), dtype=bool)
            elif name in arrays:
                values = np.asarray(arrays[name], dtype=arr.dtype)
                arr[region] = values
            else:  # a coordinate, written at creation
                values = arr.blocks[chunk]
            row[k] = digest(values)
        self.array(table_key(group))[tuple(block)] = row
        if done_region is not None:
            self.array(done_key(group))[done_region] = True

    def record_blocks(self, group: str, blocks=None) -> None:
        """Record the digests of ``blocks`` (all) as they are now (for groups written
        whole by the coordinator, right after writing them)."""
        layout = self.layout(group)
        table = self.array(table_key(group))
        rows = np.zeros(table.shape, dtype="uint64") if blocks is None else table[...]
        for block in (np.ndindex(*table.shape[:-1]) if blocks is None else blocks):
            for k, name in enumerate(layout.names):
                arr, chunk = self._chunk(layout, name, block)
                rows[tuple(block) + (k,)] = digest(arr.blocks[chunk])
        table[...] = rows

    def set_done(self, group: str, region: tuple[slice, ...], value: bool = True) -> None:
        self.array(done_key(group))[region] = value

    def forget_blocks(self, group: str, blocks) -> None:
        """Mark ``blocks`` as not computed (integrity row cleared first, then ``done``)."""
        table = self.array(table_key(group))
        chunks = self.array(done_key(group)).chunks
        for block in blocks:
            table[tuple(block)] = 0
            self.set_done(group, block_region(block, chunks), False)


    def write_whole(self, group: str, arrays: dict[str, np.ndarray], make, changed) -> None:
        """Write a group computed whole (``make()`` creates its arrays and table when absent;
        ``changed()``: whether the inputs it was computed from changed since).

        Over an existing, recorded group only damaged or unrecorded blocks are rewritten, and
        only when the values computed again agree with the recorded digests: otherwise the
        group is refused, naming the array (computing it again does not give what was stored).
        """
        if not self.has_table(group) or self.stage_info(group) is None \
                or changed() or self.missing_arrays(group):
            make()
            for name, values in arrays.items():
                self.array(f"{group}/{name}")[...] = values
            self.record_blocks(group)
            return
        layout = self.layout(group)
        table = self.array(table_key(group))
        damaged = self.verify(group, expect_all=True).blocks
        for block in np.ndindex(*self.grid(group)):
            try:
                row = table.blocks[(*block, 0)].reshape(-1)
            except Exception:  # noqa: BLE001 (an unreadable record: rewritten below)
                row = np.zeros(len(layout.names), dtype="uint64")
            fresh = []
            for k, name in enumerate(layout.names):
                arr = self.array(f"{group}/{name}")
                chunk = layout.chunk_of(arr.metadata.dimension_names, block)
                values = arrays[name][block_region(chunk, arr.chunks)]
                fresh.append(digest(values))
                if row[k] and row[k] != fresh[-1]:
                    raise StoreError(f"{group}/{name}: block {block} is damaged and computing "
                                     "it again from its seeds gives different values; the "
                                     "store cannot be repaired: regenerate it "
                                     "(store.mode=overwrite or another store.path)")
            if block in damaged or not np.all(row):
                for name in layout.names:
                    arr = self.array(f"{group}/{name}")
                    region = block_region(layout.chunk_of(arr.metadata.dimension_names, block),
                                          arr.chunks)
                    arr[region] = arrays[name][region]
                table[block] = np.array(fresh, dtype="uint64")
