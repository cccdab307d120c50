"""The report's figures (matplotlib, written as PNG and SVG).

Fig. 3 and Fig. 4 follow the paper: mean time to the first feasible plan per selector with
95 % interval bars on a log scale, and mean best score versus time with ORACLE's optimum.
One panel per store, so several planners or domains sit side by side.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.ticker
import numpy as np
from matplotlib.figure import Figure

from box_core import curve_summary
from box_core.stats import RATIO_INTERVAL_METHOD, mean_ci_columns
from pipeline.configs import RAWPLANNER

#: How selectors are named and coloured in every figure and table.
LABELS = {"box": "BOX", "eips": "EIPS", "static": "STATIC", "rand": "RAND", "doo": "DOO",
          "pembo": "PEM-BO", "oracle": "ORACLE", "fastest": "FASTEST",
          "contextual": "CONTEXTUAL", "contextual_capped": "CONTEXTUAL+CAPS",
          RAWPLANNER: "RAWPLANNER"}
COLOURS = {"box": "tab:red", "eips": "tab:orange", "static": "tab:blue", "rand": "tab:gray",
           "doo": "tab:green", "pembo": "tab:purple", "oracle": "magenta",
           "fastest": "tab:cyan", "contextual": "tab:olive", "contextual_capped": "darkgreen",
           RAWPLANNER: "tab:brown"}

#: Oracles see the held-out truth: no bars or curves of their own, only reference lines.
ORACLES = ("oracle", "fastest")

#: Fig. 4 marks where a mean curve has covered this share of the way from the failure
#: value to ORACLE's optimum (scores are negative lengths, so "95 % of the optimal score"
#: is read as 95 % of the gap closed).
OPTIMAL_SHARE = 0.95

#: Times below this (seconds) are drawn at it on a log time axis.
_LEAST_TIME = 1e-6


def label(name: str) -> str:
    return LABELS.get(name, name.upper())


def save(fig, out_dir: Path, stem: str, formats) -> dict[str, Path]:
    paths = {}
    for fmt in formats:
        path = out_dir / f"{stem}.{fmt}"
        fig.savefig(path, dpi=150 if fmt == "png" else None, bbox_inches="tight")
        paths[fmt] = path
    return paths


def _panels(count: int, width: float = 5.0, height: float = 4.0):
    """A figure of ``count`` panels side by side.  A plain Figure (no pyplot): no backend is
    chosen and no global figure registry is touched, so importing this module sets nothing."""
    fig = Figure(figsize=(width * count, height))
    axes = fig.subplots(1, count, squeeze=False)
    return fig, axes[0]


def first_feasible(results, out_dir: Path, formats) -> dict[str, Path]:
    """Fig. 3: mean time to first feasible plan per selector, 95 % interval, log scale."""
    fig, axes = _panels(len(results))
    for ax, res in zip(axes, results, strict=True):
        lines = [line for line in res.summary["selectors"] if line["name"] not in ORACLES
                 and line["mean_time"] is not None]
        x = np.arange(len(lines))
        means = np.array([line["mean_time"] for line in lines])
        low = np.array([np.nan if line["ci_low"] is None else line["ci_low"] for line in lines])
        high = np.array([np.nan if line["ci_high"] is None else line["ci_high"]
                         for line in lines])
        ax.bar(x, means, color=[COLOURS.get(line["name"], "k") for line in lines], alpha=0.85)
        ax.errorbar(x, means, yerr=_positive_errors(means, low, high), fmt="none",
                    ecolor="black", capsize=4, lw=1.2)
        ax.set_xticks(x, [label(line["name"]) for line in lines], rotation=30)
        fastest = next((line for line in res.summary["selectors"]
                        if line["name"] == "fastest" and line["mean_time"] is not None), None)
        if fastest is not None:  # headroom: the least any selector could reach
            ax.axhline(fastest["mean_time"], color=COLOURS["fastest"], ls="--", lw=1.4,
                       label="FASTEST (time-optimal oracle)")
            ax.legend(fontsize=8, loc="upper left")
        ax.set_yscale("log")
        ax.set_ylabel("mean time to first feasible plan (s)")
        ax.set_title(f"{res.label}\n{res.shape[0]} x {res.shape[1]}, "
                     f"{int(res.eligible.sum())} instances with a feasible constraint",
                     fontsize=10)
        ax.grid(axis="y", which="both", alpha=0.3)
    fig.suptitle("Time to first feasible plan (leave-one-out, bars: 95 % interval)")
    fig.tight_layout()
    return save(fig, out_dir, "fig3_first_feasible", formats)


def _axis_end(res, curves: dict[str, np.ndarray], target: float) -> float:
    """Where the paper cuts the time axis: when the first curve reaches the target, with
    room to see the others (the whole grid when none reaches it)."""
    grid = res.time_grid
    hits = [grid[np.argmax(c >= target)] for c in curves.values() if (c >= target).any()]
    return float(min(grid[-1], 3 * min(hits))) if hits and min(hits) > 0 else float(grid[-1])


def score_versus_time(results, out_dir: Path, formats) -> dict[str, Path]:
    """Fig. 4: mean best score versus time over instances with a feasible constraint."""
    fig, axes = _panels(len(results))
    for ax, res in zip(axes, results, strict=True):
        rows = res.eligible
        curves, bands = {}, {}
        for name in res.best_score:
            if name in ORACLES:
                continue
            mean, lo, hi = curve_summary(res, name, rows=rows)
            curves[name], bands[name] = mean, (lo, hi)
        if res.raw_feasible.any():
            mean, lo, hi = mean_ci_columns(res.raw_curve()[rows])
            curves[RAWPLANNER], bands[RAWPLANNER] = mean, (lo, hi)
        optimum = float(res.optimal_score[rows].mean())
        target = res.failure_value + OPTIMAL_SHARE * (optimum - res.failure_value)
        end = _axis_end(res, curves, target)
        keep = res.time_grid <= end
        t = res.time_grid[keep]
        for name, mean in curves.items():
            colour = COLOURS.get(name, "k")
            ax.step(t, mean[keep], where="post", color=colour, label=label(name), lw=1.6)
            lo, hi = bands[name]
            ax.fill_between(t, lo[keep], hi[keep], step="post", color=colour, alpha=0.12)
        ax.axhline(optimum, color=COLOURS["oracle"], ls="--", lw=1.4, label="optimal (ORACLE)")
        ax.axhline(target, color=COLOURS["oracle"], ls=":", lw=1.0,
                   label=f"{OPTIMAL_SHARE:.0%} of optimal")
        ax.set_xlim(0, end)
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"mean best score (-path length; failure = {res.failure_value:.3g})")
        ax.set_title(f"{res.label}\n{int(rows.sum())} instances", fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("Best score found versus time (leave-one-out, bands: 95 % interval)")
    fig.tight_layout()
    return save(fig, out_dir, "fig4_score_vs_time", formats)


def learning_curves(results, curves, out_dir: Path, formats) -> dict[str, Path]:
    """Time to first feasible plan of BOX, EIPS and STATIC versus training rows."""
    fig, axes = _panels(len(results))
    for ax, res, points in zip(axes, results, curves, strict=True):
        for name in dict.fromkeys(p.selector for p in points):
            mine = [p for p in points if p.selector == name]
            x = np.array([p.n_train for p in mine])
            mean = np.array([p.mean for p in mine])
            lo = np.array([p.low for p in mine])
            hi = np.array([p.high for p in mine])
            colour = COLOURS.get(name, "k")
            ax.plot(x, mean, marker="o", color=colour, label=label(name))
            ax.fill_between(x, lo, hi, color=colour, alpha=0.15)
        ax.set_xscale("log")
        sizes = sorted({p.n_train for p in points})
        ax.set_xticks(sizes, [str(v) for v in sizes])
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set_xlabel("training instances")
        ax.set_ylabel("mean time to first feasible plan (s)")
        ax.set_title(res.label, fontsize=10)
        ax.grid(which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Learning curve (held-out instances, bands: 95 % interval)")
    fig.tight_layout()
    return save(fig, out_dir, "fig_learning_curve", formats)


def _positive_errors(mean, low, high):
    """Error bar lengths for a log axis: a lower end at zero is drawn down to the axis, and a
    missing end (a single row) draws no bar on that side."""
    mean, low, high = (np.asarray(v, dtype=np.float64) for v in (mean, low, high))
    low = np.where(np.isnan(low), mean, low)
    high = np.where(np.isnan(high), mean, high)
    return [mean - np.maximum(low, mean * 1e-3), high - mean]


def c_sensitivity(results, tunings, out_dir: Path, formats) -> dict[str, Path]:
    """BOX's mean time to first feasible plan versus C, with the nested-CV tuned result."""
    fig, axes = _panels(len(results), height=4.6)
    for ax, res, tuning in zip(axes, results, tunings, strict=True):
        grid = np.array(tuning.grid)
        values = np.array([tuning.sensitivity[c] for c in tuning.grid])
        ax.errorbar(grid, values[:, 0], yerr=_positive_errors(*values.T), marker="o",
                    color=COLOURS["box"], capsize=4, label="BOX, leave-one-out, per C")
        summary = tuning.summary()
        chosen = ", ".join(f"{c:g}" for c in tuning.chosen)
        ax.axhline(summary["tuned"][0], color="black", ls="--", lw=1.2,
                   label=f"C tuned by nested CV (per fold: {chosen})")
        ax.axhline(summary["fixed"][0], color="0.5", ls=":", lw=1.2,
                   label=f"C = {tuning.fixed_c:g} on the same folds")
        ax.set_yscale("log")
        ax.set_xlabel("UCB coefficient C")
        ax.set_ylabel("mean time to first feasible plan (s)")
        ax.set_title(res.label, fontsize=10)
        ax.grid(which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=1)
    fig.suptitle("BOX's sensitivity to C (planning time only, bars: 95 % interval)")
    fig.tight_layout()
    return save(fig, out_dir, "fig_c_sensitivity", formats)


def time_distributions(results, out_dir: Path, formats) -> dict[str, Path]:
    """Empirical distribution of the time to first feasible plan per selector (as OMPL's
    Planner Arena shows planners): the share of instances with a feasible constraint that a
    selector has solved by each time, on a log time axis.  A curve that ends below 1 did not
    solve every instance within its tries; oracles are dashed."""
    fig, axes = _panels(len(results), height=4.4)
    for ax, res in zip(axes, results, strict=True):
        rows = int(res.eligible.sum())
        for name in res.selectors:
            times = res.first_feasible_time.get(name)
            if times is None or rows == 0:
                continue
            solved = np.sort(times[res.eligible][~np.isnan(times[res.eligible])])
            if solved.size == 0:
                continue
            solved = np.maximum(solved, _LEAST_TIME)  # a log axis has no 0
            share = np.arange(1, solved.size + 1) / rows
            oracle = name in ORACLES
            ax.step(np.concatenate([[solved[0]], solved]), np.concatenate([[0.0], share]),
                    where="post", color=COLOURS.get(name, "k"), lw=1.2 if oracle else 1.7,
                    ls="--" if oracle else "-", label=label(name) + (" (oracle)" if oracle
                                                                     else ""))
        ax.set_xscale("log")
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("time to first feasible plan (s, log scale)")
        ax.set_ylabel("share of instances solved")
        ax.set_title(f"{res.label}\n{rows} instances with a feasible constraint", fontsize=10)
        ax.grid(which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    fig.suptitle("Distribution of the time to first feasible plan (leave-one-out)")
    fig.tight_layout()
    return save(fig, out_dir, "fig_time_distribution", formats)


def ratio_forest(results, out_dir: Path, formats) -> dict[str, Path]:
    """Each selector's mean time over BOX's on the instances both solved, with its stored
    interval (a forest plot): right of the line at 1 BOX is faster.  Oracles are hollow."""
    most = max((len(res.summary["selectors"]) for res in results), default=1)
    fig, axes = _panels(len(results), width=6.5, height=1.2 + 0.32 * most)
    for ax, res in zip(axes, results, strict=True):
        ref = res.summary["reference"]
        lines = [line for line in res.summary["selectors"]  # a log axis has no 0
                 if line["name"] != ref and (line.get("speedup") or 0) > 0]
        lines.sort(key=lambda line: line["speedup"], reverse=True)
        for y, line in enumerate(lines):
            ratio = line["speedup"]
            low = ratio if line["speedup_low"] is None else line["speedup_low"]
            high = ratio if line["speedup_high"] is None else line["speedup_high"]
            colour = COLOURS.get(line["name"], "k")
            oracle = line["name"] in ORACLES
            # a BCa interval may leave out its own estimate: no bar on that side then
            ax.errorbar(ratio, y, xerr=[[max(ratio - low, 0)], [max(high - ratio, 0)]], fmt="o",
                        color=colour, mfc="white" if oracle else colour, capsize=3, lw=1.4)
            ax.annotate(f"{ratio:.3g} [{low:.3g}, {high:.3g}]", (1.02, y),
                        xycoords=ax.get_yaxis_transform(), va="center", fontsize=8)
        ax.axvline(1.0, color="black", lw=1)
        ax.set_yticks(range(len(lines)),
                      [label(line["name"]) + (" (oracle)" if line["name"] in ORACLES else "")
                       for line in lines])
        ax.set_ylim(-0.6, max(len(lines), 1) - 0.4)
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(f"mean time / mean time of {label(ref)}  (> 1: {label(ref)} is faster)")
        ax.set_title(res.label, fontsize=10)
        ax.grid(axis="x", which="both", alpha=0.3)
    fig.suptitle("Ratio of mean time to first feasible plan to BOX's "
                 f"(bars: 95 % {RATIO_INTERVAL_METHOD} interval)")
    fig.tight_layout()
    return save(fig, out_dir, "fig_ratio_to_box", formats)
