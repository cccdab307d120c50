"""The store's layout in one place: every array of the block groups (``instances``, ``raw``,
``constraints``, ``scores``) and of ``integrity``, with its shape, chunk grid, data type,
codecs, fill value, dimension names and attributes, as a function of the store's identity.

The stages create their groups with :func:`create`, and :func:`expected` runs the same
function against an in-memory store that records metadata only: what a store of this
identity must hold, document by document, whatever the store on disk now says.  That is
what :mod:`pipeline.metadata` checks every ``zarr.json`` against and rewrites them from.
"""

from __future__ import annotations

import json
from typing import NamedTuple

import numpy as np

from pipeline import integrity
from pipeline.store import (
    INSTANCE_SEED,
    INSTANCE_SPEC,
    SOURCE_INSTANCE,
    THETA,
    ScoreStore,
    feature_coord,
    index_coord,
    instance_coord,
    source_coord,
)

#: The groups whose layout follows from the identity, in the order the stages make them.
GROUPS = ("instances", "raw", "constraints", "scores")


class Size(NamedTuple):
    """What a store's shapes follow from: n instances, m constraints (as the constraints
    stage kept them), and the block sizes."""

    n: int
    m: int
    block_instances: int
    block_constraints: int


def size_of(attrs: dict) -> Size:
    """The :class:`Size` of a store from its root attributes (its identity and the
    constraints stage's record; m is the requested count until that stage has run)."""
    ident = attrs["identity"]
    kept = ((attrs.get("stages") or {}).get("constraints") or {}).get("m")
    return Size(int(ident["instances"]["n"]),
                int(kept if kept is not None else ident["constraints"]["m"]),
                int(ident["store.block_instances"]), int(ident["store.block_constraints"]))


def coords(group: str, domain, size: Size, seeds=None, sources=None) -> dict:
    """The coordinates of ``group``: name -> (dims, values, attributes).  ``seeds`` and
    ``sources`` give the values of ``instance_seed`` and ``constraint_source`` (zeros
    when only the metadata matters)."""
    seeds = np.zeros(size.n, dtype="int64") if seeds is None else seeds
    sources = np.zeros(size.m, dtype="int64") if sources is None else sources
    if group == "instances":
        return index_coord("instance", size.n, "instance index")
    if group == "raw":
        return {**instance_coord(seeds), **feature_coord(domain)}
    if group == "constraints":
        return {**index_coord("constraint", size.m, "constraint index"),
                **feature_coord(domain)}
    return {**instance_coord(seeds), **source_coord(sources)}


def create(store: ScoreStore, group: str, domain, size: Size, group_coords: dict) -> None:
    """Create ``group``'s arrays, coordinates and integrity table (no values but the
    coordinates'), replacing whatever was there."""
    n, m, b, bc = size
    p = domain.n_features
    if group == "instances":
        store.create(INSTANCE_SEED, (n,), (b,), "int64", 0, ("instance",),
                     long_name="seed the instance was sampled from")
        store.create(INSTANCE_SPEC, (n,), (b,), str, "", ("instance",),
                     long_name="instance spec, JSON text")
        store.write_coords(group, group_coords, ["seed", "spec"])
        store.create_table(group, ["seed", "spec", *group_coords])
    elif group == "constraints":
        store.create(THETA, (m, p), (bc, p), "float64", np.nan, ("constraint", "feature"),
                     long_name="features of the constraint θ; units: feature_units")
        store.create(SOURCE_INSTANCE, (m,), (bc,), "int64", -1, ("constraint",),
                     long_name="instance whose raw solution gave it; -1: a fixed set")
        store.write_coords(group, group_coords, ["theta", "source_instance"])
        store.create_table(group, ["theta", "source_instance", *group_coords])
    elif group == "raw":
        extra = [("tries", (n,), (b,), "int32", 0, ("instance",), {}),
                 ("constraint", (n, p), (b, p), "float64", np.nan, ("instance", "feature"),
                  {"long_name": "constraint θ extracted from the raw solution (NaN: none); "
                                "units: feature_units"})]
        store.create_results(group, (n,), (b,), ("instance",), domain, extra, group_coords)
    else:
        store.create_results(group, (n, m), (b, bc), ("instance", "constraint"), domain,
                             coords=group_coords)


def expected(attrs: dict, domain, groups) -> dict[str, dict]:
    """The metadata document (``zarr.json``, parsed) of every node of ``groups`` and of the
    ``integrity`` tables that cover them, for a store with root attributes ``attrs``
    (``domain``: the one its identity names).  A fresh copy each call; the documents of one
    identity are derived once per process."""
    size = size_of(attrs)
    key = (json.dumps(attrs["identity"], sort_keys=True), size)
    if key not in _DOCUMENTS:
        shadow = ScoreStore.in_memory()
        for group in GROUPS:
            create(shadow, group, domain, size, coords(group, domain, size))
        _DOCUMENTS.clear()  # one identity at a time is what a process checks
        _DOCUMENTS[key] = {path: json.dumps(doc) for path, doc in shadow.documents().items()}
    return {path: json.loads(doc) for path, doc in _DOCUMENTS[key].items()
            if path.split("/")[0] in groups
            or path.startswith(f"{integrity.GROUP}/") and path.split("/")[1] in groups}


#: The documents of the last identity checked (the identity fixes the domain).
_DOCUMENTS: dict[tuple, dict[str, str]] = {}


def table_columns(group: str, domain) -> list[str]:
    """The arrays ``group``'s integrity table covers, in their column order."""
    size = Size(1, 1, 1, 1)
    shadow = ScoreStore.in_memory()
    create(shadow, group, domain, size, coords(group, domain, size))
    return list(shadow.layout(group).names)
