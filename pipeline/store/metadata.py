"""Checking every metadata document of a store, and repairing what can be known.

Chunk digests (:mod:`pipeline.store.integrity`) say nothing about the ``zarr.json`` documents that
tell a reader how to decode the chunks and what they mean, so those are checked here, each
against what can be known of it:

* the arrays and groups of the block groups and their integrity tables: the documents
  :func:`pipeline.store.layout.expected` derives from the store's identity (shape, chunk grid,
  data type, codecs, fill value, dimension names, attributes such as ``flag_meanings``);
  a re-run rewrites them from there, then the chunk digests decide what to compute again;
* the evaluation's arrays: the documents the evaluate stage recorded when it wrote them
  (derived data: a difference means computing the evaluation again);
* the root attributes: ``format``, ``config_hash`` (the hash of ``identity``) and
  ``layout_version`` (what the store's arrays show) follow from the rest, and every
  attribute's digest is recorded in the ``integrity`` group (``root``) each time the
  coordinator writes one (and of each stage's record).  A stage record that differs
  is repaired by forgetting it (that stage checks its data again and records it anew);
  ``config`` by the run, which records its own settings; ``identity`` is refused as a
  different config; ``created``, ``versions``, ``git_revision`` and ``environments``
  cannot be known and are refused with one line;
* the consolidated copy in the root document (what xarray reads): each entry must equal the
  node's own document; it is written again after any repair.

Nothing here reads a chunk, so a document that claims a huge shape costs nothing to check,
and readers check documents before they allocate anything.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING

from pipeline.configs import config_hash
from pipeline.store import integrity
from pipeline.store.errors import StoreDamaged, StoreError
from pipeline.store.layout import (
    FEATURES,
    FEATURES_LAYOUT,
    FORMAT,
    INSTANCE_FEATURES,
    INSTANCES,
    LAYOUT_VERSION,
)

if TYPE_CHECKING:
    from pipeline.store.score_store import ScoreStore

#: Fields of an array document that change how its chunks decode.
STRUCTURE = ("shape", "data_type", "chunk_grid", "chunk_key_encoding", "fill_value", "codecs",
             "node_type", "zarr_format", "storage_transformers")

#: Root attributes whose right value cannot be known from anything else in the store.
UNKNOWABLE = ("created", "versions", "git_revision", "environments")

REWRITE, RECOMPUTE, FORGET_STAGES, REFUSE, RECONSOLIDATE = (
    "rewrite", "recompute", "forget stages", "refuse", "reconsolidate")


@dataclass(frozen=True)
class Difference:
    """One metadata document (or root attribute) that is not what it must be."""

    node: str  # "" for the root
    what: str  # the field(s) that differ, or what is wrong with the document
    action: str  # how a run repairs it (REWRITE, RECOMPUTE, ...), or REFUSE
    structural: bool = False  # its chunks cannot be read as they are

    @property
    def document(self) -> str:
        return f"{self.node}/zarr.json" if self.node else "zarr.json"

    def describe(self) -> str:
        return f"{self.document} ({self.what})"


def describe(found: list[Difference]) -> str:
    return "; ".join(d.describe() for d in found)


# -- what a store must hold ------------------------------------------------------------------
def root_record(attrs: dict) -> dict[str, str]:
    """A digest per root attribute, and per stage record (``stages.<stage>``): what the
    ``integrity`` group records as ``root``."""
    values = {name: value for name, value in attrs.items() if name != "stages"}
    values.update({f"stages.{stage}": info for stage, info in (attrs.get("stages") or {}).items()})
    return {name: _digest(value) for name, value in sorted(values.items())}


def _digest(value) -> str:
    return f"{integrity.digest(json.dumps(value, sort_keys=True)):016x}"


def content_layout(store: ScoreStore) -> int | None:
    """The layout the store's arrays show (None for a store with no groups yet)."""
    groups = ("instances", "raw", "constraints", "scores")
    if not any(store.has_group(g) for g in groups):
        return None
    if _recorded_instance_features(store):
        return FEATURES_LAYOUT
    if any(store.has(k) for k in ("instances/instance", "constraints/constraint",  # index
                                  "scores/constraint", "raw/feature_units")):  # coordinates
        return 4
    if any(store.has(f"{g}/environment") for g in ("raw", "scores")) \
            or store.attrs.get("environments"):
        return 3
    if any(store.has_table(g) for g in groups):
        return 2
    return 1


def _recorded_instance_features(store: ScoreStore) -> bool:
    """Whether ``instances/features`` is there and its integrity table covers it (what
    layout 5 adds; a store whose domain declares no instance features shows layout 4)."""
    if not (store.has(INSTANCE_FEATURES) and store.has_table(INSTANCES)):
        return False
    try:
        return FEATURES in store.layout(INSTANCES).names
    except (KeyError, TypeError):
        return False


def _fields(found: dict, expected: dict) -> list[str]:
    keys = [k for k in expected if k != "attributes"] + [k for k in found if k not in expected]
    out = [k for k in dict.fromkeys(keys) if found.get(k) != expected.get(k)]
    have, want = found.get("attributes") or {}, expected.get("attributes") or {}
    out += [f"attribute {a}" for a in dict.fromkeys([*want, *have]) if have.get(a) != want.get(a)]
    return out


def _compare(store: ScoreStore, expected: dict[str, dict], action: str) -> list[Difference]:
    out = []
    for node, want in expected.items():
        try:
            have = store.document(node)
        except KeyError:
            continue  # a missing array: chunk verification reports it
        except ValueError as exc:
            out.append(Difference(node, f"unreadable: {str(exc).splitlines()[0]}", action, True))
            continue
        fields = _fields(have, want)
        if fields:
            structural = any(f in STRUCTURE for f in fields)
            out.append(Difference(node, ", ".join(fields), action, structural))
    return out


def _root(store: ScoreStore) -> list[Difference]:
    attrs = store.attrs
    out = []
    if attrs.get("format") != FORMAT:
        out.append(Difference("", f"attribute format is {attrs.get('format')!r}", REWRITE))
    version = attrs.get("layout_version")
    if not isinstance(version, int) or version > LAYOUT_VERSION:
        out.append(Difference("", f"attribute layout_version is {version!r}; this version "
                                  f"reads layouts 1 to {LAYOUT_VERSION}", REFUSE))
        return out
    shown = content_layout(store)
    # a store of layout 5 whose domain declares no instance features shows layout 4
    shows_older = shown == FEATURES_LAYOUT - 1 and version >= FEATURES_LAYOUT
    if shown is not None and shown != version and not shows_older:
        out.append(Difference("", f"attribute layout_version is {version} but the arrays are "
                                  f"those of layout {shown}", REWRITE))
    if version < LAYOUT_VERSION:
        return out  # migrated by the next run; nothing more was recorded
    if attrs.get("config_hash") != config_hash(attrs.get("identity") or {}):
        out.append(Difference("", "attribute config_hash is not the hash of identity", REWRITE))
    recorded = _recorded_root(store)
    if recorded is None:
        out.append(Difference(integrity.GROUP, "attribute root (the record of the root "
                                               "attributes) is missing", REWRITE))
        return out
    current = root_record(attrs)
    for name in dict.fromkeys([*recorded, *current]):
        if recorded.get(name) == current.get(name) or name in ("format", "layout_version",
                                                               "config_hash"):
            continue
        action = (FORGET_STAGES if name.startswith("stages.") else REWRITE if name == "config"
                  else REFUSE)
        out.append(Difference("", f"attribute {name} differs from its record", action))
    return out


def _recorded_root(store: ScoreStore) -> dict | None:
    try:
        record = store.document(integrity.GROUP).get("attributes", {}).get("root")
    except (KeyError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def _evaluation(store: ScoreStore) -> list[Difference]:
    recorded = (store.stage_info("evaluate") or {}).get("metadata")
    return _compare(store, recorded, RECOMPUTE) if recorded else []


def _consolidated(store: ScoreStore) -> list[Difference]:
    raw = store.read_bytes("zarr.json")
    copies = ((json.loads(raw).get("consolidated_metadata") or {}).get("metadata") or {}) \
        if raw else {}
    out = []
    for node, copy in copies.items():
        try:
            own = store.document(node)
        except (KeyError, ValueError):
            own = None
        copy = {k: v for k, v in copy.items() if k != "consolidated_metadata"}
        if copy != own:
            out.append(Difference("", f"consolidated copy of {node}/zarr.json differs from it",
                                  RECONSOLIDATE))
    return out


def check(store: ScoreStore, domain) -> list[Difference]:
    """Every metadata difference of ``store`` (of the current layout; an older one is
    checked for its version only, and migrated by the next run)."""
    with store.documents_read_once():
        return _check(store, domain)


def _check(store: ScoreStore, domain) -> list[Difference]:
    found = _root(store)
    if any(d.action == REFUSE and "layout_version" in d.what for d in found) \
            or store.layout_version < LAYOUT_VERSION:
        return found
    from pipeline.store import layout

    stages = store.attrs.get("stages") or {}
    groups = [g for g in layout.GROUPS if store.has_group(g)
              and (g in ("raw", "scores") or g in stages)]
    expected = layout.expected(store.attrs, domain, groups)
    store.read_documents(expected)
    found += _compare(store, expected, REWRITE)
    recorded = _recorded_root(store)
    integrity_doc = {"attributes": {"root": recorded}, "zarr_format": 3, "node_type": "group"}
    if recorded is not None:
        found += _compare(store, {integrity.GROUP: integrity_doc}, REWRITE)
    found += _evaluation(store)
    if not any(d.node == "" and "unreadable" in d.what for d in found):
        found += _consolidated(store)
    return found


def structural(found: list[Difference]) -> set[str]:
    """The groups with an array whose chunks cannot be read as its document says."""
    return {d.node.split("/")[0] if not d.node.startswith(f"{integrity.GROUP}/")
            else d.node.split("/")[1] for d in found if d.structural}


def store_domain(store: ScoreStore):
    """The domain a store was made with (its units, steps and features)."""
    from pipeline.domains import load_domain

    spec = store.domain_spec()
    return load_domain(spec["name"], planner=spec["planner"], **spec["config"])


def refuse(store: ScoreStore, domain=None) -> None:
    """For readers: StoreDamaged naming every difference, before anything is read."""
    found = check(store, domain if domain is not None else store_domain(store))
    if found:
        raise StoreDamaged(f"store {store.path} has damaged metadata: {describe(found)}; "
                           "re-run the pipeline command that made it to repair it")


# -- repairing ----------------------------------------------------------------------------------
def repair_layout_version(store: ScoreStore) -> str | None:
    """Before any migration: a ``layout_version`` below what the arrays show is set back to
    what they show (a store is never migrated from a layout it does not have, which would
    adopt data that its records no longer cover)."""
    shown, version = content_layout(store), store.attrs.get("layout_version")
    if shown is None or not isinstance(version, int) or version >= shown:
        return None
    store.set_attrs(layout_version=shown)
    return f"attribute layout_version was {version} but the arrays are those of layout " \
           f"{shown}: set back to {shown}"


def repair(store: ScoreStore, domain, found: list[Difference]) -> list[str]:
    """Repair ``found`` in ``store`` (opened for writing, lock held); return a line per
    repair.  Raises StoreError, before changing anything, when one cannot be repaired."""
    refused = [d for d in found if d.action == REFUSE]
    if refused:
        raise StoreError(f"store {store.path}: {describe(refused)}; its right value cannot "
                         "be known: restore it, or regenerate the store (store.mode=overwrite "
                         "or another store.path)")
    from pipeline.store import layout

    notes = []
    rewrite = [d for d in found if d.action == REWRITE and d.node not in ("", integrity.GROUP)]
    if rewrite:
        groups = {d.node.split("/")[0] for d in rewrite} | {"instances", "raw", "constraints",
                                                            "scores"}
        want = layout.expected(store.attrs, domain, [g for g in groups if store.has_group(g)])
        for d in rewrite:
            store.write_document(d.node, want[d.node])
        notes.append(f"rewrote from the layout: {describe(rewrite)}")
    for d in found:
        if d.node == "" and d.action == REWRITE:
            if d.what.startswith("attribute format"):
                store.set_attrs(format=FORMAT)
            elif d.what.startswith("attribute layout_version"):
                store.set_attrs(layout_version=content_layout(store))
            elif d.what.startswith("attribute config_hash"):
                store.set_attrs(config_hash=config_hash(store.attrs["identity"]))
            notes.append(f"root {d.what}: rewritten")
    forget = [d.what.split()[1].removeprefix("stages.") for d in found
              if d.action == FORGET_STAGES]
    if forget:
        stages = {k: v for k, v in (store.attrs.get("stages") or {}).items() if k not in forget}
        store.set_attrs(stages=stages)
        notes.append(f"the records of stages {', '.join(forget)} differ from their record: "
                     "those stages check their data again")
    if any(d.action == RECOMPUTE for d in found):
        from pipeline.store import evaluation

        store.forget_stage("evaluate")
        store.remove(evaluation.GROUP)
        differs = describe([d for d in found if d.action == RECOMPUTE])
        notes.append(f"evaluation metadata differs ({differs}): computed again")
    record = [d for d in found if d.node == integrity.GROUP]
    if record:
        store.write_document(integrity.GROUP, {"attributes": {}, "zarr_format": 3,
                                               "node_type": "group"})
        notes.append(f"recorded the root attributes again ({describe(record)})")
    if any(d.action == RECONSOLIDATE for d in found):
        notes.append("consolidated metadata written again (it differed from the documents)")
    store.record_root()
    store.consolidate(force=any(d.action == RECONSOLIDATE for d in found))
    return notes
