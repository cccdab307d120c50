"""Renders of the first feasible plan BOX finds on a few instances, with a strip of the
tries before it.

The domain's ``render`` draws a scene and a plan; an infeasible plan leaves the robot where
it started, so rendering BOX's first try (infeasible on most instances of the main job)
shows little.  Each render here re-plans the constraint at which BOX's leave-one-out order
first meets a feasible entry of D (with the entry's own planning seed, so the plan is the
one D measured) and draws it above a strip of BOX's tries on that instance: every failed
constraint and its planning time, then the feasible one.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import matplotlib.image
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from pipeline.report.data import StoreResults

#: Tries drawn in a strip; earlier failures are counted, not drawn.
STRIP_TRIES = 8

_FAILED, _FOUND = "#d62728", "#2ca02c"


@dataclass(frozen=True)
class FirstFeasible:
    """Where BOX's order on row ``row`` first meets a feasible entry of D."""

    row: int
    constraint: int
    tries: int  # tries up to and including the feasible one
    tried: tuple[int, ...]  # the constraints tried, in order, the feasible one last


def first_feasible(res: StoreResults, row: int, selector: str = "box") -> FirstFeasible | None:
    """The first feasible constraint in ``selector``'s stored order on ``row``; None when
    its tries (k of them) hold no feasible one."""
    order = np.asarray(res.order[selector][row], dtype=np.int64)
    order = order[order >= 0]  # -1 pads an order after its last try
    hits = np.flatnonzero(res.feasible[row, order])
    if hits.size == 0:
        return None
    t = int(hits[0])
    return FirstFeasible(row, int(order[t]), t + 1, tuple(int(j) for j in order[:t + 1]))


def render_first_feasible(res: StoreResults, count: int, out_dir: Path,
                          tag: str) -> list[tuple[Path, str]]:
    """Render BOX's first feasible plan on the first ``count`` instances where BOX finds
    one (in row order, not picked): a list of (PNG path, caption)."""
    from pipeline.worker import domain_for, entry_seed

    if count <= 0 or "box" not in res.order:
        return []
    found = (first_feasible(res, int(i)) for i in np.flatnonzero(res.eligible))
    chosen = [f for f in found if f is not None][:count]
    if not chosen:
        return []
    domain = domain_for(res.spec)
    out = []
    with tempfile.TemporaryDirectory() as scratch:
        for f in chosen:
            i, j = f.row, f.constraint
            spec = json.loads(str(res.instance_specs[i]))
            plan = domain.plan(domain.check_instance(spec), res.theta[j],
                               seed=entry_seed(res.seed, int(res.instance_seeds[i]), j))
            scene = domain.render(spec, plan, Path(scratch) / f"{i}.png",
                                  constraint=res.theta[j])
            path = out_dir / f"{tag}-instance{i}-constraint{j}.png"
            _compose(scene, res, f, path)
            verdict = (f"feasible, path length {plan.length:.3f}" if plan.feasible
                       else f"planned again it is infeasible: {plan.status.name.lower()}")
            agrees = "as in D" if plan.feasible else "DIFFERS FROM D"
            strip = ("strip: BOX's first try, feasible (green), with its planning time"
                     if f.tries == 1 else
                     f"strip: BOX's tries in order, {f.tries - 1} failed (red: constraint "
                     "and planning time in D), then the feasible one (green)")
            out.append((path, f"{res.label}, instance {i}: the first feasible plan BOX finds, "
                              f"constraint {j} at try {f.tries} ({verdict}, {agrees}); "
                              f"{strip}."))
    return out


def _compose(scene: Path, res: StoreResults, f: FirstFeasible, path: Path) -> Path:
    """The domain's render above the strip of tries, as one PNG."""
    image = matplotlib.image.imread(scene)
    height, width = image.shape[:2]
    fig_w = 5.0
    fig = Figure(figsize=(fig_w, fig_w * height / width + 1.0))
    top, bottom = fig.subplots(2, 1, height_ratios=[fig_w * height / width, 1.0])
    top.imshow(image)
    top.set_axis_off()
    _strip(bottom, res, f)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    return path


def _strip(ax, res: StoreResults, f: FirstFeasible) -> None:
    """One tile per try, left to right: the constraint and D's planning time of the entry."""
    shown = f.tried[-STRIP_TRIES:]
    hidden = len(f.tried) - len(shown)
    for k, j in enumerate(shown):
        feasible = k == len(shown) - 1
        ax.add_patch(Rectangle((k + 0.05, 0.05), 0.9, 0.9, color=_FOUND if feasible
                               else _FAILED, alpha=0.85))
        ax.text(k + 0.5, 0.5, f"#{hidden + k + 1}\nc{j}\n{_seconds(res.times[f.row, j])}",
                ha="center", va="center", fontsize=7, color="white")
    ax.set_xlim(0, max(len(shown), 4))
    ax.set_ylim(0, 1)
    ax.set_axis_off()
    note = f" ({hidden} earlier failed tries not drawn)" if hidden else ""
    ax.set_title("BOX's first try is feasible" if f.tries == 1 else
                 f"BOX's tries: {f.tries - 1} failed, then feasible{note}", fontsize=8)


def _seconds(t: float) -> str:
    if not np.isfinite(t):
        return "-"
    return f"{t * 1e3:.2g} ms" if t < 0.01 else (f"{t * 1e3:.0f} ms" if t < 1 else f"{t:.3g} s")
