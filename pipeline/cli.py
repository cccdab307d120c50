"""The ``box`` command line."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape

import box_core
from box_core import synthetic
from box_core.io import MatrixFile, load_matrix
from pipeline.store import ScoreStore, StoreDamaged, StoreError
from pipeline.store.layout import (
    CHECKS,
    FEASIBLE,
    INSTANCE_SEED,
    INSTANCE_SPEC,
    SCORES,
    THETA,
)
from pipeline.store.storage_errors import translated
from pipeline.tables import stdout_console, summary_table

app = typer.Typer(
    help="Score-space constraint selection (BOX). Inspect score stores made by "
    "`python -m pipeline` (status, show, export) and evaluate selectors on any score matrix "
    "(evaluate, demo).",
    no_args_is_help=True,
)
out = stdout_console()
err = Console(stderr=True)

#: Exit codes: a damaged store; bad input (missing file or array, wrong shapes, bad values,
#: a store that cannot be reached or read).
DAMAGED, BAD_INPUT = 1, 2


def _version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        out.print(f"box-planning {version('box-planning')}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit.")) -> None:
    """Score-space constraint selection (BOX)."""


def _fail(message: str, kind: str = "error", code: int = BAD_INPUT) -> None:
    err.print(f"[bold red]{kind}:[/] {escape(message)}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


@contextlib.contextmanager
def _reading(store):
    """Read ``store`` in the block: a store that cannot be used (bad input, or a storage
    failure: credentials, endpoint, permissions, unreadable metadata) ends the command with
    one line and exit code 2, a damaged one with one line and exit code 1."""
    try:
        with translated(store):
            yield
    except (StoreError, ValueError) as exc:
        _fail(str(exc))
    except StoreDamaged as exc:
        _fail(str(exc), "damaged", DAMAGED)


@app.command()
def evaluate(
    file: Path = typer.Argument(..., help="Score matrix file (.npz, or .mat from MATLAB), a "
                                "box export (.npz, .nc, .parquet), or a score store (.zarr "
                                "folder) made by the pipeline."),
    selectors: str = typer.Option(
        "", help=f"Comma-separated selectors, of: {', '.join(sorted(box_core.SELECTORS))} "
        "(doo needs constraint features). Default: box, static, "
        "rand, plus doo when the file has features."),
    k: int = typer.Option(None, "-k", help="Tries per held-out instance (default: all m)."),
    seed: int = typer.Option(0, help="Seed of the random selectors (fold i uses (seed, i))."),
    c: float = typer.Option(1.96, help="BOX's UCB coefficient."),
    failure_rule: str = typer.Option("magnitude", help="Failure score rule: magnitude or literal."),
    scores_var: str = typer.Option(None, help="Name of the score matrix array / variable "
                                   "(default: scores). A name given must exist."),
    times_var: str = typer.Option(None, help="Name of the per-entry planning times, seconds "
                                  "(default: times or time when present, else 1 per try)."),
    feasible_var: str = typer.Option(None, help="Name of the feasibility mask (default: "
                                     "feasible when present)."),
    features_var: str = typer.Option(None, help="Name of the constraint features, m x p "
                                     "(default: features or theta when present)."),
    instance_features_var: str = typer.Option(
        None, help="Name of the instance features, n x q, for the contextual selectors "
        "(default: instance_features when present)."),
    checks_var: str = typer.Option(None, help="Name of the collision checks per entry, n x "
                                   "m, for capped tries (default: checks when present)."),
    overhead: bool = typer.Option(True, help="Add the selectors' own compute time to times."),
    as_json: bool = typer.Option(False, "--json", help="Print the result as JSON."),
):
    """Leave-one-out evaluation of constraint selectors on a score matrix FILE.

    Rows are instances, columns constraints, higher scores are better. Without a
    feasibility mask, entries equal to the matrix minimum count as failures. An array named
    with --*-var must exist in FILE; a damaged file or pickled objects are refused (exit 2).
    """
    forbidden = None
    if file.is_dir():
        with _reading(file):
            data, forbidden = store_matrix(file)
    else:
        try:
            if file.suffix in (".nc", ".parquet") and file.is_file():
                from pipeline.export import read_export

                data, forbidden = read_export(file)
            else:
                data = load_matrix(file, scores=scores_var, times=times_var,
                                   feasible=feasible_var, features=features_var,
                                   instance_features=instance_features_var,
                                   checks=checks_var)
        except (FileNotFoundError, ValueError, StoreError) as exc:
            _fail(str(exc))
    names = [s.strip() for s in selectors.split(",") if s.strip()]
    if not names:
        names = ["box", "static", "rand"] + (["doo"] if data.features is not None else [])
    _evaluate_matrix(data, file, names, k=k, seed=seed, c=c, failure_rule=failure_rule,
                     overhead=overhead, as_json=as_json,
                     forbidden=data.forbidden if forbidden is None else forbidden)


def store_matrix(path: Path) -> tuple[MatrixFile, np.ndarray | None]:
    """The store's matrix, and the columns each row must not try: those extracted from its
    own raw solution (hidden as ``stage=evaluate`` hides them by default)."""
    from pipeline.evaluation import own_constraints

    store = ScoreStore.open(path)
    if store.stage_info("scores") is None:
        raise StoreError(f"{path}: the score matrix is not complete; finish it with "
                         "python -m pipeline stage=generate")
    from pipeline.evaluation import instance_features

    scores, feasible, times, theta = store.score_matrix()
    return (MatrixFile(scores=scores, times=times, feasible=feasible, features=theta,
                       instance_features=instance_features(store),
                       checks=store.result(SCORES, CHECKS)), own_constraints(store))


def _evaluate_matrix(data: MatrixFile, file: Path, names: list[str], *, k=None, seed=0,
                     c=1.96, failure_rule="magnitude", overhead=True, as_json=False,
                     forbidden=None) -> None:
    """Run the LOOCV on loaded ``data`` and print its summary (table or JSON)."""
    from pipeline.evaluation import loocv_workers
    from pipeline.planning.blas import single_thread_with_children
    from pipeline.validation import available_memory, evaluation_bytes, memory_text

    params = {"box": {"c": c}} if "box" in names else {}
    shape = np.shape(data.scores)
    if len(shape) == 2:
        need, have = evaluation_bytes(*shape, len(names)), available_memory()
        if have is not None and need > have:
            _fail(f"{file}: evaluating a {shape[0]} x {shape[1]} matrix needs about "
                  f"{memory_text(need)} of memory, {memory_text(have)} is available")
    try:
        with single_thread_with_children():  # both processes: one BLAS thread each
            result = box_core.loocv(
                data.scores, times=data.times, feasible=data.feasible,
                features=data.features, selectors=names, k=k, seed=seed, params=params,
                failure_rule=failure_rule, measure_overhead=overhead, forbidden=forbidden,
                instance_features=data.instance_features, checks=data.checks,
                until_best=True, workers=loocv_workers(int(np.prod(shape))))
    except ValueError as exc:
        _fail(f"{file}: {exc}")
    except MemoryError:
        _fail(f"{file}: not enough memory to evaluate a {shape} matrix")
    summary = result.summary()
    n, m = data.scores.shape
    rule = ("given" if data.feasible is not None else
            f"derived: entries scoring above the minimum ({float(np.min(data.scores)):.4g}) "
            "are feasible (give a feasibility mask with --feasible-var to say otherwise)")
    if as_json:
        doc = {"file": str(file), "n": n, "m": m, "feasibility": rule,
               "failure_value": result.failure_value,
               "rows_with_feasible": int(result.eligible.sum()), **summary.to_dict()}
        typer.echo(json.dumps(doc, indent=2))
        return
    if data.feasible is None:
        err.print(f"feasibility {rule}", highlight=False, soft_wrap=True)
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
        _outside_stores(path, "--path")
    except ValueError as exc:
        _fail(str(exc))
    try:
        useful = min(50, m)  # the paper's matrix: about 50 of 162 grasps ever feasible
        data = synthetic.score_matrix(n, m, useful=useful, per_type=min(4, useful), seed=seed)
    except ValueError as exc:
        _fail(str(exc))
    if path.exists() and not overwrite and not _holds(path, data):
        _fail(f"{path} exists and holds a different matrix; pass --overwrite to replace it")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        data.save(path)
    except OSError as exc:
        _fail(f"--path {path}: cannot write there ({exc.strerror or exc})")
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


STORE_HELP = "A score store (.zarr folder) made by python -m pipeline."
STORE_URL_HELP = STORE_HELP + " A URL (s3://bucket/x.zarr, file:///...) works too."


@app.command()
def status(store: str = typer.Argument(..., help=STORE_URL_HELP),
           as_json: bool = typer.Option(False, "--json", help="Print the status as JSON.")):
    """Show what STORE holds: stages, completion, corrupted chunks.

    Exit code 0 when every chunk reads back as recorded, 1 when some are corrupted or
    missing (re-running the stage recomputes them), 2 when STORE is missing, not a store
    of this pipeline, or cannot be reached or read (credentials, endpoint, permissions, a
    truncated or invalid zarr.json).
    """
    from pipeline.store.status import collect, damaged, print_status

    with _reading(store):
        report = collect(store) if as_json else print_status(store, out)
    if as_json:
        typer.echo(json.dumps(report, indent=2))
    if damaged(report):
        raise typer.Exit(DAMAGED)


@app.command()
def show(
    store: Path = typer.Argument(..., help=STORE_HELP),
    instance: int = typer.Option(..., "--instance", "-i", help="Instance (row) index."),
    constraint: int = typer.Option(None, "--constraint", "-c",
                                   help="Constraint (column) index: plan it and draw the plan."),
    out_path: Path = typer.Option(None, "--out", "-o",
                                  help="PNG to write (default: instance<I>[-constraint<J>].png)."),
    overwrite: bool = typer.Option(False, help="Replace an existing PNG."),
):
    """Render one instance of STORE to a PNG, optionally with a constraint's plan.

    With --constraint J, entry (I, J) is planned again with its stored seed, which gives
    the same plan as in the score matrix, and drawn.
    """
    from pipeline.worker import domain_for, entry_seed

    name = f"instance{instance}" + ("" if constraint is None else f"-constraint{constraint}")
    target = out_path or Path.cwd() / f"{name}.png"
    with _reading(store):  # everything from the store first, so a failure there draws nothing
        st = ScoreStore.open(store)
        if not st.has(INSTANCE_SPEC):
            raise StoreError(f"{store} has no instances yet; run stage=instances first")
        specs = st.array(INSTANCE_SPEC)
        n = specs.shape[0]
        if not 0 <= instance < n:
            raise ValueError(f"--instance {instance} out of range: the store has {n} instances")
        spec = json.loads(str(specs[instance]))
        domain = domain_for(st.domain_spec())
        check_png_target(target, overwrite)
        theta = seed = was = None
        if constraint is not None:
            if not st.has(THETA):
                raise StoreError(f"{store} has no constraints yet; run stage=constraints first")
            theta = st.theta()
            if not 0 <= constraint < theta.shape[0]:
                raise ValueError(f"--constraint {constraint} out of range: the store has "
                                 f"{theta.shape[0]} constraints")
            seed = entry_seed(int(st.attrs["config"]["seed"]),
                              int(st.array(INSTANCE_SEED)[instance]), constraint)
            if st.has_results(SCORES) and st.done(SCORES)[instance, constraint]:
                was = bool(st.result(SCORES, FEASIBLE)[instance, constraint])
    try:
        if constraint is None:
            domain.render(spec, None, target)
        else:
            plan = domain.plan(domain.check_instance(spec), theta[constraint], seed=seed)
            domain.render(spec, plan, target, constraint=theta[constraint])
    except ValueError as exc:
        _fail(str(exc))
    except OSError as exc:
        _fail(f"-o {target}: cannot write there ({exc.strerror or exc})")
    if constraint is None:
        out.print(f"wrote {target}")
        return
    stored = "" if was is None else " (as in the score matrix)" if was == plan.feasible else \
        f" (the score matrix says {'feasible' if was else 'infeasible'})"
    verdict = f"feasible, length {plan.length:.4g}" if plan.feasible else plan.status.name.lower()
    out.print(f"wrote {target}: {verdict}{stored}, {plan.time * 1e3:.1f} ms", highlight=False)


def _outside_stores(path: Path, option: str) -> None:
    from pipeline.export import enclosing_store

    store = enclosing_store(path)
    if store is not None:
        raise ValueError(f"{option} {path}: inside the zarr store {store}; nothing is written "
                         "into a store")


def check_png_target(target: Path, overwrite: bool) -> None:
    """Refuse a PNG path that is not a .png, exists (without ``overwrite``) or lies in a
    zarr store."""
    if target.suffix.lower() != ".png":
        raise ValueError(f"-o {target}: give a path ending in .png")
    _outside_stores(target, "-o")
    if target.exists() and not (overwrite and target.is_file()):
        raise ValueError(f"-o {target} exists; pass --overwrite to replace it"
                         if target.is_file() else f"-o {target} exists and is not a file")


@app.command()
def export(
    store: str = typer.Argument(..., help=STORE_URL_HELP),
    fmt: str = typer.Option("npz", "--format", "-f", help="npz (a NumPy archive), netcdf (an "
                            "xarray Dataset, .nc), parquet (one row per entry) or csv (a folder "
                            "of CSV files plus metadata.json); box evaluate reads the first "
                            "three."),
    out_path: Path = typer.Option(None, "--out", "-o", help="Where to write (default: in "
                                  "the current folder, named after the store). Never inside "
                                  "a store."),
    overwrite: bool = typer.Option(False, help="Replace an existing file, or a folder that "
                                   "holds a previous csv export."),
):
    """Export STORE's score matrix and metadata (npz, netcdf, parquet or csv) for other tools.

    Writes scores (NaN where infeasible; the failure value box evaluate uses is in the
    metadata), times, feasibility, path lengths, statuses and failed steps, constraint
    features and the store's config. An unfinished store is exported with a `done` mask
    and a warning.
    """
    from pipeline.export import export as write

    with _reading(store):
        path, complete = write(store, fmt, out_path, overwrite=overwrite)
    out.print(f"wrote {path}", highlight=False)
    if not complete:
        err.print("[yellow]warning:[/] the store is not complete; entries not computed yet "
                  "have done = 0")


def main() -> None:  # pragma: no cover - console entry point
    app()
