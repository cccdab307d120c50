"""Summary table of a leave-one-out evaluation (paper Fig. 3 as numbers)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from box_core.stats import INTERVAL_METHOD, mean_ci, mean_ci_columns, paired_ratio


@dataclass(frozen=True)
class SelectorSummary:
    """One selector's line: time to first feasible plan over rows that have one."""

    name: str
    rows: int  # rows with at least one feasible constraint
    found: int  # of those, rows where a feasible one was found within k tries
    mean_time: float
    ci_low: float
    ci_high: float
    median_time: float
    mean_tries: float  # tries up to and including the first feasible one
    overhead_ms: float  # mean selector compute time per step, milliseconds
    speedup: float  # mean time of this selector / mean time of the reference, paired rows
    speedup_low: float
    speedup_high: float


@dataclass(frozen=True)
class Summary:
    reference: str
    level: float
    k: int
    n: int
    lines: tuple[SelectorSummary, ...]

    def line(self, name: str) -> SelectorSummary:
        for entry in self.lines:
            if entry.name == name:
                return entry
        raise KeyError(name)

    def to_dict(self) -> dict:
        return {
            "reference": self.reference,
            "level": self.level,
            "k": self.k,
            "n": self.n,
            "selectors": [_jsonable(asdict(line)) for line in self.lines],
        }

    def table_rows(self) -> list[list[str]]:
        """Header and formatted rows, for any table renderer."""
        pct = f"{round(self.level * 100)}% CI"
        head = ["selector", "found", "mean time", pct, "median", "tries", "ms/step",
                f"x {self.reference}", f"{pct} of x"]
        rows = [head]
        for s in self.lines:
            rows.append([
                s.name,
                f"{s.found}/{s.rows}",
                _num(s.mean_time),
                f"[{_num(s.ci_low)}, {_num(s.ci_high)}]",
                _num(s.median_time),
                "-" if math.isnan(s.mean_tries) else f"{s.mean_tries:.2f}",
                "-" if math.isnan(s.overhead_ms) else f"{s.overhead_ms:.3f}",
                f"{s.speedup:.2f}",
                f"[{s.speedup_low:.2f}, {s.speedup_high:.2f}]",
            ])
        return rows

    def __str__(self) -> str:
        rows = self.table_rows()
        widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
        text = ["  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)) for r in rows]
        text.insert(1, "  ".join("-" * w for w in widths))
        caption = (
            f"time to first feasible plan, leave-one-out over n = {self.n} rows, k = {self.k}; "
            f"x {self.reference} = mean time / mean time of {self.reference} on the same rows; "
            f"95 % intervals: {INTERVAL_METHOD}"
        )
        return caption + "\n" + "\n".join(text)


def summarize(result, reference: str = "box", level: float = 0.95, others=None) -> Summary:
    """Build the :class:`Summary` of a :class:`~box_core.loocv.LoocvResult`.

    ``others`` maps a name to per-row times to first feasible plan measured outside the
    LOOCV (NaN where none was found), e.g. RAWPLANNER's: they get a line of their own.
    """
    if reference not in result.selectors:
        reference = result.selectors[0]
    eligible = result.eligible
    ref_time = result.first_feasible_time[reference][eligible]
    measured = {}
    for name, values in (others or {}).items():
        values = np.asarray(values, dtype=np.float64)
        if values.shape != eligible.shape:
            raise ValueError(f"times of {name!r}: expected shape {eligible.shape}, "
                             f"got {values.shape}")
        measured[name] = values
    lines = []
    for name in (*result.selectors, *measured):
        if name in measured:
            times = measured[name][eligible]
            steps = np.full(times.shape, np.nan)
            overhead = math.nan
        else:
            times = result.first_feasible_time[name][eligible]
            steps = result.first_feasible_step[name][eligible]
            made = result.order[name] >= 0  # the tries made (a row may stop early)
            overhead = float(result.overhead[name][made].mean() * 1e3) if made.any() else 0.0
        found = ~np.isnan(times)
        mean, lo, hi = mean_ci(times, level)
        ratio, r_lo, r_hi = paired_ratio(times, ref_time, level)
        lines.append(SelectorSummary(
            name=name,
            rows=int(eligible.sum()),
            found=int(found.sum()),
            mean_time=mean,
            ci_low=lo,
            ci_high=hi,
            median_time=float(np.median(times[found])) if found.any() else math.nan,
            mean_tries=float((steps[found] + 1).mean()) if found.any() else math.nan,
            overhead_ms=overhead,
            speedup=ratio,
            speedup_low=r_lo,
            speedup_high=r_hi,
        ))
    return Summary(reference=reference, level=level, k=result.k, n=result.n, lines=tuple(lines))


def curve_summary(result, name: str, level: float = 0.95, rows=None):
    """Mean best score versus ``result.time_grid`` with its interval: (mean, low, high)."""
    values = result.best_score[name] if rows is None else result.best_score[name][rows]
    return mean_ci_columns(values, level)


def _num(x: float) -> str:
    return "nan" if math.isnan(x) else f"{x:.4g}"


def _jsonable(d: dict) -> dict:
    return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in d.items()}
