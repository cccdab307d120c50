"""Cluster settings checked before any work; where a started scheduler listens; how many
workers a local cluster gets inside an allocation."""

from __future__ import annotations

import io

import psutil
import pytest
from rich.console import Console

from pipeline.cluster import ClusterError, available_cores, connect, worker_side
from pipeline.cluster.checks import check_config
from pipeline.configs import ClusterConfig, ClusterKind, SlurmConfig


@pytest.mark.parametrize(("changes", "key"), [
    ({"n_workers": 0}, "cluster.n_workers"),
    ({"worker_timeout": 0}, "cluster.worker_timeout"),
    ({"connect_timeout": -1}, "cluster.connect_timeout"),
    ({"dashboard_address": "8787"}, "cluster.dashboard_address"),
    ({"kind": ClusterKind.address}, "cluster.address"),
    ({"kind": ClusterKind.slurm, "slurm": SlurmConfig(cores=0)}, "cluster.slurm.cores"),
    ({"kind": ClusterKind.slurm, "slurm": SlurmConfig(memory_per_worker="lots")},
     "cluster.slurm.memory_per_worker"),
    ({"kind": ClusterKind.slurm, "slurm": SlurmConfig(max_replacements=-1)},
     "cluster.slurm.max_replacements"),
])
def test_bad_keys_are_named(changes, key):
    with pytest.raises(ClusterError, match=key.replace(".", r"\.")) as info:
        check_config(ClusterConfig(**changes))
    assert "\n" not in str(info.value)


def _listening(process: psutil.Process) -> set[str]:
    return {c.laddr.ip for c in process.net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN}


def test_local_cluster_listens_on_loopback_only_says_where_and_is_tuned():
    out = io.StringIO()
    console = Console(file=out, width=200)
    with connect(ClusterConfig(n_workers=1), console) as client:
        me = psutil.Process()
        hosts = _listening(me)
        for child in me.children(recursive=True):
            hosts |= _listening(child)
        address = client.scheduler.address
        port = client.scheduler_info()["services"]["dashboard"]
        ports = {c.laddr.port for c in me.net_connections(kind="inet")
                 if c.status == psutil.CONN_LISTEN}
        settings = client.run(worker_side.probe)
    assert hosts == {"127.0.0.1"}
    assert [(s["env"], s["config"]) for s in settings.values()] == [
        ({}, worker_side.TUNED_CONFIG)]
    assert port in ports
    assert f"dask: 1 worker at {address}; dashboard http://127.0.0.1:{port}/status" \
        in out.getvalue()


def test_local_workers_follow_the_allocation(monkeypatch):
    monkeypatch.delenv("SLURM_CPUS_PER_TASK", raising=False)
    monkeypatch.delenv("SLURM_CPUS_ON_NODE", raising=False)
    unconstrained = available_cores()
    monkeypatch.setenv("SLURM_CPUS_ON_NODE", "1")
    assert available_cores() == 1
    monkeypatch.setenv("SLURM_CPUS_PER_TASK", "1")
    monkeypatch.setenv("SLURM_CPUS_ON_NODE", "64")
    assert available_cores() == 1
    monkeypatch.delenv("SLURM_CPUS_PER_TASK")
    assert available_cores() == unconstrained  # never more than the affinity mask allows


def test_the_dashboard_link_printed_opens_dask_s_dashboard():
    """The banner's link serves Dask's status page, not "Dask needs bokeh" (bokeh is a
    dependency of this package, installed by the README's commands)."""
    import re
    import urllib.request

    out = io.StringIO()
    with connect(ClusterConfig(n_workers=1), Console(file=out, width=200)):
        link = re.search(r"dashboard (http://\S+/status)", out.getvalue()).group(1)
        with urllib.request.urlopen(link, timeout=30) as page:  # noqa: S310 (loopback)
            status, html = page.status, page.read().decode()
    assert status == 200
    assert "bokeh" in html.lower() and "needs bokeh" not in html.lower()


def test_no_dashboard_means_none_and_no_port_8787(recwarn):
    """``dashboard_address=null``: no dashboard, and the HTTP server every Dask scheduler
    starts listens on a free loopback port, so a port 8787 that something else holds
    gives no warning (Dask's default would try 8787 and warn, which a run prints on
    stderr)."""
    import socket

    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", 8787))
        holder.listen()
    except OSError:
        holder.close()
        holder = None  # held already, by something else: the same situation
    try:
        out = io.StringIO()
        with connect(ClusterConfig(n_workers=1, dashboard_address=None),
                     Console(file=out, width=200)) as client:
            port = client.scheduler_info()["services"]["dashboard"]  # the HTTP server's
            status = _status_code(f"http://127.0.0.1:{port}/status")
            me = psutil.Process()
            hosts = _listening(me)
            for child in me.children(recursive=True):
                hosts |= _listening(child)
    finally:
        if holder is not None:
            holder.close()
    assert status == 404 and port != 8787  # no dashboard page there
    assert "dashboard" not in out.getvalue()
    assert hosts == {"127.0.0.1"}
    assert not [w for w in recwarn if "8787" in str(w.message)]  # Dask's port warning


def _status_code(url: str) -> int:
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(url, timeout=30) as page:  # noqa: S310 (loopback)
            return page.status
    except urllib.error.HTTPError as exc:
        return exc.code
