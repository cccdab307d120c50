"""What the evaluate and solve stages need from a run, and nothing more."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

from rich.console import Console

from pipeline.store import ScoreStore

Section = dict[str, Any]  # one section of the config: the keys of its dataclass


class RunConfig(TypedDict):
    """A run's resolved config as plain data: :class:`pipeline.configs.Config` (its keys,
    checked by Hydra and :func:`pipeline.validation.validate`) through
    ``OmegaConf.to_container(resolve=True, enum_to_str=True)``, so enums are their values."""

    stage: str
    seed: int
    domain: Section  # the domain's schema (pipeline.domains.domain_schema)
    planner: Section
    cluster: Section
    instances: Section
    constraints: Section
    store: Section
    evaluate: Section  # pipeline.configs.EvaluateConfig
    report: Section
    solve: Section  # pipeline.configs.SolveConfig
    progress: bool
    progress_every: float


@dataclass(frozen=True)
class StageContext:
    """A stage's view of one run: its store, resolved settings, output and Dask client.

    ``config`` is the run's resolved config as plain data (``config["evaluate"]["k"]``);
    ``client()`` connects to (or starts) the run's Dask cluster on first use.
    """

    store: ScoreStore | None
    path: Path
    config: RunConfig
    seed: int
    token: str  # names the run's Dask tasks: two runs on one scheduler never share a future
    retries: int
    progress: bool
    console: Console
    client: Callable[[], Any]

    def say(self, text: str) -> None:
        self.console.print(text, highlight=False)
