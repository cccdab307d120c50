"""Settings of the dashboard a scheduler this run starts (local or SLURM) serves."""

from __future__ import annotations


def no_dashboard(cfg) -> dict:
    """The scheduler's settings for ``dashboard_address=null``: no dashboard, and Dask's
    plain HTTP server (health checks, metrics), which every scheduler starts, on a free
    port of ``cfg.host``.  Without the port, Dask would try 8787 and warn on stderr when
    another scheduler holds it."""
    if cfg.dashboard_address is not None:
        return {}
    return {"dashboard": False, "dashboard_address": f"{cfg.host}:0"}
