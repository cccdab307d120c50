"""Rich tables shared by the ``box`` command line and the pipeline's stages."""

from __future__ import annotations

from rich.table import Table

import box_core
from box_core.stats import INTERVAL_METHOD


def summary_table(summary: box_core.Summary, title: str) -> Table:
    head, *rows = summary.table_rows()
    table = Table(title=title, caption=f"time to first feasible plan (LOOCV, k = {summary.k}); "
                  f"'x {summary.reference}' = mean time / mean time of {summary.reference}; "
                  f"intervals: {INTERVAL_METHOD} over instances")
    for i, h in enumerate(head):
        table.add_column(h, justify="left" if i == 0 else "right")
    for row in rows:
        table.add_row(*row)
    return table
