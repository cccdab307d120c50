"""Which environment computed each block of a result group, and the ``store.environment``
policy (docs/reproducibility.md).

Blocks computed in different environments (another CPU, other library versions, edited
source) agree within the reproducibility tolerance, not bitwise.  A run says so in one line
before it computes when the workers' environment differs from the one that computed the
store's finished blocks, and again if a block arrives from yet another one (a SLURM job on
another kind of node); with ``store.environment=refuse`` it stops instead, before writing
anything from the other environment.
"""

from __future__ import annotations

from collections.abc import Callable

from pipeline.configs import EnvironmentPolicy
from pipeline.environment import RTOL, difference
from pipeline.store import UNKNOWN_ENVIRONMENT, ScoreStore
from pipeline.store.errors import StoreError

WHY = f"floats agree within {RTOL:g} relative, not bitwise (docs/reproducibility.md)"


class Provenance:
    """The environments of ``group``'s blocks during one run."""

    def __init__(self, store: ScoreStore, group: str, policy: EnvironmentPolicy,
                 say: Callable[[str], None]):
        self.store, self.group, self.policy, self.say = store, group, policy, say
        used = store.environments_used(group)
        self.unknown = used.pop(UNKNOWN_ENVIRONMENT, 0)
        table = store.environments()
        #: environments of this group's blocks (finished ones, then this run's)
        self.records = [table[i] for i in sorted(used) if 0 <= i < len(table)]
        self.entries = sum(used.values())
        self.announced: list[dict] = []

    def before(self, workers: list[dict]) -> None:
        """Say (or refuse) before computing when ``workers`` (the environments of the
        workers at hand) differ from those of the finished blocks."""
        new = [w for w in workers if w not in self.records]
        if self.records and new:
            self._differs(new[0], f"resuming in another environment than the one that "
                                  f"computed its {self.entries} finished entries")
            self.announced += new  # said once for all the workers at hand
        elif self.unknown:
            self.say(f"[yellow]{self.group}: {self.unknown} finished entries were computed "
                     "before environments were recorded (layout < 3); new blocks may differ "
                     f"from them in the last bits: {WHY}")

    def index(self, record: dict) -> int:
        """The environment index to store with a block computed in ``record``."""
        if record not in self.records:
            if self.records and record not in self.announced:
                self._differs(record, "a block was computed in another environment than "
                                      "this store's other blocks")
                self.announced.append(record)
            self.records.append(record)
        return self.store.environment_index(record)

    def _differs(self, record: dict, what: str) -> None:
        change = difference(self.records[0], record) or "unknown"
        if self.policy is EnvironmentPolicy.refuse:
            raise StoreError(f"{self.group}: {what} ({change}); store.environment=refuse keeps "
                             "a store to one environment: run it where it was made, or with "
                             "store.environment=allow")
        self.say(f"[yellow]{self.group}: {what} ({change}); {WHY}")
