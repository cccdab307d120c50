"""The ``box`` command line."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import typer
from rich.console import Console

import box_core
from box_core import synthetic
from box_core.io import MatrixFile, load_matrix
from pipeline.tables import summary_table

app = typer.Typer(
    help="Score-space constraint selection (BOX): evaluate selectors on score matrices.",
    no_args_is_help=True,
    add_completion=False,
)
# Off a terminal (pipes, CI logs) rich assumes 80 columns and wraps the table badly.
out = Console(width=None if sys.stdout.isatty() else 132)
err = Console(stderr=True)

#: Exit code for bad input (missing file or array, wrong shapes, bad values).
BAD_INPUT = 2


def _fail(message: str) -> None:
    err.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(BAD_INPUT)


@app.command()
def evaluate(
    file: Path = typer.Argument(..., help="Score matrix file: .npz, or .mat (MATLAB)."),
    selectors: str = typer.Option(
        "", help="Comma-separated selectors (box, static, rand, doo, pembo, oracle). "
        "Default: box, static, rand, plus doo when the file has features."),
    k: int = typer.Option(None, "-k", help="Tries per held-out instance (default: all m)."),
    seed: int = typer.Option(0, help="Seed of the random selectors (fold i uses (seed, i))."),
    c: float = typer.Option(1.96, help="BOX's UCB coefficient."),
    failure_rule: str = typer.Option("magnitude", help="Failure score rule: magnitude or literal."),
    scores_var: str = typer.Option("scores", help="Name of the score matrix array / variable."),
    times_var: str = typer.Option("times", help="Name of the per-entry planning times (seconds)."),
    feasible_var: str = typer.Option("feasible", help="Name of the feasibility mask."),
    features_var: str = typer.Option("features", help="Name of the constraint features (m x p)."),
    overhead: bool = typer.Option(True, help="Add the selectors' own compute time to times."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
):
    """Leave-one-out evaluation of constraint selectors on a score matrix FILE.

    Rows are instances, columns constraints, higher scores are better. Without a
    feasibility mask, entries equal to the matrix minimum count as failures.
    """
    try:
        data = load_matrix(file, scores=scores_var, times=times_var,
                           feasible=feasible_var, features=features_var)
    except (FileNotFoundError, ValueError) as exc:
        _fail(str(exc))
    names = [s.strip() for s in selectors.split(",") if s.strip()]
    if not names:
        names = ["box", "static", "rand"] + (["doo"] if data.features is not None else [])
    _evaluate_matrix(data, file, names, k=k, seed=seed, c=c, failure_rule=failure_rule,
                     overhead=overhead, as_json=as_json)


def _evaluate_matrix(data: MatrixFile, file: Path, names: list[str], *, k=None, seed=0,
                     c=1.96, failure_rule="magnitude", overhead=True, as_json=False) -> None:
    """Run the LOOCV on loaded ``data`` and print its summary (table or JSON)."""
    params = {"box": {"c": c}} if "box" in names else {}
    try:
        result = box_core.loocv(
            data.scores, times=data.times, feasible=data.feasible, features=data.features,
            selectors=names, k=k, seed=seed, params=params, failure_rule=failure_rule,
            measure_overhead=overhead,
        )
    except ValueError as exc:
        _fail(f"{file}: {exc}")
    summary = result.summary()
    n, m = data.scores.shape
    if as_json:
        doc = {"file": str(file), "n": n, "m": m, "failure_value": result.failure_value,
               "rows_with_feasible": int(result.eligible.sum()), **summary.to_dict()}
        typer.echo(json.dumps(doc, indent=2))
        return
    print_summary(summary, title=f"{file}  ({n} x {m}, failure value {result.failure_value:.4g})")


def print_summary(summary: box_core.Summary, title: str) -> None:
    out.print(summary_table(summary, title))


@app.command()
def demo(
    n: int = typer.Option(1800, help="Instances (rows)."),
    m: int = typer.Option(162, help="Constraints (columns)."),
    seed: int = typer.Option(0, help="Seed of the synthetic matrix and the selectors."),
    path: Path = typer.Option(Path("data/synthetic.npz"), help="Where to write the matrix (.npz)."),
    overwrite: bool = typer.Option(False, help="Replace a different matrix already at PATH."),
):
    """Generate a synthetic score matrix shaped like real planning data and evaluate it.

    Most entries are infeasible, a few dozen constraints are ever feasible and instances
    share latent types, like the paper's grasp-and-arm matrix (1800 x 162). Re-running the
    same command reuses the file; a different matrix at PATH is kept unless --overwrite.
    """
    if path.suffix != ".npz":
        _fail(f"{path}: the demo writes a NumPy archive; give a path ending in .npz")
    try:
        useful = min(50, m)  # the paper's matrix: about 50 of 162 grasps ever feasible
        data = synthetic.score_matrix(n, m, useful=useful, per_type=min(4, useful), seed=seed)
    except ValueError as exc:
        _fail(str(exc))
    if path.exists() and not overwrite and not _holds(path, data):
        _fail(f"{path} exists and holds a different matrix; pass --overwrite to replace it")
    path.parent.mkdir(parents=True, exist_ok=True)
    data.save(path)
    out.print(f"wrote {path}: {n} x {m}, {data.feasible.mean():.1%} of entries feasible")
    matrix = MatrixFile(scores=data.scores, times=data.times, feasible=data.feasible,
                        features=data.features)
    _evaluate_matrix(matrix, path, ["box", "static", "rand", "doo", "pembo"], seed=seed)


def _holds(path: Path, data: synthetic.SyntheticData) -> bool:
    """Whether the archive at ``path`` holds exactly ``data``'s arrays."""
    try:
        old = load_matrix(path)
    except (FileNotFoundError, ValueError):
        return False
    pairs = [(old.scores, data.scores), (old.times, data.times),
             (old.feasible, data.feasible), (old.features, data.features)]
    return all(a is not None and np.array_equal(a, b) for a, b in pairs)


def main() -> None:  # pragma: no cover - console entry point
    app()
