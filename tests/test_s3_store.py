"""A store in object storage: a real S3-compatible server process (moto's standalone
``moto_server``) on 127.0.0.1, configured the way AWS users expect (environment variables)."""

import json
import os
import signal
import time

import numpy as np
import pytest
from typer.testing import CliRunner

from tests import pipeline_runs as pr
from tests.s3_server import BUCKET, read_object, requests_sent, serve
from tests.s3_server import done as _done
from tests.s3_server import matrix as _matrix


@pytest.fixture(scope="module")
def s3():
    """The server's environment (AWS_ENDPOINT_URL, credentials) with a fresh bucket."""
    with serve() as env:
        yield env


def test_full_run_status_and_export_on_s3(s3, made, tmp_path):
    url = f"s3://{BUCKET}/runs/full.zarr"
    res = pr.run(url, "stage=generate", cwd=tmp_path)
    assert res.returncode == 0, res.stderr + res.stdout
    assert pr.same_matrix(pr.matrix(made[0]), _matrix(url))  # bitwise the local store's D
    assert {p.name for p in tmp_path.iterdir()} <= {"outputs"}  # Hydra's; no "s3:" folder

    from pipeline.cli import app

    runner = CliRunner()
    with requests_sent() as sent:
        status = runner.invoke(app, ["status", url, "--json"])
    assert status.exit_code == 0, status.output
    doc = json.loads(status.output)
    assert doc["stages"]["scores"]["done"] == 24 * 15 and not doc["damaged"]
    assert doc["environments"][0]["entries"] == {"raw": 24, "scores": 24 * 15}
    # status reads every object it needs once and lists each group's and array's objects
    # once (it read each done mask three times and listed every array twice before); the
    # store's own folder is listed twice: once to see that something is there, once for
    # the groups in it
    for op in ("get_object", "list_objects_v2"):
        keys = [key for kind, key in sent if kind == op and key != "runs/full.zarr/"]
        twice = sorted({key for key in keys if keys.count(key) > 1})
        assert not twice, (op, [(k, keys.count(k)) for k in twice])
    written = {a["array"]: a["chunks_written"] for a in doc["arrays"]}
    assert written["scores/feasible"] == written["scores/done"] == 4 * 3, written
    out = tmp_path / "d.npz"
    exported = runner.invoke(app, ["export", url, "-o", str(out)])
    assert exported.exit_code == 0, exported.output
    with np.load(out) as data:
        np.testing.assert_array_equal(data["feasible"], pr.matrix(made[0])["feasible"])
    assert "scores: already complete" in _nothing_to_do_reads_each_object_once(url, tmp_path)


def _nothing_to_do_reads_each_object_once(url: str, tmp_path) -> str:
    """Run ``stage=generate`` on the finished store ``url`` in this process (nothing to
    plan, so no workers): every chunk of a result it verifies is read once (the ``done``
    masks that say which blocks are finished are not read again to be checked), and no
    Zarr v2 document is asked for (the stores are Zarr v3).  Not yet checked here: the
    integrity tables (a small chunk per block), which each stage reads again for the
    digests of its inputs.  Its output."""
    import io

    from rich.console import Console

    from pipeline.stages import run_pipeline

    out = io.StringIO()
    with requests_sent() as sent:
        run_pipeline(_small_config(url, "generate"), Console(file=out))
    chunks = [key for op, key in sent if op == "get_object" and "/c/" in key
              and "/integrity/" not in key]
    assert len(chunks) > 100, sent  # every finished block of every group is verified
    twice = sorted({key for key in chunks if chunks.count(key) > 1})
    assert not twice, [(k, chunks.count(k)) for k in twice]
    assert not [key for _, key in sent
                if key.rsplit("/", 1)[-1] in (".zgroup", ".zattrs", ".zarray", ".zmetadata")]
    return out.getvalue()


def _small_config(url: str, stage: str):
    """The tests' small planar run (``pr.SMALL``) on the store ``url``, composed as
    ``python -m pipeline`` composes it, to run in this process."""
    from hydra import compose, initialize_config_dir

    from pipeline.configs import CONF_DIR, register_configs

    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=[*pr.SMALL, f"store.path={url}",
                                                        f"stage={stage}"])


def test_kill_9_on_s3_then_resume_is_bitwise_identical(s3, made, tmp_path):
    url = f"s3://{BUCKET}/runs/killed.zarr"
    proc = pr.start(url, "stage=generate", cwd=tmp_path)
    while _done(url) == 0:
        assert proc.poll() is None, proc.stdout.read()
        time.sleep(0.1)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)
    done = _done(url)
    assert 0 < done < 24 * 15, "the kill came too late to test resuming"
    res = pr.run(url, "stage=generate", cwd=tmp_path)  # the dead run's lease is taken over
    assert res.returncode == 0, res.stderr + res.stdout
    assert f"{done} of {24 * 15} entries already done" in res.stdout
    assert pr.same_matrix(pr.matrix(made[0]), _matrix(url))


def test_a_live_lease_refuses_a_second_run(s3, tmp_path):
    from pipeline.store import StoreLock

    url = f"s3://{BUCKET}/runs/leased.zarr"
    with StoreLock(url):
        res = pr.run(url, "stage=instances", cwd=tmp_path)
    assert res.returncode == 2 and "in use by a running pipeline" in res.stderr
    assert "heartbeat" in res.stderr
    res = pr.run(url, "stage=instances", cwd=tmp_path)  # released: free again
    assert res.returncode == 0, res.stderr


def test_unknown_schemes_are_refused_in_one_line(tmp_path):
    res = pr.run("nosuch://b/x.zarr", "stage=instances", cwd=tmp_path)
    assert res.returncode == 2
    assert "unknown scheme 'nosuch'" in res.stderr and "Traceback" not in res.stderr
    assert {p.name for p in tmp_path.iterdir()} <= {"outputs"}


def test_lost_input_tables_in_s3_are_rebuilt_without_recomputing_results(s3, made, tmp_path):
    """Issue 24 case 2 in object storage: the integrity tables of instances and constraints
    deleted; the re-run rebuilds them from the inputs computed again, keeps raw and scores."""
    import s3fs

    fs = s3fs.S3FileSystem(endpoint_url=s3["AWS_ENDPOINT_URL"])
    key = f"{BUCKET}/runs/tables.zarr"
    fs.put(str(made[0]), key, recursive=True)
    fs.rm([f"{key}/integrity/instances", f"{key}/integrity/constraints"], recursive=True)
    url = f"s3://{key}"

    from pipeline.cli import app

    status = CliRunner().invoke(app, ["status", url, "--json"])
    assert status.exit_code == 1 and "integrity/constraints" in status.output
    res = pr.run(url, "stage=generate", cwd=tmp_path)
    assert res.returncode == 0, res.stderr + res.stdout
    assert "integrity table is missing" in res.stdout and "inputs changed" not in res.stdout
    assert "scores: already complete" in res.stdout
    assert CliRunner().invoke(app, ["status", url]).exit_code == 0
    assert pr.same_matrix(pr.matrix(made[0]), _matrix(url))



def test_each_read_is_one_request_and_no_new_array_is_probed(s3, tmp_path, monkeypatch):
    """No HEAD before a GET (s3fs's size probe: it doubled every read), no existence check
    of a parent group's document the run already read, no removal of a new array's folder
    where a listing finds nothing (s3fs probes it), an array's attributes in its first
    document (a data array's ``coordinates`` listing in a second, once they exist); ``box
    status`` writes nothing and reads each object without probing it first."""
    from rich.console import Console

    from pipeline.cli import app
    from pipeline.stages import run_pipeline

    url = f"s3://{BUCKET}/runs/requests.zarr"
    root_doc = "runs/requests.zarr/zarr.json"  # asked for once, before the run first reads it
    cfg = _small_config(url, "instances")
    monkeypatch.chdir(tmp_path)
    with requests_sent() as sent:
        run_pipeline(cfg, Console(file=open(os.devnull, "w")))  # noqa: SIM115
    probed = {key for op, key in sent if op == "head_object"}
    assert not {key for op, key in sent if op == "get_object"} & probed - {root_doc}, sent
    assert probed <= {root_doc, "runs/requests.zarr"}, sent  # no array's folder probed
    written = [key for op, key in sent if op == "put_object" and key.endswith("/zarr.json")]
    docs = {key: json.loads(read_object(key)) for key in written}
    arrays = {key: doc for key, doc in docs.items() if doc["node_type"] == "array"}
    assert len(arrays) >= 3, written  # the instances' arrays and their integrity table
    for key, doc in arrays.items():  # a data array's coordinates are named once they exist
        assert written.count(key) == 1 + ("coordinates" in doc["attributes"]), (key, written)

    with requests_sent() as sent:
        status = CliRunner().invoke(app, ["status", url, "--json"])
    assert status.exit_code == 0, status.output
    read = {key for op, key in sent if op == "get_object"}
    assert len(read) > 20 and not read & {key for op, key in sent if op == "head_object"}, sent
    assert {op for op, _ in sent} <= {"get_object", "list_objects_v2", "head_object"}, sent
