"""What the evaluate and solve stages need from a run, and nothing more."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console

from pipeline.store import ScoreStore


@dataclass(frozen=True)
class StageContext:
    """A stage's view of one run: its store, resolved settings, output and Dask client.

    ``config`` is the run's resolved config as plain data (``config["evaluate"]``...);
    ``client()`` connects to (or starts) the run's Dask cluster on first use.
    """

    store: ScoreStore | None
    path: Path
    config: dict
    seed: int
    token: str  # names the run's Dask tasks: two runs on one scheduler never share a future
    retries: int
    progress: bool
    console: Console
    client: Callable[[], Any]

    def say(self, text: str) -> None:
        self.console.print(text, highlight=False)
