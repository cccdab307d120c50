"""The per-process cache of domains: one domain object (and with it its simulator client)
per configuration, reused by every task a worker process runs.  Explicit: ``close()``
disconnects the clients, and a domain pushed out of the cache is closed at once."""

from __future__ import annotations

import json
from collections import OrderedDict

from pipeline.domains import Domain, load_domain


class DomainCache:
    """At most ``size`` domains, least recently used first out."""

    def __init__(self, size: int = 4):
        self.size = size
        self._domains: OrderedDict[str, Domain] = OrderedDict()

    def get(self, spec: dict) -> Domain:
        """The domain of ``spec`` ({"name", "config", "planner"} as plain data)."""
        key = json.dumps([spec["name"], spec["config"], spec["planner"]], sort_keys=True)
        if key in self._domains:
            self._domains.move_to_end(key)
            return self._domains[key]
        domain = load_domain(spec["name"], planner=spec["planner"], **spec["config"])
        self._domains[key] = domain
        while len(self._domains) > self.size:
            self._domains.popitem(last=False)[1].close()
        return domain

    def close(self) -> None:
        """Close every cached domain and forget it."""
        while self._domains:
            self._domains.popitem(last=False)[1].close()

    def __len__(self) -> int:
        return len(self._domains)


#: the process's cache (a worker process's tasks share it)
CACHE = DomainCache()


def domain_for(spec: dict) -> Domain:
    """``spec``: {"name", "config", "planner"} as plain data (what tasks receive)."""
    return CACHE.get(spec)


def close_domains() -> None:
    """Disconnect the simulator clients of every cached domain of this process."""
    CACHE.close()
