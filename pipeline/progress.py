"""How a run shows the entries it has done: a live bar on a terminal, lines elsewhere.

Off a terminal (SLURM batch jobs, ``> log``) a live bar prints nothing until the run ends,
so the same numbers are printed as one line every ``every_s`` seconds and once at the end.
Those lines also go to the ``pipeline`` logger on a terminal, so Hydra's run log
(``outputs/<date>/<time>/__main__.log``) holds them either way.
"""

from __future__ import annotations

import logging
import time

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

log = logging.getLogger("pipeline")


def duration(seconds: float) -> str:
    """``42 s``, ``6 min``, ``2 h 05 min``."""
    if seconds < 59.5:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


def rate_text(rate: float) -> str:
    return f"{rate:,.0f}" if rate >= 10 else f"{rate:.2g}"


class Rate:
    """Entries per second since ``start`` and the time left at that rate."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.start = time.monotonic()

    def per_s(self, done: int) -> float:
        return done / max(time.monotonic() - self.start, 1e-9)

    def eta(self, done: int) -> str:
        rate = self.per_s(done)
        return duration((self.total - done) / rate) if rate > 0 else "unknown"

    def line(self, label: str, done: int, final: bool = False) -> str:
        """``scores: 1234/2400 entries (51%), 3.1 entries/s, ETA 6 min``; the ``final``
        line gives the time taken instead of the ETA."""
        share = done / self.total if self.total else 1.0
        rate = rate_text(self.per_s(done))
        end = (f"took {duration(time.monotonic() - self.start)}" if final
               else f"ETA {self.eta(done)}")
        return f"{label}: {done}/{self.total} entries ({share:.0%}), {rate} entries/s, {end}"


class EntryProgress:
    """A context manager that shows ``update(done)`` calls: a rich bar when ``console`` is
    an interactive terminal, else a line every ``every_s`` seconds; in both cases the lines
    go to the log.  ``enabled=False`` shows nothing.  The final line is written when the
    block closes without an error."""

    def __init__(self, label: str, total: int, console: Console, *, enabled: bool,
                 every_s: float) -> None:
        self.label, self.console, self.enabled, self.every_s = label, console, enabled, every_s
        self.rate = Rate(total)
        self.done = 0
        self._last_line = self.rate.start
        self._bar = self._job = None
        if enabled and console.is_interactive:
            self._bar = Progress(TextColumn(f"[bold]{label}"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("entries  {task.fields[rate]} /s"),
                                 TimeElapsedColumn(), TextColumn("ETA {task.fields[eta]}"),
                                 console=console, transient=False)
            self._job = self._bar.add_task(label, total=total, rate="-", eta="unknown")

    def __enter__(self) -> EntryProgress:
        if self._bar is not None:
            self._bar.start()
        return self

    def __exit__(self, kind, value, tb) -> None:
        if self._bar is not None:
            self._bar.stop()
        if kind is None and self.enabled:
            self._say(self.rate.line(self.label, self.done, final=True))

    def update(self, done: int) -> None:
        self.done = done
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(self._job, completed=done, rate=rate_text(self.rate.per_s(done)),
                             eta=self.rate.eta(done))
        now = time.monotonic()
        if now - self._last_line >= self.every_s and done < self.rate.total:
            self._last_line = now
            self._say(self.rate.line(self.label, done))

    def _say(self, line: str) -> None:
        """The log always; the console too when it shows no bar."""
        log.info(line)
        if self._bar is None:
            self.console.print(line, highlight=False, soft_wrap=True)
