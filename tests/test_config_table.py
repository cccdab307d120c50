"""docs/config.md's table of keys and defaults is the one scripts/config_table.py generates
from the schemas and conf/ (the defaults are written once, in the schemas)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _script():
    spec = importlib.util.spec_from_file_location("config_table",
                                                  ROOT / "scripts" / "config_table.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_config_table_is_the_generated_one():
    script = _script()
    text = script.DOC.read_text()
    assert script.splice(text, script.generate()) == text, (
        "docs/config.md is out of date: run python scripts/config_table.py")


def test_the_table_holds_every_key_of_the_composed_config():
    script = _script()
    block = script.DOC.read_text().split(script.BEGIN)[1].split(script.END)[0]
    for key in ("seed", "instances.n", "constraints.m", "planner.max_checks",
                "cluster.slurm.cores", "store.block_instances", "evaluate.selectors",
                "report.c_grid", "solve.max_seconds", "progress", "domain.step_order",
                "domain.raw_max_tries"):
        assert f"| `{key}` |" in block, key


def test_a_stages_view_of_the_config_has_the_keys_of_the_config():
    """StageContext.config's type (RunConfig) names every top-level key of Config."""
    from dataclasses import fields

    from pipeline.configs import Config
    from pipeline.context import RunConfig

    assert list(RunConfig.__annotations__) == [f.name for f in fields(Config)]
