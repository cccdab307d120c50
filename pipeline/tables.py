"""Rich tables shared by the ``box`` command line and the pipeline's stages, and the
console they print to.

A rich table wider than its console squeezes its columns until names and numbers are cut
("selec…").  :class:`FittedTable` instead leaves out its least important columns, one at a
time, until the rest fit (columns of words may wrap at spaces, others keep their width), and
says in its caption which ones it left out.  Only a console too narrow for the columns that
always stay folds their cells across lines; nothing is ever cut.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass

from rich.console import Console, ConsoleOptions, RenderResult
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

import box_core
from box_core.stats import INTERVAL_METHOD

#: The width of standard output off a terminal when COLUMNS does not say: rich's own
#: default there (80) wraps the tables of logs and pipes that nobody reads at 80 columns.
OFF_TERMINAL_WIDTH = 132


def stdout_console() -> Console:
    """Standard output: the terminal's width; off a terminal, COLUMNS when set, else
    :data:`OFF_TERMINAL_WIDTH`."""
    if sys.stdout.isatty() or os.environ.get("COLUMNS", "").isdigit():
        return Console()
    return Console(width=OFF_TERMINAL_WIDTH)


@dataclass(frozen=True)
class Column:
    """``drop``: the order in which the column is left out when the table is too wide
    (1 first); None: always shown.  ``wrap``: its cells may wrap at spaces (lists, prose);
    other columns are as wide as their widest cell."""

    header: str
    justify: str = "right"
    drop: int | None = None
    wrap: bool = False


def _cell_width(cell: str, wrap: bool) -> int:
    text = Text.from_markup(cell)
    return max((len(w) for w in text.plain.split()), default=0) if wrap else text.cell_len


class FittedTable:
    """A table that fits the width it is printed at (see the module docstring)."""

    def __init__(self, columns: Sequence[Column], rows: Sequence[Sequence[str]], *,
                 title: str | None = None, caption: str | None = None) -> None:
        self.columns, self.rows = list(columns), [list(r) for r in rows]
        self.title, self.caption = title, caption

    def needed(self, shown: list[int]) -> int:
        """The narrowest width at which columns ``shown`` fit without folding a cell: each
        column's widest cell (longest word for ``wrap`` columns), a space either side and
        a rule between columns and at both edges."""
        widths = [max(_cell_width(cell, self.columns[i].wrap)
                      for cell in [self.columns[i].header, *(row[i] for row in self.rows)])
                  for i in shown]
        return sum(widths) + 3 * len(shown) + 1

    def shown(self, width: int) -> list[int]:
        """The columns kept at ``width``."""
        shown = list(range(len(self.columns)))
        order = sorted((c.drop, i) for i, c in enumerate(self.columns) if c.drop is not None)
        for _, i in order:
            if self.needed(shown) <= width:
                break
            shown.remove(i)
        return shown

    def table(self, width: int) -> Table:
        """The rich table of the columns that fit ``width``."""
        shown = self.shown(width)
        left_out = [c.header for i, c in enumerate(self.columns) if i not in shown]
        notes = [self.caption] if self.caption else []
        if left_out:
            notes.append(f"left out at this width: {', '.join(left_out)}")
        table = Table(title=Text(self.title, overflow="fold") if self.title else None,
                      caption=Text("; ".join(notes), overflow="fold") if notes else None)
        squeezed = self.needed(shown) > width  # then every cell may fold, none is cropped
        for i in shown:
            column = self.columns[i]
            table.add_column(column.header, justify=column.justify, overflow="fold",
                             no_wrap=not (column.wrap or squeezed))
        for row in self.rows:
            table.add_row(*(row[i] for i in shown))
        return table

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield self.table(options.max_width)

    def __rich_measure__(self, console: Console, options: ConsoleOptions) -> Measurement:
        return Measurement.get(console, options, self.table(options.max_width))


def summary_table(summary: box_core.Summary, title: str) -> FittedTable:
    """The evaluation summary.  At narrow widths it leaves out ms/step, tries, the median
    and the interval of the mean time, in that order; the selector, its successes, its mean
    time and its ratio to the reference with that ratio's interval always stay."""
    head, *rows = summary.table_rows()
    drop = {"ms/step": 1, "tries": 2, "median": 3, head[3]: 4}  # head[3]: "95% CI"
    columns = [Column(h, justify="left" if i == 0 else "right", drop=drop.get(h))
               for i, h in enumerate(head)]
    return FittedTable(columns, rows, title=title,
                       caption=f"time to first feasible plan (LOOCV, k = {summary.k}); "
                       f"'x {summary.reference}' = mean time / mean time of "
                       f"{summary.reference}; intervals: {INTERVAL_METHOD} over instances")
