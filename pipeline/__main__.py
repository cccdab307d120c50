"""``python -m pipeline stage=NAME key=value ...`` (Hydra; ``-m`` for sweeps)."""

from __future__ import annotations

import os
import sys

# Global settings belong to entry points.  Importing distributed resets its logger to INFO
# unless this is set before it loads; workers started by this process inherit it.
os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")

import hydra  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.markup import escape  # noqa: E402

from pipeline.configs import CONF_DIR, register_configs  # noqa: E402

register_configs()

#: Exit codes: bad input (config values, stores) and an interrupted run.
BAD_INPUT, FAILED, INTERRUPTED = 2, 1, 130


@hydra.main(config_path=str(CONF_DIR), config_name="config", version_base="1.3")
def main(cfg) -> None:
    from pipeline.execution import TaskFailed
    from pipeline.stages import run_pipeline
    from pipeline.store import StoreDamaged, StoreError
    from pipeline.tables import stdout_console
    from pipeline.validation import validate

    console = stdout_console()
    err = Console(stderr=True)
    try:
        validate(cfg)  # every key, whatever the stage, before anything is opened or written
        run_pipeline(cfg, console, explicit=explicit_keys())
    except (StoreError, ValueError) as exc:
        _end(err, "error", exc, BAD_INPUT)
    except StoreDamaged as exc:
        _end(err, "damaged", exc, FAILED)
    except TaskFailed as exc:
        _end(err, "failed", exc, FAILED)
    except Exception as exc:  # noqa: BLE001 - storage failures come as many types
        from pipeline.store.storage_errors import storage_error

        problem = storage_error(exc, _location(cfg))  # e.g. the endpoint went away mid-run
        if problem is None:
            raise
        _end(err, "error", problem, BAD_INPUT)
    except KeyboardInterrupt:
        err.print("interrupted: finished blocks are saved; re-run the same command to resume")
        sys.exit(INTERRUPTED)


def explicit_keys() -> frozenset[str]:
    """The dotted config keys this job's command line set (Hydra's overrides of the task, a
    sweep's values included).  A store made before a key's default changed continues under
    the value it was made with unless the key is among these
    (:func:`pipeline.configs.earlier_values`)."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.core.override_parser.overrides_parser import OverridesParser

    task = list(HydraConfig.get().overrides.task)
    return frozenset(o.key_or_group for o in OverridesParser.create().parse_overrides(task))


def _end(err: Console, kind: str, exc: Exception, code: int) -> None:
    """One line on stderr and in the run's log, then exit with ``code``."""
    import logging

    err.print(f"[bold red]{kind}:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)
    logging.getLogger("pipeline").error("%s: %s", kind, exc)
    sys.exit(code)


#: Hydra's flag for a sweep (``-m``): each of its jobs is checked before any starts
MULTIRUN = ("-m", "--multirun")


def config_error(args: list[str]) -> str | None:
    """One line saying why the config composed from ``args`` cannot run: Hydra cannot
    compose it (an unknown key, a value of the wrong type), a value is refused by
    :func:`pipeline.validation.validate`, or its store cannot be used (:func:`check_store`).
    A sweep (``-m``): the first of its jobs that cannot run (:func:`sweep_error`).  None
    when it can run, or when ``args`` hold other flags (``--cfg``, ...), which Hydra handles
    itself (``main`` validates each job).

    Checked before Hydra starts, so a refused command writes nothing, not even Hydra's
    ``outputs/`` or ``multirun/`` folder."""
    flags = [a for a in args if a.startswith("-")]
    if flags:
        if set(flags) <= set(MULTIRUN):
            return sweep_error([a for a in args if a not in MULTIRUN])
        return None
    return _job_error(args)


def sweep_error(overrides: list[str]) -> str | None:
    """The first job of the sweep ``overrides`` that cannot run (:func:`config_error`),
    named as Hydra numbers it, with its swept values: ``sweep job #1 (evaluate.k=0):
    evaluate.k=0: must lie between ...``.  None when every job can run, or when the sweep
    is not the basic sweeper's (``hydra/sweeper=...``: another sweeper reads the overrides
    its own way; Hydra validates each job it makes)."""
    for number, (swept, job) in enumerate(sweep_jobs(overrides) or ()):
        problem = _job_error(job, in_sweep=True)
        if problem:
            return f"sweep job #{number} ({' '.join(swept)}): {problem}" if swept else problem
    return None


def sweep_jobs(overrides: list[str]) -> list[tuple[list[str], list[str]]] | None:
    """The jobs Hydra's basic sweeper makes of ``overrides``: (the job's swept overrides,
    all its overrides) each, in the sweeper's order (the cartesian product of the sweeps,
    the last varying fastest).  Overrides Hydra cannot parse are one job (composing it
    names the problem); None when another sweeper is chosen or a sweep is not a list of
    values (an interval, which only an optimising sweeper samples)."""
    import itertools

    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except Exception:  # noqa: BLE001 - Hydra's parser raises several types; compose names it
        return [([], overrides)]
    if any(o.key_or_group == "hydra/sweeper" for o in parsed):
        return None
    choices = []
    for o in parsed:
        if not o.is_sweep_override():
            choices.append([(False, o.input_line)])
            continue
        try:
            values = list(o.sweep_string_iterator())
        except Exception:  # noqa: BLE001 - an interval sweep: not the basic sweeper's
            return None
        choices.append([(True, f"{o.get_key_element()}={v}") for v in values])
    return [([arg for swept, arg in job if swept], [arg for _, arg in job])
            for job in itertools.product(*choices)]


def _job_error(args: list[str], in_sweep: bool = False) -> str | None:
    """:func:`config_error` of one run's overrides.  ``in_sweep``: a job of a sweep,
    checked before the sweep starts, so the stores an earlier job may make are not required
    yet (those a report reads, the run's own for a stage that needs earlier ones); each job
    checks them when it starts."""
    broken = plugin_problem(args)
    if broken:
        return broken
    from hydra import compose, initialize_config_dir

    from pipeline.store import StoreError
    from pipeline.validation import validate

    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = compose(config_name="config", overrides=args)
    except Exception as exc:  # noqa: BLE001 - Hydra/OmegaConf raise many types; all mean "bad"
        return _one_line(exc)
    try:
        validate(cfg, report_stores=not in_sweep)
        check_store(cfg, in_sweep)
    except (StoreError, ValueError) as exc:
        return str(exc)
    return None


def plugin_problem(args: list[str]) -> str | None:
    """Why the domain or planner plug-in that ``args`` choose cannot be loaded, if it
    cannot (:func:`pipeline.plugins.problem`)."""
    from pipeline.plugins import problem

    for arg in args:
        group, _, value = arg.partition("=")
        if group in ("domain", "planner") and problem(group, value):
            return problem(group, value)
    return None


def _location(cfg):
    """The Location of the run's store (as :class:`pipeline.stages.Run` resolves it)."""
    from omegaconf import OmegaConf

    from pipeline.store.location import locate
    from pipeline.validation import run_store

    plain = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
    return locate(plain["store"]["path"] or run_store(plain),
                  plain["store"].get("storage_options"))


def check_store(cfg, in_sweep: bool = False) -> None:
    """The run's store, if something is there, can be reached and is a store of ours whose
    metadata can be read: a StoreError otherwise (no credentials, an endpoint that cannot be
    reached, permission denied, a ``zarr.json`` that is truncated or invalid, a foreign
    store).  Where nothing is there, the stage must be one that can start a store (not
    ``stage=evaluate`` alone, say: it would make an empty store only to refuse it), unless
    ``in_sweep`` (:func:`_job_error`).  The run checks all this again; checking it first
    writes nothing."""
    from pipeline.configs import NEEDS, needs_first
    from pipeline.store import StoreError, check_is_ours

    location = _location(cfg)
    if not location.is_empty():
        check_is_ours(location)
        return
    if in_sweep:
        return
    stage = getattr(cfg.stage, "value", cfg.stage)
    if stage in NEEDS:
        raise StoreError(f"no store at {location}: {needs_first(NEEDS[stage], stage)}")
    if stage in ("solve", "status"):  # they read a store (a report's are validate's)
        raise StoreError(f"no store at {location}")


def _one_line(exc: Exception) -> str:
    """Hydra's multi-line composition error as one line: the override, then the reason (a
    YAML file that cannot be parsed, the package's or one on ``hydra.searchpath``: the file,
    line and column, then what the parser found)."""
    mark = getattr(exc, "problem_mark", None)  # yaml's MarkedYAMLError
    if mark is not None:
        return (f"{mark.name} line {mark.line + 1} column {mark.column + 1}: not valid YAML "
                f"({getattr(exc, 'problem', None) or type(exc).__name__})")
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    head = lines[0] if lines else type(exc).__name__
    for prefix in ("Error merging override ", "Could not override "):
        if head.startswith(prefix):
            head = head.removeprefix(prefix).strip("'.")
    if exc.__cause__ is not None:
        reason = str(exc.__cause__).strip().splitlines()
        return f"{head}: {reason[0] if reason else type(exc.__cause__).__name__}"
    if "Available options" in str(exc):
        options = [ln for ln in lines[lines.index(next(x for x in lines
                                                       if x.startswith("Available"))) + 1:]
                   if not ln.startswith("Config search path") and "=" not in ln]
        options = [o for o in options if not o.endswith("_schema")]
        return f"{head} (available: {', '.join(options)})"
    return head


def run() -> None:
    """The ``box-pipeline`` console script and ``python -m pipeline``: the config checked in
    one line before Hydra starts (a refused command writes nothing), then the run.  Shell
    completion (``-sc``) is Hydra's, offering only real choices (``pipeline.completion``)."""
    from pipeline import completion

    problem = config_error(sys.argv[1:])
    if problem:
        Console(stderr=True).print(f"[bold red]error:[/] {escape(problem)}", highlight=False,
                                   soft_wrap=True)
        sys.exit(BAD_INPUT)
    if completion.is_query(sys.argv[1:]):
        with completion.filtered_answer():  # Hydra's answer less the schema entries
            main()
        return
    main()


if __name__ == "__main__":
    run()
