"""Configuration schemas (Hydra structured configs) and loading of the YAML files in conf/.

Every value Hydra composes is checked against these dataclasses, so a typo in a key or a
value of the wrong type is refused before anything runs.  ``identity`` is the part of a
config that determines the score matrix: a store remembers it and refuses to continue
under a different one.
"""

from __future__ import annotations

import enum
import hashlib
import json
from dataclasses import dataclass, field, fields
from typing import Any

from omegaconf import MISSING, OmegaConf

from pipeline.domains import domain_names, domain_schema, has_yaml
from pipeline.planning.settings import SETTINGS, PlannerSettings, keys_of
from pipeline.plugins import problem
from pipeline.yaml_configs import CONF_DIR, load_yaml_config, planner_settings

__all__ = ["CONF_DIR", "Config", "PlannerSettings", "comparable", "differing_keys",
           "earlier_values", "identity", "load_yaml_config", "matching_identity",
           "planner_settings", "register_configs", "with_earlier_values"]


class Stage(enum.Enum):
    instances = "instances"
    raw = "raw"
    constraints = "constraints"
    scores = "scores"
    generate = "generate"
    evaluate = "evaluate"
    report = "report"
    solve = "solve"
    status = "status"
    all = "all"


#: the stage each store-writing stage needs finished first (stage=generate and stage=all
#: run them in order; a stage run alone on a store without it is refused)
NEEDS = {"raw": "instances", "constraints": "raw", "scores": "constraints",
         "evaluate": "scores"}


def needs_first(stage: str, needed_by: str) -> str:
    """The one-line refusal of stage ``needed_by`` on a store where ``stage`` is missing."""
    return (f"stage {needed_by} needs stage {stage} first (run stage={stage}, or "
            "stage=generate for all of them)")


class StoreMode(enum.Enum):
    resume = "resume"  # continue a store made with the same config; refuse a different one
    overwrite = "overwrite"  # replace a store of ours made with a different config


class EnvironmentPolicy(enum.Enum):
    """What a run does with blocks computed in an environment (CPU, libraries, source) that
    differs from the one that computed a store's other blocks (docs/reproducibility.md)."""

    allow = "allow"  # record it per block and say so in one line
    refuse = "refuse"  # keep the store to one environment: stop with one line instead


class ClusterKind(enum.Enum):
    local = "local"
    address = "address"
    slurm = "slurm"


@dataclass
class InstancesConfig:
    n: int = 1000


@dataclass
class ConstraintsConfig:
    m: int = 162  # subsampled (seeded) from the candidates when there are more


@dataclass
class StoreConfig:
    path: str | None = None  # default: data/<domain>-<planner>-seed<seed>.zarr
    mode: StoreMode = StoreMode.resume
    block_instances: int = 25  # a task computes one block = one chunk of every score array
    block_constraints: int = 60
    environment: EnvironmentPolicy = EnvironmentPolicy.allow
    #: passed to the fsspec filesystem of a URL store.path (endpoint_url, key, secret, ...)
    storage_options: dict[str, Any] = field(default_factory=dict)


@dataclass
class SlurmConfig:
    """cluster=slurm: worker jobs submitted through dask-jobqueue (docs/clusters.md).  Each
    job runs ``cores`` single-threaded worker processes."""

    queue: str | None = None  # partition (sbatch -p)
    account: str | None = None  # sbatch -A
    cores: int = 1  # cores per job = worker processes per job
    memory_per_worker: str = "4GB"  # a job asks for this x cores
    walltime: str = "04:00:00"
    interface: str | None = None  # network interface of scheduler and workers (e.g. ib0)
    job_extra_directives: list[str] = field(default_factory=list)  # e.g. ["--qos=long"]
    job_script_prologue: list[str] = field(default_factory=list)  # e.g. ["module load x"]
    local_directory: str | None = None  # workers' scratch folder (e.g. $TMPDIR); null: dask's
    log_directory: str | None = None  # job logs; null: <run's output folder>/slurm-logs
    max_replacements: int = 8  # lost jobs (cancelled, timed out) replaced at most this often


@dataclass
class ClusterConfig:
    kind: ClusterKind = ClusterKind.local
    n_workers: int | None = None  # local: one per allocated core when null; slurm: in total
    address: str | None = None  # kind=address: tcp://host:8786
    retries: int = 3  # per task, after a worker dies or a task raises
    host: str = "127.0.0.1"  # where a scheduler started by this run listens
    dashboard_address: str | None = "127.0.0.1:0"  # its dashboard; null: none
    connect_timeout: float = 30.0  # seconds to reach cluster.address
    worker_timeout: float = 180.0  # seconds without any worker before the run stops
    reuse: bool = False  # keep the cluster for the next run of a sweep in this process
    slurm: SlurmConfig = field(default_factory=SlurmConfig)


#: The selector measured in stage ``raw`` rather than by leave-one-out: the domain's own
#: search over constraints (a name that evaluate.selectors and solve.selectors accept).
RAWPLANNER = "rawplanner"


@dataclass
class EvaluateConfig:
    selectors: list[str] = field(
        default_factory=lambda: ["box", "contextual", "contextual_capped", "eips", "static",
                                 "rand", "doo", "pembo", "oracle", "fastest", RAWPLANNER])
    k: int | None = None  # tries per held-out instance; null = all m
    c: float = 1.96
    failure_rule: str = "magnitude"
    # hide from held-out row i the constraints extracted from row i's own raw solution
    exclude_own_constraints: bool = True


@dataclass
class ReportConfig:
    stores: list[str] = field(default_factory=list)  # empty: this run's store
    dir: str | None = None  # default: the run's Hydra output folder
    renders: int = 3  # instances rendered with BOX's first feasible plan, per store
    fractions: list[float] = field(default_factory=lambda: [0.1, 0.25, 0.5, 1.0])
    repeats: int = 5  # random held-out sets per learning-curve point
    c_grid: list[float] = field(default_factory=lambda: [0.0, 0.5, 1.0, 1.96, 3.0, 5.0])
    c_folds: int = 5  # outer folds of the nested cross-validation of C
    formats: list[str] = field(default_factory=lambda: ["png", "svg"])


@dataclass
class SolveConfig:
    n: int = 20  # fresh instances (seeds never used in the store)
    selectors: list[str] = field(
        default_factory=lambda: ["box", "contextual", "contextual_capped", "eips", "static"])
    max_evaluations: int | None = 50  # planning calls per instance and selector; null = m
    max_seconds: float | None = None  # wall-clock budget per instance and selector
    use_incomplete: bool = False  # fit on the completed rows of an unfinished store
    dir: str | None = None  # default: the run's Hydra output folder


@dataclass
class Config:
    stage: Stage = Stage.generate
    seed: int = 0
    domain: Any = MISSING
    planner: Any = MISSING  # the chosen planner's settings (pipeline/planning/settings.py)
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    instances: InstancesConfig = field(default_factory=InstancesConfig)
    constraints: ConstraintsConfig = field(default_factory=ConstraintsConfig)
    store: StoreConfig = field(default_factory=StoreConfig)
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)
    report: ReportConfig = field(default_factory=ReportConfig)
    solve: SolveConfig = field(default_factory=SolveConfig)
    progress: bool = True  # entries done: a bar on a terminal, else lines (off for tests)
    progress_every: float = 60.0  # seconds between progress lines off a terminal and in the log


def register_configs() -> None:
    """Put the schemas in Hydra's ConfigStore (the YAML files name them in ``defaults``)."""
    from hydra.core.config_store import ConfigStore

    cs = ConfigStore.instance()
    cs.store(name="config_schema", node=Config)
    for name, schema in SETTINGS.items():
        cs.store(group="planner", name=f"{name}_schema", node=schema)
    for name, schema in plugin_planner_schemas().items():
        cs.store(group="planner", name=name, node=schema)  # the option itself (no YAML)
    cs.store(group="cluster", name="cluster_schema", node=ClusterConfig)
    for name in domain_names():
        if problem("domain", name):  # a broken plug-in: refused where it is asked for
            continue
        schema = domain_schema(name)
        cs.store(group="domain", name=f"{name}_schema", node=schema)
        if not has_yaml(name):  # e.g. a plug-in's domain: its schema's defaults are the option
            cs.store(group="domain", name=name, node=OmegaConf.merge(
                OmegaConf.structured(schema), {"name": name}))
    cs.store(group="hydra/help", name="pipeline_help", node=help_config(), provider="pipeline")


def plugin_planner_schemas() -> dict[str, type]:
    """name -> settings class of each installed plug-in planner (entry-point group
    ``box_planning.planners``; importing each one's module), whose name no built-in takes."""
    from pipeline.planning.registry import settings_class
    from pipeline.plugins import plugin_targets

    return {name: settings_class(name) for name in plugin_targets("planner")
            if name not in SETTINGS and not problem("planner", name)}


#: The command's name in its help (the console script; ``python -m pipeline`` is the same).
APP_NAME = "box-pipeline"


def choices(group: str) -> list[str]:
    """The options of a config group: its YAML files in ``conf/`` (schemas are not
    options), and for ``domain`` the installed plug-ins' domains."""
    found = {p.stem for p in (CONF_DIR / group).glob("*.yaml")}
    return sorted(found | set(domain_names()) if group == "domain" else found)


def help_choices(group: str) -> list[str]:
    """:func:`choices`, and for ``planner`` the installed plug-ins' names too."""
    extra = sorted(plugin_planner_schemas()) if group == "planner" else []
    return choices(group) + extra


def help_config() -> dict:
    """``--help``: the command's own name and the real choices of each group (Hydra's
    default lists the schemas too)."""
    groups = "\n".join(f"  {g}: {', '.join(help_choices(g))}" for g in ("domain", "planner",
                                                                      "cluster"))
    return {
        "app_name": APP_NAME,
        "header": f"{APP_NAME} (python -m pipeline): score matrices of planning problems, "
                  "the leave-one-out comparison of constraint selectors (BOX), reports and "
                  "live solving.\nUsage: " + APP_NAME + " stage=NAME key=value ... "
                  "(stages: " + ", ".join(s.value for s in Stage) + "; -m for sweeps)",
        "footer": "README.md and docs/pipeline.md say what each key does, docs/config.md "
                  "lists every default; --cfg job prints the composed "
                  "config, --hydra-help Hydra's own flags.",
        "template": "${hydra.help.header}\n\n== Configuration groups (group=option) ==\n"
                    + groups + "\n\n== Config ==\nOverride anything below "
                    "(key=value):\n\n$CONFIG\n${hydra.help.footer}\n",
    }


#: The keys that determine a store's contents (a store refuses to continue under others).
IDENTITY_KEYS = ("domain", "planner", "seed", "instances", "constraints",
                 "store.block_instances", "store.block_constraints")


def identity(cfg) -> dict:
    """The part of a resolved config that determines the score matrix, as plain data."""
    plain = OmegaConf.to_container(OmegaConf.create(cfg) if not OmegaConf.is_config(cfg) else cfg,
                                   resolve=True, enum_to_str=True)
    out = {}
    for key in IDENTITY_KEYS:
        node = plain
        for part in key.split("."):
            node = node[part]
        out[key] = node
    for key, old in LATER_KEYS.items():
        _drop_if(out, key, old)
    return comparable(out)


def comparable(ident: dict) -> dict:
    """``ident`` (an identity, as :func:`identity` makes it or as a store holds it) with
    its planner's settings only: the keys that planner's settings class declares, minus
    ``collision`` (which changes the cost of D, never its contents: the robot model's
    certified checks give the same answers).

    Stores made before planners had a settings class each hold every planner's keys (an
    rrt_connect store has ``planner.trajopt_*``); those keys never changed what that
    planner computed, so dropping them here lets such a store match the identity of
    today's config without rewriting it, and a key added to another planner later changes
    no store of this one.  A planner that is not installed keeps all its keys."""
    planner = ident.get("planner")
    if not isinstance(planner, dict):
        return ident
    try:
        from pipeline.planning.registry import settings_class

        declared = set(keys_of(settings_class(planner.get("name"))))
    except (ValueError, ImportError):
        declared = set(planner)
    kept = {k: v for k, v in planner.items() if k in declared and k != "collision"}
    return {**ident, "planner": kept}


def matching_identity(stored: dict | None, wanted: dict) -> dict:
    """The identity a run uses for a store: ``stored`` when it is ``wanted`` once both are
    :func:`comparable` (a store made before per-planner settings: it is kept as it is, so
    the store is neither rewritten nor refused), else ``wanted``."""
    if stored and stored != wanted and not differing_keys(stored, wanted):
        return stored
    return wanted


#: Keys that change D, added to the schemas after stores had been made, each with the value
#: that reproduces what every store made before it computed.  ``identity`` leaves such a
#: key out while it has that value, so a store made before the key existed (whose identity
#: never had it) still matches and resumes; any other value is recorded, and a store made
#: with it refuses to continue under the old value (and the reverse).  A key's default may
#: later move away from that value (``domain.contacts``: ``fresh`` since 2026-11-27): a run
#: that does not set the key itself continues such a store under the old value
#: (:func:`earlier_values`), and a recorded config that lacks the key is read with it
#: (:func:`with_earlier_values`).
LATER_KEYS = {
    "domain.ik": "damped",  # pybullet's damped IK (pipeline.domains.ik.solve_ik)
    "domain.contacts": "cached",  # pybullet's cached contact points (docs/contacts.md)
}


def earlier_values(stored: dict | None, wanted: dict, explicit=frozenset()) -> dict[str, Any]:
    """The LATER_KEYS a run takes from an existing store rather than from its defaults:
    those the store's identity ``stored`` lacks (so it was made under their old value) while
    this run's identity ``wanted`` holds another value, unless the run set the key itself
    (``explicit``: dotted keys, as on the command line; then the store is refused as made
    with a different config).  {dotted key: old value}."""
    if not stored:
        return {}
    have, want = flatten(comparable(stored)), flatten(comparable(wanted))
    return {key: old for key, old in LATER_KEYS.items()
            if key in want and key not in have and key not in explicit}


def with_earlier_values(config: dict) -> dict:
    """A recorded run config (a store's ``config`` attribute, a replay file's entry) with
    every LATER_KEY of the domain that it lacks set to the key's old value: it was recorded
    before the key existed, when every run computed that value.  Keys the domain's schema
    does not declare (``planar`` has no ``contacts``) stay absent."""
    domain = dict(config.get("domain") or {})
    try:
        declared = {f.name for f in fields(domain_schema(domain.get("name")))}
    except (ValueError, ImportError, TypeError):
        return config  # an unknown domain (load_domain names it), or a schema of no fields
    for key, old in LATER_KEYS.items():
        top, _, name = key.partition(".")
        if top == "domain" and name in declared and name not in domain:
            domain[name] = old
    return {**config, "domain": domain}


def _drop_if(ident: dict, key: str, value) -> None:
    """Remove ``key`` (dotted: a group of IDENTITY_KEYS, then the path inside it) from
    ``ident`` when it holds ``value``."""
    top = next((t for t in IDENTITY_KEYS if key.startswith(t + ".")), None)
    if top is None:
        raise ValueError(f"LATER_KEYS: {key} is not inside any of IDENTITY_KEYS")
    *parents, last = key[len(top) + 1:].split(".")
    node = ident[top]
    for part in parents:
        node = node.get(part) if isinstance(node, dict) else None
    if isinstance(node, dict) and last in node and node[last] == value:
        del node[last]


def config_hash(ident: dict) -> str:
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:16]


def flatten(tree, prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}} -> {"a.b": 1}: how differing keys are named in errors."""
    if isinstance(tree, dict):
        out = {}
        for k, v in tree.items():
            out.update(flatten(v, f"{prefix}{k}."))
        return out
    return {prefix[:-1]: tree}


def differing_keys(stored: dict, wanted: dict) -> list[str]:
    """The keys in which two identities differ, once both are :func:`comparable`."""
    a, b = flatten(comparable(stored)), flatten(comparable(wanted))
    return sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
