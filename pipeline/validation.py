"""Every config key checked before any stage runs, whatever the stage.

``python -m pipeline`` calls :func:`validate` on the composed config before it opens a store
or starts a cluster, so a bad value is refused in one line naming the key, with nothing
written: not after ``generate`` has run for an hour, not half-way through a report.

Hydra's schemas (:mod:`pipeline.configs`) already refuse unknown keys and wrong types; this
module checks values, the keys that depend on each other, and memory: it estimates the
arrays the requested stages will hold (from the measured sizes below) and refuses a run
that cannot fit in the memory available now, naming the keys that make it too big.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from omegaconf import OmegaConf

from pipeline.configs import RAWPLANNER, Stage

#: Selector the report draws for its learning curve, its C sensitivity and its renders.
REPORT_NEEDS = "box"

REPORT_FORMATS = ("png", "svg", "pdf")

# -- memory model --------------------------------------------------------------------------
# Measured with tracemalloc on box_core.loocv (benchmarks/bench_memory_estimate.py prints
# the estimate against the measured peak): about 95 bytes per score entry and 9.7 kB per
# instance and selector (the best-score curves on the 200-point time grid), plus the m x m
# covariance and its fold copy.  Loading the store adds the score, feasibility, length and
# time arrays (25 bytes per entry).
EVAL_BYTES_PER_ENTRY = 128
EVAL_BYTES_PER_ROW_AND_SELECTOR = 10_000
#: An instance spec held by the coordinator: JSON text up to ~2.6 kB (pick_place), kept as
#: a Python string and as a fixed-width (4 bytes per character) NumPy array.
SPEC_BYTES = 16 * 1024
#: What the coordinator keeps per block task (Task object, Dask future and key).
TASK_BYTES = 4 * 1024
#: One block of the score arrays (pipeline.store.RESULT_COLUMNS: 35 bytes per entry), held
#: by a worker, plus the compressor's copy of each chunk.
BLOCK_BYTES_PER_ENTRY = 2 * 35
#: A local Dask worker process with the planning libraries loaded.
WORKER_BYTES = 150 * 1024**2


class ConfigError(ValueError):
    """A config value that cannot run (the message names the key)."""


@dataclass(frozen=True)
class Need:
    """Bytes one part of a run holds at once, and the keys that size it."""

    what: str
    keys: str
    bytes: float


def validate(cfg, available: float | None = None, report_stores: bool = True) -> None:
    """Check every key of ``cfg`` (a composed Hydra config or a plain dict).

    ``available``: bytes of memory the run may use (default: what the OS reports as
    available now; None there skips the memory checks).  Raises :class:`ConfigError`.
    Stage ``report`` also needs its stores to hold an evaluation of ``box``; that is
    checked here too, before anything is written (a StoreError for a missing store),
    unless ``report_stores`` is False (a sweep checked before it starts: an earlier job may
    make them; each job checks them again when it starts).
    """
    plain = (OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
             if OmegaConf.is_config(cfg) else cfg)
    stage = Stage(plain["stage"])
    check_values(plain)
    check_memory(plain, stage, available_memory() if available is None else available)
    if stage is Stage.all and REPORT_NEEDS not in plain["evaluate"]["selectors"]:
        raise ConfigError(f"evaluate.selectors={plain['evaluate']['selectors']}: stage all ends "
                          f"with the report, which draws {REPORT_NEEDS} (learning curve, C "
                          f"sensitivity, renders); add {REPORT_NEEDS}")
    if report_stores and stage is Stage.report:
        check_report_stores(report_paths(plain))
    if report_stores and stage is Stage.all and plain["report"]["stores"]:  # evaluates its own
        own = run_store(plain)
        check_report_stores([p for p in report_paths(plain) if p != own])


# -- values --------------------------------------------------------------------------------
def check_values(c: dict) -> None:
    """Every key's value on its own and against the keys it depends on."""
    _at_least(c, "seed", 0)
    _at_least(c, "instances.n", 3, why=" (leave-one-out needs them)")
    _at_least(c, "constraints.m", 1)
    _at_least(c, "store.block_instances", 1)
    _at_least(c, "store.block_constraints", 1)
    if not c["progress_every"] > 0:
        raise ConfigError(f"progress_every={c['progress_every']}: must be > 0 (seconds "
                          "between progress lines)")
    _check_cluster(c)
    _check_planner_and_domain(c)
    _check_evaluate(c)
    _check_report(c)
    _check_solve(c)


def _check_cluster(c: dict) -> None:
    """The ``cluster.*`` keys, by the cluster's own rules (one place for them)."""
    from pipeline.cluster import ClusterError
    from pipeline.cluster.checks import check_config
    from pipeline.configs import ClusterConfig

    try:
        check_config(OmegaConf.merge(OmegaConf.structured(ClusterConfig), c["cluster"]))
    except ClusterError as exc:
        raise ConfigError(str(exc)) from None


def _check_planner_and_domain(c: dict) -> None:
    from pipeline import configs
    from pipeline.domains import domain_config, domain_names

    try:
        configs.planner_settings(c["planner"])
    except (ValueError, TypeError) as exc:
        raise ConfigError(str(exc)) from None
    domain = dict(c["domain"])
    name = domain.pop("name", None)
    if name not in domain_names():
        raise ConfigError(f"domain={name}: unknown domain; choose from "
                          f"{', '.join(domain_names())}")
    try:
        domain_config(name, domain)  # its schema only: no domain module, no simulator
    except (ValueError, TypeError) as exc:
        raise ConfigError(str(exc)) from None


def _check_evaluate(c: dict) -> None:
    from box_core import SELECTORS
    from box_core.failure import RULES

    e = c["evaluate"]
    _selectors("evaluate.selectors", e["selectors"], {*SELECTORS, RAWPLANNER})
    k, m = e["k"], c["constraints"]["m"]
    if k is not None and not 1 <= k <= m:
        raise ConfigError(f"evaluate.k={k}: must lie between 1 and constraints.m = {m}, or be "
                          "null for all constraints")
    if not (math.isfinite(e["c"]) and e["c"] >= 0):
        raise ConfigError(f"evaluate.c={e['c']}: BOX's coefficient must be a finite number "
                          ">= 0")
    if e["failure_rule"] not in RULES:
        raise ConfigError(f"evaluate.failure_rule={e['failure_rule']}: choose one of "
                          f"{', '.join(RULES)}")


def _check_report(c: dict) -> None:
    r = c["report"]
    _at_least(c, "report.renders", 0)
    _at_least(c, "report.repeats", 1)
    _at_least(c, "report.c_folds", 2)
    formats = list(r["formats"])
    bad = [f for f in formats if f not in REPORT_FORMATS]
    if bad or "png" not in formats:
        raise ConfigError(f"report.formats={formats}: must include png and may add svg or pdf"
                          + (f" ({', '.join(map(str, bad))} unknown)" if bad else ""))
    fractions = list(r["fractions"])
    if not fractions or not all(0 < f <= 1 for f in fractions):
        raise ConfigError(f"report.fractions={fractions}: a non-empty list of shares in (0, 1]")
    grid = list(r["c_grid"])
    if not grid or not all(math.isfinite(x) and x >= 0 for x in grid):
        raise ConfigError(f"report.c_grid={grid}: a non-empty list of finite values >= 0")
    for i, store in enumerate(r["stores"]):
        if not str(store).strip():
            raise ConfigError(f"report.stores[{i}] is empty")


def _check_solve(c: dict) -> None:
    from box_core import SELECTORS

    s = c["solve"]
    _at_least(c, "solve.n", 1)
    names = _selectors("solve.selectors", s["selectors"], {*SELECTORS, RAWPLANNER})
    oracles = [n for n in names if n in ("oracle", "fastest")]
    if oracles:
        raise ConfigError(f"solve.selectors: {oracles[0]} needs the true scores of a new "
                          "instance, which live solving does not have")
    budget = s["max_evaluations"]
    if budget is not None and budget < 1:
        raise ConfigError(f"solve.max_evaluations={budget}: must be >= 1, or null for m")
    seconds = s["max_seconds"]
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise ConfigError(f"solve.max_seconds={seconds}: must be > 0, or null for no limit")


def _selectors(key: str, names, known: set[str]) -> list[str]:
    names = list(names)
    if not names:
        raise ConfigError(f"{key} is empty; choose from {', '.join(sorted(known))}")
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ConfigError(f"{key}: unknown selector(s) {', '.join(map(str, unknown))}; choose "
                          f"from {', '.join(sorted(known))}")
    return names


def _at_least(c: dict, key: str, low: int, why: str = "") -> None:
    value = _get(c, key)
    if value < low:
        raise ConfigError(f"{key} must be >= {low}{why}, got {value}")


def _get(c: dict, key: str):
    node = c
    for part in key.split("."):
        node = node[part]
    return node


# -- memory --------------------------------------------------------------------------------
def available_memory() -> float | None:
    """Bytes of memory available to new allocations now (Linux: MemAvailable), else the
    physical memory, else None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def needs(c: dict, stage: Stage) -> tuple[list[Need], list[Need]]:
    """(what the coordinating process holds at once, what one worker holds) for ``stage``,
    each a list of the largest simultaneous allocations."""
    n, m = c["instances"]["n"], c["constraints"]["m"]
    bi, bj = c["store"]["block_instances"], c["store"]["block_constraints"]
    generating = stage in (Stage.instances, Stage.raw, Stage.constraints, Stage.scores,
                           Stage.generate, Stage.all)
    coordinator, worker = [], []
    if generating:
        coordinator.append(Need("instance specs", "instances.n", n * SPEC_BYTES))
        tasks = math.ceil(n / bi) * math.ceil(m / bj)
        coordinator.append(Need(f"{tasks:.3g} block tasks",
                                "instances.n / store.block_instances",
                                tasks * TASK_BYTES))
        coordinator.append(Need("the feasibility matrix", "instances.n x constraints.m",
                                2.0 * n * m))
        worker.append(Need(f"one {bi} x {bj} block",
                           "store.block_instances x store.block_constraints",
                           float(bi) * bj * BLOCK_BYTES_PER_ENTRY))
        if c["cluster"]["kind"] == "local":
            workers = c["cluster"]["n_workers"] or os.cpu_count() or 1
            coordinator.append(Need(f"{workers} local worker processes", "cluster.n_workers",
                                    workers * WORKER_BYTES))
    if stage in (Stage.evaluate, Stage.all):
        selectors = len(set(c["evaluate"]["selectors"]))
        coordinator.append(Need("the leave-one-out evaluation", "instances.n x constraints.m",
                                evaluation_bytes(n, m, selectors)))
    if stage is Stage.solve:
        coordinator.append(Need("fresh instances", "solve.n", c["solve"]["n"] * SPEC_BYTES))
    return coordinator, worker


def evaluation_bytes(n: int, m: int, selectors: int) -> float:
    """Estimated peak bytes of a leave-one-out evaluation of an n x m store."""
    return (float(n) * m * EVAL_BYTES_PER_ENTRY + float(n) * selectors
            * EVAL_BYTES_PER_ROW_AND_SELECTOR + 2.0 * 8 * m * m)


def check_memory(c: dict, stage: Stage, available: float | None) -> None:
    if available is None:
        return
    coordinator, worker = needs(c, stage)
    total = sum(need.bytes for need in coordinator)
    if total > available:
        big = max(coordinator, key=lambda need: need.bytes)
        lower = big.keys.replace(" x ", " or ").replace(" / ", " or raise ")
        raise ConfigError(
            f"{_values(c, big.keys)}: stage {stage.value} would hold about "
            f"{memory_text(total)} in memory ({big.what}: {memory_text(big.bytes)}), but "
            f"{memory_text(available)} is available; lower {lower}")
    local = c["cluster"]["kind"] == "local"
    workers = (c["cluster"]["n_workers"] or os.cpu_count() or 1) if local else 1
    per_worker = available / workers  # remote workers: unknown here, this machine's memory
    for need in worker:
        if need.bytes > per_worker:
            where = (f"each of {workers} local workers has about {memory_text(per_worker)}"
                     if local else f"this machine has {memory_text(available)}")
            raise ConfigError(
                f"{_values(c, need.keys)}: {need.what} needs about {memory_text(need.bytes)} "
                f"in a worker, but {where}; lower {need.keys.replace(' x ', ' and ')}")


def _values(c: dict, keys: str) -> str:
    """'instances.n x constraints.m' -> 'instances.n=1000, constraints.m=162'."""
    names = [k.strip() for k in keys.replace(" / ", " x ").split(" x ")]
    return ", ".join(f"{k}={_get(c, k)}" for k in names)


def memory_text(b: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if b < 1024 or unit == "PiB":
            return f"{b:.3g} {unit}"
        b /= 1024
    return f"{b:.3g} PiB"  # pragma: no cover


# -- stores a stage reads ------------------------------------------------------------------
def report_paths(c: dict) -> list[Path]:
    """The stores stage ``report`` reads: report.stores, else this run's store."""
    stores = c["report"]["stores"]
    if stores:
        return [Path(p).expanduser().absolute() for p in stores]
    return [run_store(c)]


def run_store(c: dict) -> Path:
    """This run's store (as :class:`pipeline.stages.Run` resolves it)."""
    from pipeline.planning.settings import planner_label
    from pipeline.store import default_path

    path = c["store"]["path"] or default_path(c["domain"]["name"], planner_label(c["planner"]),
                                              c["seed"])
    return Path(path).expanduser().absolute()


def check_report_stores(paths: list[Path], available: float | None = None) -> None:
    """Each store must hold a finished evaluation of ``box`` (what the report draws), and
    its report must fit in memory.  StoreError for a path that is not a store."""
    from pipeline.store import ScoreStore

    available = available_memory() if available is None else available
    for path in paths:
        store = ScoreStore.open(path)
        info = store.stage_info("evaluate")
        if info is None:
            raise ConfigError(f"report: {path} has no evaluation yet; run stage=evaluate (or "
                              "stage=all) on it first")
        evaluated = [line["name"] for line in info.get("summary", {}).get("selectors", [])]
        if REPORT_NEEDS not in evaluated:
            raise ConfigError(
                f"report: {path} was evaluated with selectors {evaluated}; the report draws "
                f"{REPORT_NEEDS} (learning curve, C sensitivity, renders): re-run "
                f"stage=evaluate with evaluate.selectors including {REPORT_NEEDS}")
        shape = store.matrix_shape()
        if available is not None and shape is not None:
            n, m = shape
            need = evaluation_bytes(n, m, 2)
            if need > available:
                raise ConfigError(f"report: {path} ({n} x {m}) needs about {memory_text(need)} in "
                                  f"memory, but {memory_text(available)} is available")
