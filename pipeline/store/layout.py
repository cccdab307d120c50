"""The store's layout, declared once: its groups, arrays, dimensions, codecs, attributes and
coordinates, the ``evaluation/`` dataset included.  Every other module reaches the store's
arrays through the names, key functions, readers and writers declared here and in the rest
of :mod:`pipeline.store`; none outside the package spells a group or array name.

Layout (a contract: users open it with ``xarray.open_zarr(path, group=...)`` or
``xarray.open_datatree(path, engine="zarr")``; docs/store.md describes it for them)::

    /                 attrs: format, layout_version, identity, config_hash, config,
                             versions, git_revision, created, stages, environments
    instances/        seed (instance), spec (instance; JSON text), features (instance,
                      instance_feature; only when the domain declares instance features);
                      coordinates instance, instance_feature, instance_feature_units
                      (instance_feature)
    raw/              score length feasible time status checks step tries environment
                      (instance), constraint (instance, feature), done (instance);
                      coordinates instance, instance_seed (instance), feature,
                      feature_units (feature)
    constraints/      theta (constraint, feature), source_instance (constraint);
                      coordinates constraint, feature, feature_units
    scores/           score length feasible time status checks step environment done
                      (instance, constraint); coordinates instance, instance_seed
                      (instance), constraint, constraint_source (constraint)
    evaluation/       order (selector, instance, step), first_feasible_step,
                      first_feasible_time (selector, instance), best_score (selector,
                      instance, time), eligible, optimal_score (instance); coordinates
                      selector, instance, step, time (EVALUATION_ARRAYS below;
                      written and read by pipeline/store/evaluation.py)
    integrity/        per block group a table of chunk digests (pipeline/store/integrity.py)

Every dimension has an index coordinate (``instance`` and ``constraint`` count from 0);
physical quantities carry CF ``units`` and ``long_name`` (times in "seconds", which xarray
leaves as float seconds unless opened with ``decode_timedelta=True``); ``status`` and
``step`` are codes with CF ``flag_values``/``flag_meanings`` that
:func:`pipeline.dataset.with_names` turns into names.

The stages create the block groups with :func:`create`, and :func:`expected` runs the same
function against an in-memory store that records metadata only: what a store of this
identity must hold, document by document, whatever the store on disk now says.  That is
what :mod:`pipeline.store.metadata` checks every ``zarr.json`` against and rewrites them
from.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from zarr.codecs import Crc32cCodec, ZstdCodec

from pipeline.planning import Status

FORMAT = "box-planning-score-store"
#: 1: the first layout; 2: integrity tables, coordinates, every chunk written; 3: the
#: environment that computed each block (``environment`` arrays, ``environments`` table);
#: 4: a dataset: index coordinates, units and names, the evaluation along ``selector``;
#: 5: the instances' features (``instances/features``), when the domain declares some.
LAYOUT_VERSION = 5
#: The layout that added the instances' features.
FEATURES_LAYOUT = 5
CODECS = (ZstdCodec(level=3), Crc32cCodec())

# -- groups ----------------------------------------------------------------------------------
INSTANCES, RAW, CONSTRAINTS, SCORES = "instances", "raw", "constraints", "scores"
EVALUATION = "evaluation"
INTEGRITY = "integrity"
#: The groups whose layout follows from the identity, in the order the stages make them.
GROUPS = (INSTANCES, RAW, CONSTRAINTS, SCORES)
#: The block axes of each block group.
BLOCK_DIMS = {INSTANCES: ("instance",), RAW: ("instance",), CONSTRAINTS: ("constraint",),
              SCORES: ("instance", "constraint")}
#: The group each store-writing stage writes (the block groups are named after their stage).
STAGE_GROUPS = {INSTANCES: INSTANCES, RAW: RAW, CONSTRAINTS: CONSTRAINTS, SCORES: SCORES,
                "evaluate": EVALUATION}


def key(group: str, name: str) -> str:
    """The key of array (or subgroup) ``name`` of ``group``."""
    return f"{group}/{name}"


def table_key(group: str) -> str:
    """The key of block group ``group``'s integrity table."""
    return key(INTEGRITY, group)


# -- arrays ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Column:
    """One array of a result group: dtype, fill value."""

    dtype: str
    fill: object


#: The per-entry results of a planning call (raw: per instance; scores: per entry).
SCORE, LENGTH, FEASIBLE, TIME, STATUS, CHECKS, STEP = (
    "score", "length", "feasible", "time", "status", "checks", "step")
RESULT_COLUMNS = {
    SCORE: Column("float64", np.nan),  # -(path length); NaN when infeasible
    LENGTH: Column("float64", np.nan),
    FEASIBLE: Column("bool", False),
    TIME: Column("float64", np.nan),  # seconds (the only machine-dependent value)
    STATUS: Column("int8", -1),  # pipeline.planning.Status; -1 = not computed
    CHECKS: Column("int64", 0),
    STEP: Column("int8", -1),  # index into the domain's steps of the one that failed; -1: none
}
#: The mask of entries whose block finished (raw and scores).
DONE = "done"
#: The arrays of the groups computed whole, and raw's arrays beyond RESULT_COLUMNS.
SEED, SPEC, FEATURES = "seed", "spec", "features"
THETA_NAME, SOURCE_NAME = "theta", "source_instance"
TRIES, CONSTRAINT = "tries", "constraint"
#: The per-entry index into the root attribute ENVIRONMENTS (raw and scores).
ENVIRONMENT = "environment"
ENVIRONMENTS = "environments"
UNKNOWN_ENVIRONMENT = -1

INSTANCE_SEED = key(INSTANCES, SEED)
INSTANCE_SPEC = key(INSTANCES, SPEC)
INSTANCE_FEATURES = key(INSTANCES, FEATURES)
RAW_CONSTRAINT = key(RAW, CONSTRAINT)
THETA = key(CONSTRAINTS, THETA_NAME)
SOURCE_INSTANCE = key(CONSTRAINTS, SOURCE_NAME)
#: The names of the coordinates of θ's features (raw and constraints).
FEATURE, FEATURE_UNITS = "feature", "feature_units"
#: The names of the coordinates of the instances' features (not θ's ``feature``).
INSTANCE_FEATURE, INSTANCE_FEATURE_UNITS = "instance_feature", "instance_feature_units"


def result_key(group: str, name: str) -> str:
    """The key of result array ``name`` (a RESULT_COLUMNS name or ``done``) of ``group``
    (``raw`` or ``scores``)."""
    return key(group, name)


def done_key(group: str) -> str:
    """The key of ``group``'s ``done`` mask."""
    return key(group, DONE)


def instance_arrays(seeds, specs, features) -> dict:
    """The data arrays of ``instances`` by name, for a block write (``features``: (n, q),
    stored when q > 0)."""
    return {SEED: seeds, SPEC: specs, **({FEATURES: features} if features.shape[1] else {})}


def constraint_arrays(theta, sources) -> dict:
    """The data arrays of ``constraints`` by name, for a block write."""
    return {THETA_NAME: theta, SOURCE_NAME: sources}


def raw_extras(tries, constraint) -> dict:
    """The arrays of a ``raw`` block beyond RESULT_COLUMNS by name, for a block write."""
    return {TRIES: tries, CONSTRAINT: constraint}


#: What each stage is computed from (its digests are recorded with the stage).
STAGE_INPUTS = {
    INSTANCES: (),
    RAW: (INSTANCE_SEED, INSTANCE_SPEC),
    CONSTRAINTS: (RAW_CONSTRAINT,),
    SCORES: (INSTANCE_SEED, INSTANCE_SPEC, THETA),
    "evaluate": (*(result_key(SCORES, k) for k in (FEASIBLE, LENGTH, TIME, CHECKS)), THETA,
                 result_key(RAW, FEASIBLE), result_key(RAW, TIME), INSTANCE_FEATURES),
}

# -- attributes and coordinates ---------------------------------------------------------------
#: CF units of times: xarray keeps them float seconds unless ``decode_timedelta=True``.
TIME_UNITS = "seconds"


def flag_attrs(values, meanings, **special) -> dict:
    """CF flag attributes: ``flag_values`` and ``flag_meanings`` decode codes to names;
    ``special`` names the codes outside them (``not_computed=-1``)."""
    return {"flag_values": list(values), "flag_meanings": " ".join(meanings), **special}


def result_attrs(domain) -> dict[str, dict]:
    """CF attributes of each result array (RESULT_COLUMNS) of a store of ``domain``."""
    length = {"units": domain.length_units}
    return {
        SCORE: {"long_name": f"score: minus the {domain.length_name} (NaN: infeasible)",
                **length},
        LENGTH: {"long_name": domain.length_name, **length},
        FEASIBLE: {"long_name": "a feasible plan was found"},
        TIME: {"long_name": "planning time of the call", "units": TIME_UNITS},
        STATUS: {"long_name": "outcome of the planning call",
                 **flag_attrs([s.value for s in Status], Status.names(), not_computed=-1)},
        CHECKS: {"long_name": "collision checks used", "units": "1"},
        STEP: {"long_name": "planning step that failed",
               **flag_attrs(list(range(len(domain.steps))), domain.steps, none=-1)},
    }


def dims_of_coords(coords: dict) -> set[str]:
    """Coordinates named like their only dimension (xarray indexes them by themselves)."""
    return {name for name, (dims, _, _) in coords.items() if tuple(dims) == (name,)}


def index_coord(dim: str, n: int, long_name: str) -> dict:
    """The index coordinate of ``dim``: 0..n-1."""
    return {dim: ((dim,), np.arange(n, dtype="int64"), {"long_name": long_name})}


def instance_coord(seeds) -> dict:
    return {**index_coord("instance", len(seeds), "instance index"),
            "instance_seed": (("instance",), np.asarray(seeds, dtype="int64"),
                              {"long_name": "seed the instance was sampled from"})}


def feature_coord(domain) -> dict:
    """The names and units of θ's features, as the domain declares them."""
    features = domain.theta_features
    return {FEATURE: (("feature",), np.asarray([f.name for f in features], dtype=str),
                      {"long_name": "feature of a constraint θ"}),
            FEATURE_UNITS: (("feature",), np.asarray([f.units for f in features], dtype=str),
                            {"long_name": "UDUNITS units of the feature"})}


def instance_feature_coord(domain) -> dict:
    """The names and units of the instances' features, as the domain declares them ({}
    when it declares none)."""
    features = domain.omega_features
    if not features:
        return {}
    return {INSTANCE_FEATURE: ((INSTANCE_FEATURE,), np.asarray([f.name for f in features],
                                                               dtype=str),
                               {"long_name": "feature of an instance ω"}),
            INSTANCE_FEATURE_UNITS: ((INSTANCE_FEATURE,),
                                     np.asarray([f.units for f in features], dtype=str),
                                     {"long_name": "UDUNITS units of the instance feature"})}


def source_coord(sources) -> dict:
    return {**index_coord("constraint", len(sources), "constraint index"),
            "constraint_source": (("constraint",), np.asarray(sources, dtype="int64"),
                                  {"long_name": "instance whose raw solution gave the "
                                                "constraint; -1: a fixed set"})}


# -- the evaluation dataset (layout 4) ---------------------------------------------------------
class EvaluationArray(NamedTuple):
    """One array of ``evaluation/``: its dimensions, data type, fill value and attributes
    (``scored``: its unit is the scores' own, added when it is written)."""

    dims: tuple[str, ...]
    dtype: str
    fill: object
    attrs: dict
    scored: bool = False


SELECTOR, EVALUATION_TIME = "selector", "time"
#: The coordinates of ``evaluation/`` (each along itself) and their attributes.
EVALUATION_COORDS = {
    SELECTOR: {"long_name": "constraint selector"},
    "instance": {"long_name": "held-out instance index"},
    "step": {"long_name": "0-based try of the selector"},
    EVALUATION_TIME: {"long_name": "time since the instance was given", "units": TIME_UNITS},
}
ORDER, FIRST_FEASIBLE_STEP, FIRST_FEASIBLE_TIME = "order", "first_feasible_step", \
    "first_feasible_time"
BEST_SCORE, ELIGIBLE, OPTIMAL_SCORE = "best_score", "eligible", "optimal_score"
#: The data arrays of ``evaluation/``, in the order they are written.
EVALUATION_ARRAYS = {
    ORDER: EvaluationArray((SELECTOR, "instance", "step"), "int32", -1,
                           {"long_name": "columns tried, in order (-1: no try)"}),
    FIRST_FEASIBLE_STEP: EvaluationArray(
        (SELECTOR, "instance"), "int32", -1,
        {"long_name": "0-based step of the first feasible try (-1: none)"}),
    FIRST_FEASIBLE_TIME: EvaluationArray(
        (SELECTOR, "instance"), "float64", np.nan,
        {"long_name": "time to the first feasible plan (NaN: none)", "units": TIME_UNITS}),
    BEST_SCORE: EvaluationArray((SELECTOR, "instance", "time"), "float64", np.nan,
                                {"long_name": "best score found by each time"}, scored=True),
    ELIGIBLE: EvaluationArray(("instance",), "bool", False,
                              {"long_name": "the instance has a feasible constraint"}),
    OPTIMAL_SCORE: EvaluationArray(("instance",), "float64", np.nan,
                                   {"long_name": "the instance's best score"}, scored=True),
}
#: Layout 3 and before: one group per selector holding these arrays, and a time grid.
TIME_GRID = "time_grid"


def evaluation_key(name: str) -> str:
    """The key of array ``name`` of ``evaluation/`` (``<selector>/<array>`` before
    layout 4)."""
    return key(EVALUATION, name)


# -- the block groups, as a function of the identity ------------------------------------------
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
    if group == INSTANCES:
        return {**index_coord("instance", size.n, "instance index"),
                **instance_feature_coord(domain)}
    if group == RAW:
        return {**instance_coord(seeds), **feature_coord(domain)}
    if group == CONSTRAINTS:
        return {**index_coord("constraint", size.m, "constraint index"),
                **feature_coord(domain)}
    return {**instance_coord(seeds), **source_coord(sources)}


def create(store, group: str, domain, size: Size, group_coords: dict) -> None:
    """Create ``group``'s arrays, coordinates and integrity table (no values but the
    coordinates'), replacing whatever was there."""
    n, m, b, bc = size
    p = domain.n_features
    if group == INSTANCES:
        store.create(INSTANCE_SEED, (n,), (b,), "int64", 0, ("instance",),
                     long_name="seed the instance was sampled from")
        store.create(INSTANCE_SPEC, (n,), (b,), str, "", ("instance",),
                     long_name="instance spec, JSON text")
        names = [SEED, SPEC]
        if domain.n_instance_features:
            create_instance_features(store, size, domain.n_instance_features)
            names.append(FEATURES)
        store.write_coords(group, group_coords, names[2:])
        store.create_table(group, [*names, *group_coords])
    elif group == CONSTRAINTS:
        store.create(THETA, (m, p), (bc, p), "float64", np.nan, ("constraint", "feature"),
                     long_name="features of the constraint θ; units: feature_units")
        store.create(SOURCE_INSTANCE, (m,), (bc,), "int64", -1, ("constraint",),
                     long_name="instance whose raw solution gave it; -1: a fixed set")
        store.write_coords(group, group_coords, [THETA_NAME, SOURCE_NAME])
        store.create_table(group, [THETA_NAME, SOURCE_NAME, *group_coords])
    elif group == RAW:
        extra = [(TRIES, (n,), (b,), "int32", 0, ("instance",), {}),
                 (CONSTRAINT, (n, p), (b, p), "float64", np.nan, ("instance", "feature"),
                  {"long_name": "constraint θ extracted from the raw solution (NaN: none); "
                                "units: feature_units"})]
        store.create_results(group, (n,), (b,), ("instance",), domain, extra, group_coords)
    else:
        store.create_results(group, (n, m), (b, bc), ("instance", "constraint"), domain,
                             coords=group_coords)


def create_instance_features(store, size: Size, q: int) -> None:
    """The array of the instances' features: (n, q), a chunk per block of instances."""
    store.create(INSTANCE_FEATURES, (size.n, q), (size.block_instances, q), "float64", np.nan,
                 ("instance", INSTANCE_FEATURE),
                 long_name="features of the instance ω; units: instance_feature_units")


def expected(attrs: dict, domain, groups) -> dict[str, dict]:
    """The metadata document (``zarr.json``, parsed) of every node of ``groups`` and of the
    ``integrity`` tables that cover them, for a store with root attributes ``attrs``
    (``domain``: the one its identity names).  A fresh copy each call; the documents of one
    identity are derived once per process."""
    size = size_of(attrs)
    cache_key = (json.dumps(attrs["identity"], sort_keys=True), size)
    if cache_key not in _DOCUMENTS:
        shadow = _shadow()
        for group in GROUPS:
            create(shadow, group, domain, size, coords(group, domain, size))
        _DOCUMENTS.clear()  # one identity at a time is what a process checks
        _DOCUMENTS[cache_key] = {path: json.dumps(doc) for path, doc in shadow.documents().items()}
    return {path: json.loads(doc) for path, doc in _DOCUMENTS[cache_key].items()
            if path.split("/")[0] in groups
            or path.startswith(f"{INTEGRITY}/") and path.split("/")[1] in groups}


#: The documents of the last identity checked (the identity fixes the domain).
_DOCUMENTS: dict[tuple, dict[str, str]] = {}


def table_columns(group: str, domain) -> list[str]:
    """The arrays ``group``'s integrity table covers, in their column order."""
    size = Size(1, 1, 1, 1)
    shadow = _shadow()
    create(shadow, group, domain, size, coords(group, domain, size))
    return list(shadow.layout(group).names)


def _shadow():
    """An empty in-memory store that records metadata only (the store module builds on
    this one, so it is imported when first needed)."""
    from pipeline.store.score_store import ScoreStore

    return ScoreStore.in_memory()
