"""Issue 24's metadata campaign: every metadata document and root attribute of a small
finished store is edited in turn, one at a time; for each, status names it, and a re-run
either repairs the store to the bitwise-identical one or refuses with one line, changing
nothing.

"Bitwise identical": every file's bytes, except the root document and the integrity group's,
whose stage records carry the time each stage finished (compared without those times), and
the chunks of the evaluation's two time-dependent arrays (``first_feasible_time``,
``best_score``): a selector's time includes its measured compute time (box_core.loocv's
``overhead``), which differs from run to run; their documents are compared.
Status and the re-runs run in this process (the re-runs need no workers: nothing is
planned), on one working copy of the store that each edit leaves equal to the reference
again (copied afresh only where an edit left it different).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from rich.console import Console

from pipeline.configs import CONF_DIR, register_configs
from pipeline.stages import run_pipeline
from pipeline.store import status
from pipeline.store.errors import StoreError
from tests import pipeline_runs as pr

#: The evaluation's arrays that hold measured times.
TIMED = ("evaluation/first_feasible_time/", "evaluation/best_score/", "evaluation/time/")

#: Root attributes whose right value the store cannot tell: an edit is refused.
REFUSED = {"created", "versions", "git_revision", "environments", "identity"}


def _load(path: Path) -> dict:
    return json.loads(path.read_text())


def _save(path: Path, doc: dict) -> None:
    path.write_text(json.dumps(doc, indent=2))


def snapshot(store: Path) -> dict[str, object]:
    """Every file's bytes; the two documents that carry stage times, without them."""
    out: dict[str, object] = {}
    for path in sorted(p for p in store.rglob("*") if p.is_file()):
        key = str(path.relative_to(store))
        if key in ("zarr.json", "integrity/zarr.json"):
            doc = _load(path)
            doc.pop("consolidated_metadata", None)
            attrs = doc.get("attributes", {})
            (attrs.get("stages") or {}).pop("evaluate", None)  # times measured again
            for info in (attrs.get("stages") or {}).values():
                info.pop("finished", None)
            attrs.pop("config", None)  # the latest run's settings (same command: same values)
            record = attrs.get("root", {})
            for name in [k for k in record if k.startswith("stages.") or k == "config"]:
                del record[name]  # digests of what is compared above without its times
            out[key] = doc
        elif key.startswith(TIMED) and not key.endswith("zarr.json"):
            continue
        else:
            out[key] = path.read_bytes()
    return out


# -- the edits --------------------------------------------------------------------------------
def _other(value):
    """A plausible different value of the same kind."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * 2 + 1
    if isinstance(value, str):
        words = value.split()
        return " ".join(reversed(words)) if len(set(words)) > 1 else value + "x"
    if isinstance(value, list):
        return list(reversed(value)) if len(set(map(json.dumps, value))) > 1 else value + value
    if isinstance(value, dict):
        return {**value, "edited": True}
    return "edited"


def _array_edit(doc: dict, k: int) -> tuple[str, dict]:
    """The k-th kind of edit of an array document (kinds cycle over the documents)."""
    doc = json.loads(json.dumps(doc))
    kinds = ["shape", "chunk_grid", "data_type", "fill_value", "codecs", "dimension_names",
             "attributes"]
    kind = kinds[k % len(kinds)]
    if kind == "shape":
        doc["shape"] = [100000] * len(doc["shape"])  # case 1: a reader must not allocate it
    elif kind == "chunk_grid":
        chunks = doc["chunk_grid"]["configuration"]["chunk_shape"]
        doc["chunk_grid"]["configuration"]["chunk_shape"] = [max(1, c // 2) for c in chunks]
    elif kind == "data_type":
        doc["data_type"] = "int16" if doc["data_type"] != "int16" else "int32"
    elif kind == "fill_value":
        doc["fill_value"] = 7 if doc["fill_value"] != 7 else 8
    elif kind == "codecs":
        doc["codecs"] = doc["codecs"][:-1]
    elif kind == "dimension_names":
        doc["dimension_names"] = [f"{d}_edited" for d in doc["dimension_names"]]
    else:
        doc["attributes"]["edited"] = "by hand"
    return kind, doc


def edits(store: Path):
    """(name, what status must say, document, edited document) for every document and root
    attribute."""
    out = []
    docs = sorted(p.relative_to(store) for p in store.rglob("zarr.json"))
    for k, rel in enumerate(d for d in docs if str(d) != "zarr.json"):
        doc = _load(store / rel)
        if doc["node_type"] == "array":
            kind, edited = _array_edit(doc, k)
        else:
            kind, edited = "attributes", {**doc, "attributes": {**doc["attributes"],
                                                               "edited": "by hand"}}
        out.append((f"{rel} {kind}", str(rel), rel, edited))
    status_doc = _load(store / "scores/status/zarr.json")
    for name, value in status_doc["attributes"].items():  # every attribute of one array
        edited = json.loads(json.dumps(status_doc))
        edited["attributes"][name] = _other(value)
        out.append((f"scores/status/zarr.json attribute {name}", "scores/status/zarr.json",
                    Path("scores/status/zarr.json"), edited))
    root = _load(store / "zarr.json")
    for name, value in root["attributes"].items():
        edited = json.loads(json.dumps(root))
        edited["attributes"][name] = (1 if name == "layout_version" else
                                      {**value, "raw": {"finished": "2000-01-01"}}
                                      if name == "stages" else _other(value))
        out.append((f"zarr.json attribute {name}", name, Path("zarr.json"), edited))
    consolidated = json.loads(json.dumps(root))
    copies = consolidated["consolidated_metadata"]["metadata"]
    copies["scores/status"]["attributes"]["flag_meanings"] = "edited"
    out.append(("zarr.json consolidated copy of scores/status",
                "consolidated copy of scores/status", Path("zarr.json"), consolidated))
    return out


#: A store smaller than the other tests' (2 x 2 blocks of 4 x 3): the campaign checks and
#: re-runs it some eighty times.
TINY = {"instances.n": 8, "constraints.m": 6, "store.block_instances": 4,
        "store.block_constraints": 3}


@pytest.fixture(scope="module")
def campaign_store(tmp_path_factory):
    """A small finished store (generate, then evaluate, in this process) and its config."""
    store = tmp_path_factory.mktemp("campaign") / "a.zarr"
    overrides = [o for o in pr.SMALL if o.split("=")[0] not in TINY]
    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[
            *overrides, *(f"{k}={v}" for k, v in TINY.items()), f"store.path={store}",
            "stage=generate"])
    assert rerun(cfg) is None
    cfg.stage = "evaluate"
    assert rerun(cfg) is None
    return store, cfg


def rerun(cfg) -> str | None:
    """Run ``cfg`` in this process: None, or the one-line refusal."""
    try:
        run_pipeline(cfg, Console(file=open("/dev/null", "w")))  # noqa: SIM115, PTH123
    except StoreError as exc:
        return str(exc)
    return None


def fresh_copy(store: Path, copy: Path) -> None:
    shutil.rmtree(copy)
    shutil.copytree(store, copy)


def test_every_metadata_edit_is_named_then_repaired_or_refused(campaign_store, tmp_path):
    store, cfg = campaign_store
    reference = snapshot(store)
    counts = {"edits": 0, "named": 0, "repaired": 0, "refused": 0}
    failures, refused = [], []
    copy = tmp_path / "copy.zarr"
    shutil.copytree(store, copy)
    for name, token, rel, edited in edits(store):
        # every edit starts from a copy equal to the reference (checked below, after each
        # edit): a repaired copy is the reference again, a refused one gets its edited
        # document back, and only a copy left different is copied afresh
        _save(copy / rel, edited)
        counts["edits"] += 1
        try:
            report = status.collect(copy)
            said = status.damaged(report)
        except StoreError as exc:  # the store cannot be opened as it is: named in one line
            said = str(exc)
        if token not in said:
            failures.append(f"{name}: status does not name it: {said!r}")
            fresh_copy(store, copy)
            continue
        counts["named"] += 1
        damaged = snapshot(copy)
        for stage in ("generate", "evaluate"):
            cfg.stage, cfg.store.path = stage, str(copy)
            refusal = rerun(cfg)
            if refusal is not None:
                break
        if refusal is not None:
            if "\n" in refusal or snapshot(copy) != damaged:
                failures.append(f"{name}: refused in more than one line or changed the store")
                fresh_copy(store, copy)
            else:
                counts["refused"] += 1
                refused.append(f"{name}: {refusal}")
                shutil.copyfile(store / rel, copy / rel)  # the reference again
                assert snapshot(copy) == reference
            continue
        after = snapshot(copy)
        if after != reference:
            diff = [k for k in reference if after.get(k) != reference[k]]
            failures.append(f"{name}: re-run left the store different ({diff[:4]})")
            fresh_copy(store, copy)
            continue
        counts["repaired"] += 1
    print(f"\nmetadata campaign: {counts}\nrefused:\n" + "\n".join(refused))
    assert not failures, "\n".join(failures)
    assert counts["edits"] == counts["repaired"] + counts["refused"]
    assert counts["refused"] >= len(REFUSED) - 1  # each of REFUSED (format aside) is refused
