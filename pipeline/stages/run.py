"""The :class:`Run` of one invocation: the resolved config, the store (read-only first,
locked and opened for writing only when a stage has work), a Dask client when needed, and
what every stage shares: its ``todo`` check, its inputs' digests, the blocks to compute and
their writing as they finish."""

from __future__ import annotations

import contextlib
import logging
import uuid
from collections import Counter

import numpy as np
from omegaconf import OmegaConf
from rich.console import Console
from rich.text import Text

from pipeline import configs, environment, validation
from pipeline.context import StageContext
from pipeline.domains import load_domain
from pipeline.execution import Task, dask_client, run_tasks
from pipeline.planning.registry import planner_module
from pipeline.planning.settings import planner_label
from pipeline.provenance import Provenance
from pipeline.stages.todo import TODO
from pipeline.store import (
    LAYOUT_VERSION,
    LockError,
    ScoreStore,
    StoreError,
    StoreLock,
    check_is_ours,
    default_path,
    domain_spec_of,
    metadata,
)
from pipeline.store.integrity import Damage
from pipeline.store.layout import ENVIRONMENT, STAGE_INPUTS, STATUS
from pipeline.store.location import locate

log = logging.getLogger("pipeline")

#: What each stage is computed from (its digests are recorded with the stage).
INPUTS = STAGE_INPUTS


class Run:
    """One invocation: the resolved config, the store, and a Dask client when needed."""

    def __init__(self, cfg, console: Console, explicit=frozenset()):
        self.console = console
        #: the dotted keys the command line set (``pipeline.__main__.explicit_keys``)
        self.explicit = frozenset(explicit)
        self._configure(cfg)
        path = cfg.store.path or default_path(self.domain.name, planner_label(self.planner),
                                               cfg.seed)
        self.location = locate(path, self.plain["store"].get("storage_options"))
        self.path = self.location.path
        #: names this run's tasks: two runs on one scheduler never share a future
        self.token = (configs.config_hash({"store": str(self.location)})[:8] + "-"
                      + uuid.uuid4().hex[:8])
        self.store: ScoreStore | None = None
        self.writing = False
        self.wrote = False
        #: check_is_ours passed on this run's store (open_for_reading): the check before
        #: the lock is not made again (prepare() checks once more, under the lock)
        self._checked_ours = False
        self._todo: dict[str, str | None] = {}
        self._stack = contextlib.ExitStack()
        self._client = None
        #: the report's jobs started early (``stage=all``: pipeline.report.jobs), or None
        self.report_jobs = None

    def _configure(self, cfg) -> None:
        """The config and what follows from it: the domain (as this process and the
        workers build it) and the identity."""
        self.cfg = cfg
        self.plain = OmegaConf.to_container(cfg, resolve=True, enum_to_str=True)
        validation.check_values(self.plain)  # also when stages run without the entry point
        self.planner = configs.planner_settings(self.plain["planner"])
        self.domain_spec = domain_spec_of(self.plain)
        self.domain = load_domain(self.domain_spec["name"], planner=self.planner,
                                  **self.domain_spec["config"])
        self.identity = configs.identity(cfg)
        self.identity_hash = configs.config_hash(self.identity)

    def _keep_earlier_values(self, stored: dict | None) -> None:
        """Continue a store made before a key's default changed under the value it was made
        with (:func:`pipeline.configs.earlier_values`), unless the command line set the key
        or asked to overwrite the store, and say so."""
        if self.cfg.store.mode is configs.StoreMode.overwrite:
            return
        earlier = configs.earlier_values(stored, self.identity, self.explicit)
        if not earlier:
            return
        cfg = self.cfg.copy()
        for key, value in earlier.items():
            OmegaConf.update(cfg, key, value)
        self._configure(cfg)
        for key, value in earlier.items():
            self.say(f"store: made with {key}={value} (its identity does not record that "
                     f"value); continuing with it, while {key}=... on the command line "
                     "would refuse the store")

    # -- resources -------------------------------------------------------------------------
    def open_for_reading(self) -> ScoreStore | None:
        """A read-only view of the existing store made with this config, or None when
        there is none yet (a foreign path or a different config is refused here unless
        ``store.mode=overwrite``, which needs writing)."""
        holder = StoreLock(self.location).held_by_other() if self.location.exists() else None
        if holder:
            raise LockError(f"store {self.location} is in use by a running pipeline ({holder}); "
                            "wait for it or stop it first")
        if self.location.is_empty():
            return None
        store = ScoreStore.checked(self.location)
        self._checked_ours = True
        self._keep_earlier_values(store.attrs.get("identity"))
        self._adopt(store.attrs.get("identity"))
        if store.attrs.get("identity") != self.identity:
            return None  # prepare() refuses it, or replaces it with store.mode=overwrite
        self.store = store
        return store

    def open_for_writing(self) -> ScoreStore:
        """Lock the store and open it for writing (created, replaced or migrated here)."""
        if self.writing:
            return self.store
        if self.location.local is not None:
            local = self.location.local
            if not self._checked_ours and local.exists() and (
                    not local.is_dir() or any(local.iterdir())):
                check_is_ours(self.location)  # refuse before touching anything near it
            local.parent.mkdir(parents=True, exist_ok=True)
        lock = self._stack.enter_context(StoreLock(self.location))
        self.store = ScoreStore.prepare(
            self.location, self.identity, self.recorded_config(),
            overwrite=self.cfg.store.mode is configs.StoreMode.overwrite)
        self._adopt(self.store.attrs.get("identity"))
        self.store.fence = lock.check
        if lock.took_over:
            self.say(f"[yellow]store: took over the lease of a run presumed dead "
                     f"({lock.took_over})")
        note = metadata.repair_layout_version(self.store)
        if note:
            self.say(f"[yellow]store: {note}")
        if self.store.layout_version < LAYOUT_VERSION:
            from pipeline.store.migrate import migrate

            for note in migrate(self.store, self.domain):
                self.say(f"store: migrated to {note}")
            self._todo.clear()  # judged on the store before it was migrated
        found = metadata.check(self.store, self.domain)
        if found:
            for note in metadata.repair(self.store, self.domain, found):
                self.say(f"[yellow]store: {note}")
            self.wrote = True
        self.writing = True
        return self.store

    def _adopt(self, stored: dict | None) -> None:
        """Take a store's identity as this run's when it is this run's once both are
        comparable (a store made before per-planner settings holds other planners' keys:
        :func:`pipeline.configs.comparable`), so the store resumes as it is."""
        self.identity = configs.matching_identity(stored, self.identity)
        self.identity_hash = configs.config_hash(self.identity)

    def recorded_config(self) -> dict:
        """The resolved config as the store records it (storage options may hold secrets:
        only their keys are kept)."""
        store = dict(self.plain["store"])
        store["storage_options"] = dict.fromkeys(store.get("storage_options") or {}, "***")
        return {**self.plain, "store": store}

    @property
    def client(self):
        if self._client is None:
            self._client = self._stack.enter_context(
                dask_client(self.cfg.cluster, self.console, preload=self.worker_modules()))
        return self._client

    def worker_modules(self) -> tuple[str, ...]:
        """The modules this run's tasks import: its domain's and its planner's."""
        return (type(self.domain).__module__, planner_module(self.domain.planner.name))

    def close(self) -> None:
        self._stack.close()

    def on_close(self, release) -> None:
        """Call ``release()`` when the run closes (before what was opened earlier)."""
        self._stack.callback(release)

    def context(self) -> StageContext:
        """What the evaluate and solve stages see of this run."""
        return StageContext(store=self.store, path=self.path, config=self.plain,
                            seed=self.cfg.seed, token=self.token,
                            retries=self.cfg.cluster.retries, progress=self.cfg.progress,
                            console=self.console, client=lambda: self.client)

    def say(self, text: str) -> None:
        """One line, never wrapped, on the console and in the run's log (Hydra's
        ``outputs/<date>/<time>/__main__.log``)."""
        self.console.print(text, highlight=False, soft_wrap=True)
        log.info(Text.from_markup(text).plain)

    def require(self, stage: str, needed_by: str) -> None:
        if self.store is None or self.store.stage_info(stage) is None:
            raise StoreError(configs.needs_first(stage, needed_by))

    # -- what changed ------------------------------------------------------------------------
    def todo(self, stage: str) -> str | None:
        """Why ``stage`` must run, or None (checked once per stage and run: the read-only
        check that decided to take the lock is not repeated)."""
        if stage not in self._todo:
            self._todo[stage] = TODO[stage](self)
        return self._todo.pop(stage) if self.writing else self._todo[stage]

    def changed_inputs(self, stage: str) -> list[str]:
        """Inputs of ``stage`` whose digests differ from those it recorded."""
        recorded = (self.store.stage_info(stage) or {}).get("inputs")
        if not recorded:
            return []  # not run, or run before inputs were recorded
        keys = [k for k in recorded if self.store.has(k)]
        current = self.store.array_digests(keys)
        return sorted(k for k in recorded if current.get(k) != recorded[k])

    def finish(self, stage: str, **info) -> None:
        """Mark ``stage`` finished, with the digests of its inputs."""
        keys = [k for k in INPUTS[stage] if self.store.has(k)]
        self.store.mark_finished(stage, inputs=self.store.array_digests(keys), **info)
        self.wrote = True

    # -- block groups ------------------------------------------------------------------------
    def block_state(self, group: str) -> tuple[list[tuple], Damage]:
        """(blocks to compute, damage found in finished ones) of a result group."""
        store = self.store
        if not store.has_table(group):
            finished, pending = store.blocks(group)  # a layout-1 store opened read-only
            damage = store.verify(group)
            return sorted(set(pending) | damage.blocks), damage
        rows = store.table_rows(group)  # read once, for both
        finished = store.finished_blocks(group, rows)
        damage = store.verify(group, finished, rows=rows)
        ok = set(finished) - damage.blocks
        return [b for b in np.ndindex(*store.grid(group)) if b not in ok], damage

    def pending_blocks(self, group: str, coords: dict) -> list[tuple[int, ...]]:
        """Blocks of ``group`` to compute; damaged finished ones are un-marked first (and
        the coordinates, derived from other groups, written again)."""
        changed = self.changed_inputs(group)
        if changed:
            self.say(f"[yellow]{group}: its inputs changed since it ran "
                     f"({', '.join(changed)}); computing every block again")
            self.store.forget_blocks(group, list(np.ndindex(*self.store.grid(group))))
            self.store.forget_stage(group)
        pending, damage = self.block_state(group)
        if damage:
            self.say(f"[yellow]{group}: {len(damage.blocks)} damaged block(s) found "
                     f"({damage.describe()}); recomputing them")
            self.store.forget_blocks(group, sorted(damage.blocks))
            self.store.forget_stage(group)
            names = [n for n in self.store.layout(group).names if n not in coords]
            self.store.write_coords(group, coords, names)
        return sorted(pending)

    def worker_environments(self) -> list[dict]:
        """The distinct environments of the workers connected now (this process's when
        they cannot be asked)."""
        try:
            found = list(self.client.run(environment.fingerprint).values())
        except Exception:  # noqa: BLE001 (the watchdog reports unusable workers)
            found = []
        return [r for k, r in enumerate(found) if r not in found[:k]] or \
            [environment.fingerprint()]

    def run_blocks(self, group: str, tasks: list[Task], label: str) -> Counter:
        statuses: Counter = Counter()
        provenance = Provenance(self.store, group, self.cfg.store.environment, self.say)
        if tasks:
            provenance.before(self.worker_environments())

        def finished(task: Task, result: tuple[dict, dict]) -> None:
            arrays, report = result
            where = provenance.index(report["environment"])
            arrays[ENVIRONMENT] = np.full(np.shape(arrays[STATUS]), where, dtype="int16")
            self.store.write_block(group, task.block, arrays)
            statuses.update(report["status"])
            for message in report["errors"]:
                self.say(f"[yellow]{label}: planning error in block: {message}")

        if tasks:
            self.wrote = True
            run_tasks(self.client, tasks, finished, retries=self.cfg.cluster.retries,
                      label=label, console=self.console, progress=self.cfg.progress,
                      every_s=self.cfg.progress_every)
        return statuses



def instance_inputs(run: Run) -> tuple[list[str], np.ndarray]:
    """The instances' specs (JSON text) and seeds, as the workers receive them."""
    specs = [str(s) for s in run.store.instance_specs()]
    seeds = run.store.instance_seeds()
    return specs, seeds
