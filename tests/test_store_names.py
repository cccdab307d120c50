"""The store's layout is declared once (``pipeline/store/layout.py``): no module of
``pipeline/`` outside ``pipeline/store/`` spells one of its group or array names, so that a
change of the layout is a change of that package only (docs/architecture.md, "The store").

The names are taken from the layout itself (what :func:`pipeline.store.layout.create` makes
in an in-memory store, and the evaluation dataset it declares), so a new array is covered
as soon as it is declared.  Spelled means: a string that is a store key (``"scores/done"``,
``f"integrity/{group}"``, ``f"{group}/done"``), or a group or array name passed as a literal
to the store's readers, writers or key functions (``store.has_table("raw")``,
``result_key("scores", "feasible")``)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from pipeline.domains import load_domain
from pipeline.store import ScoreStore, layout

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "pipeline"
STORE_PACKAGE = PACKAGE / "store"

#: Methods and functions that take a group, an array name or a key of the store.
ACCESSORS = {"array", "has", "has_group", "has_table", "has_results", "remove", "result",
             "done", "require_done", "blocks", "grid", "missing_arrays", "finished_blocks",
             "verify", "arrays_under", "create_results", "write_coords", "write_whole",
             "write_block", "record_blocks", "forget_blocks", "set_done", "create_table",
             "result_key", "done_key", "table_key", "key", "evaluation_key"}


def layout_names() -> tuple[set[str], set[str]]:
    """(groups, array names) of the store's layout, as the layout module creates them."""
    shadow = ScoreStore.in_memory()
    domain = load_domain("planar")
    size = layout.Size(2, 2, 1, 1)
    for group in layout.GROUPS:
        layout.create(shadow, group, domain, size, layout.coords(group, domain, size))
    paths = [path for path in shadow.documents() if path]
    groups = {path.split("/")[0] for path in paths} | {layout.EVALUATION}
    names = {path.split("/")[-1] for path in paths if "/" in path}
    names |= {*layout.EVALUATION_ARRAYS, *layout.EVALUATION_COORDS, layout.TIME_GRID}
    return groups, names - groups


GROUPS, NAMES = layout_names()


def spelled(source: str) -> list[str]:
    """Where ``source`` spells a store group or array name: ``line: text``."""
    found = []

    def note(node, text):
        found.append(f"{node.lineno}: {text}")

    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            head, sep, rest = node.value.partition("/")
            if sep and head in GROUPS and (not rest or rest.split("/")[0] in NAMES | GROUPS):
                note(node, repr(node.value))
        elif isinstance(node, ast.JoinedStr):  # a key made of a group: f"{group}/done"
            match node.values:
                case [ast.FormattedValue(), ast.Constant(value=str(text))] \
                        if text.startswith("/") and text[1:] in NAMES:
                    note(node, f"f-string {{...}}{text}")
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
            if name not in ACCESSORS:
                continue
            for arg in node.args:
                if isinstance(arg, ast.Constant) and arg.value in GROUPS | NAMES:
                    note(node, f"{name}({arg.value!r}, ...)")
    return found


def modules_outside_the_store() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if STORE_PACKAGE not in p.parents)


def test_the_layout_names_are_found():
    assert {"instances", "raw", "constraints", "scores", "evaluation", "integrity"} <= GROUPS
    assert {"done", "theta", "seed", "feasible", "environment", "feature_units",
            "best_score", "selector"} <= NAMES


@pytest.mark.parametrize("code", [
    'store.array("scores/done")',
    'x = "integrity/raw"',
    'store.array(f"integrity/{group}")',
    'store.has(f"{group}/done")',
    'store.has_table("raw")',
    'result_key("scores", "feasible")',
    'store.result(SCORES, "feasible")',
])
def test_a_spelled_store_name_is_found(code):
    assert spelled(code), code


@pytest.mark.parametrize("code", [
    'store.stage_info("scores")',
    'f"{found}/{total}"',
    'f"http://{host}:{port}/status"',
    'store.result(SCORES, FEASIBLE)',
    'print("raw: already complete")',
])
def test_other_strings_are_not_taken_for_store_names(code):
    assert not spelled(code), code


def test_no_module_outside_the_store_package_spells_a_store_name():
    found = {str(path.relative_to(ROOT)): hits for path in modules_outside_the_store()
             if (hits := spelled(path.read_text()))}
    assert not found, found
