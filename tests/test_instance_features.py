"""Instance features: the geometry they are computed from, their place in the store
(``instances/features``, written by stage ``instances``), and stores of layouts 3 and 4
gaining them on migration with D untouched, also after an interrupted migration.  (Each
domain's features keep the contract in tests/test_domain_contract.py.)"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import zarr

from pipeline.domains import features as F
from pipeline.domains import load_domain
from pipeline.domains.geometry import Box
from pipeline.domains.grasp_arm import SURFACES, surface_of
from pipeline.store import LAYOUT_VERSION, ScoreStore
from pipeline.store.migrate import _add_instance_features
from tests import pipeline_runs as pr

DATA = Path(__file__).parent / "data"
LAYOUT_3 = DATA / "layout3_planar.tar.gz"
#: the command that made LAYOUT_4 with the code of layout 4 (main at d0e1ff7), in /tmp/l4:
#: python -m pipeline stage=all domain=planar instances.n=12 constraints.m=8
#:   store.block_instances=4 store.block_constraints=4 cluster.n_workers=1
#:   planner.max_checks=4000 evaluate.k=4 progress=false store.path=/tmp/l4/layout4.zarr
#:   report.dir=/tmp/l4/report report.c_folds=2
LAYOUT_4 = DATA / "layout4_planar.tar.gz"
#: the settings both were made with (LAYOUT_3's command: tests/test_dataset.py)
OLD_RUN = ("domain=planar", "instances.n=12", "constraints.m=8", "store.block_instances=4",
           "store.block_constraints=4", "cluster.n_workers=1", "planner.max_checks=4000",
           "progress=false")
#: the groups of D and of its inputs, whose arrays a migration leaves as they are
UNTOUCHED = ("raw", "constraints", "scores")


# -- geometry ----------------------------------------------------------------------------------
def test_gaps_between_boxes_are_exact():
    unit = Box((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), 0.0)
    others = [Box((1.0, 1.0, 1.0), (2.0, 0.0, 0.0), 0.0),  # beside it: 1 m
              Box((1.0, 1.0, 1.0), (0.5, 0.5, 0.0), 0.3),  # overlapping: 0
              Box((1.0, 1.0, 1.0), (2.0, 2.0, 0.0), 0.0),  # corner to corner: √2
              Box((1.0, 1.0, 1.0), (0.0, 0.0, 3.0), 0.0),  # above it: 2 m
              Box((1.0, 1.0, 1.0), (2.0, 0.0, 2.0), np.pi / 4)]  # a corner ahead, 1 m up
    corner = 2.0 - np.sqrt(0.5) - 0.5
    np.testing.assert_allclose(F.gaps(unit, others),
                               [1.0, 0.0, np.sqrt(2.0), 2.0, np.hypot(corner, 1.0)], atol=1e-12)
    assert F.nearby(unit, others) == [0.0, 1.0, 1.0]
    assert F.nearby(unit, []) == [F.GAP_CAP, 0.0, 0.0]
    shelf = Box((1.0, 1.0, 0.1), (0.0, 0.0, 1.05), 0.0)
    assert F.headroom(unit, [shelf]) == pytest.approx(0.5)
    assert F.headroom(unit, [Box((1.0, 1.0, 0.1), (3.0, 0.0, 1.05), 0.0)]) == F.GAP_CAP


def test_grasp_arm_features_say_where_the_target_stands():
    d = load_domain("grasp_arm")
    names = [f.name for f in d.omega_features]
    surfaces = list(SURFACES)
    for seed in range(40):
        spec = d.sample_instance(seed)
        x = dict(zip(names, d.instance_features(spec), strict=True))
        target = d.check_instance(spec).target
        assert surfaces[surface_of(target)] == spec["target"]["surface"]
        assert x[f"on_{spec['target']['surface']}"] == 1.0
        assert sum(x[f"on_{s}"] for s in surfaces) == 1.0
        assert x["obstacles"] == len(spec["obstacles"])
        assert x["obstacles_within_10cm"] <= x["obstacles_within_20cm"] <= x["obstacles"]
        assert (x["nearest_gap"] <= 0.10) == (x["obstacles_within_10cm"] > 0)
        under = spec["target"]["surface"] == "under_shelf"
        assert (x["headroom"] < 0.28) == under  # only the board limits it
        assert np.sign(x["arm_side"]) == np.sign(x["target_y"])  # arm 0 stands at y > 0


# -- the store ---------------------------------------------------------------------------------
def stored_features(store: Path):
    return ScoreStore.open(store).instance_features()


def features_of_specs(store: Path) -> np.ndarray:
    """The features the store's domain computes from the specs the store holds."""
    s = ScoreStore.open(store)
    spec = s.domain_spec()
    domain = load_domain(spec["name"], planner=spec["planner"], **spec["config"])
    return np.stack([domain.instance_features(domain.check_instance(json.loads(text)))
                     for text in s.instance_specs()])


def test_a_fresh_store_holds_the_features_of_its_specs(made):
    store, _ = made
    found = stored_features(store)
    planar = load_domain("planar")
    assert found.names == tuple(f.name for f in planar.omega_features)
    assert found.units == tuple(f.units for f in planar.omega_features)
    assert found.values.tobytes() == features_of_specs(store).tobytes()
    ds = xr.open_zarr(store, group="instances")
    assert ds["features"].dims == ("instance", "instance_feature")
    assert list(ds["instance_feature"].values) == list(found.names)
    assert list(ds["instance_feature_units"].values) == list(found.units)
    tree = xr.open_datatree(store, engine="zarr")
    np.testing.assert_array_equal(
        tree["instances"]["features"].sel(instance_feature="obstacles").values,
        found.values[:, 0])


def test_a_grasp_arm_store_holds_the_features_of_its_specs(tmp_path):
    store = tmp_path / "arm.zarr"
    res = subprocess.run([sys.executable, "-m", "pipeline", "stage=instances", "domain=grasp_arm",
                          "instances.n=6", "constraints.m=4", "store.block_instances=4",
                          "progress=false", f"store.path={store}"], capture_output=True,
                         text=True, cwd=tmp_path, env=pr.env(), timeout=600)
    assert res.returncode == 0, res.stderr + res.stdout
    found = stored_features(store)
    assert found.values.shape == (6, len(load_domain("grasp_arm").omega_features))
    assert found.values.tobytes() == features_of_specs(store).tobytes()


def _unpack(archive: Path, tmp_path: Path) -> Path:
    with tarfile.open(archive) as tar:
        tar.extractall(tmp_path, filter="data")
        return tmp_path / tar.getnames()[0].split("/")[0]


def _values(store: Path, groups) -> dict[str, bytes]:
    g = zarr.open_group(store, mode="r", use_consolidated=False)
    return {f"{group}/{path}": g[f"{group}/{path}"][...].tobytes() for group in groups
            if group in g for path, node in g[group].members(max_depth=None)
            if isinstance(node, zarr.Array)}


def _run_old(store: Path, *overrides: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pipeline", *OLD_RUN, f"store.path={store}",
                           *overrides], capture_output=True, text=True, cwd=store.parent,
                          env=pr.env(), timeout=600)


@pytest.fixture(scope="module")
def fresh_old_identity(tmp_path_factory) -> np.ndarray:
    """The features stage instances stores for the identity of the old stores."""
    store = tmp_path_factory.mktemp("fresh") / "fresh.zarr"
    res = _run_old(store, "stage=instances")
    assert res.returncode == 0, res.stderr + res.stdout
    return stored_features(store).values


def _status(store: Path) -> dict:
    from typer.testing import CliRunner

    from pipeline.cli import app

    res = CliRunner().invoke(app, ["status", str(store), "--json"])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)


@pytest.mark.parametrize("archive", [LAYOUT_3, LAYOUT_4], ids=["layout3", "layout4"])
def test_an_old_store_gains_the_features_of_a_fresh_one_and_keeps_d(archive, tmp_path,
                                                                    fresh_old_identity):
    store = _unpack(archive, tmp_path)
    # (layout 3's evaluation is regrouped by the step to layout 4: test_dataset.py)
    groups = (*UNTOUCHED, "evaluation") if archive == LAYOUT_4 else UNTOUCHED
    before = _values(store, groups)
    assert stored_features(store) is None
    res = _run_old(store, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "its instance features are not stored yet" not in res.stdout  # said before locking
    assert "migrated to layout 5: instances: 4 features of 12 instances" in res.stdout
    assert "scores: already complete" in res.stdout and "dask:" not in res.stdout
    doc = _status(store)
    assert doc["layout_version"] == LAYOUT_VERSION and not doc["damaged"]
    assert stored_features(store).values.tobytes() == fresh_old_identity.tobytes()
    after = _values(store, groups)
    assert after.keys() >= before.keys()
    changed = [key for key in before if after[key] != before[key]]
    # (the step to layout 4 gives θ's ``feature`` coordinate the domain's names)
    assert changed == ([] if archive == LAYOUT_4 else ["raw/feature", "constraints/feature"])
    res = _run_old(store, "stage=generate")
    assert "migrated" not in res.stdout and "instances: already complete" in res.stdout


def test_an_interrupted_migration_completes_when_run_again(tmp_path, fresh_old_identity):
    """Interrupted at each point of the step to layout 5: with the features array made but
    not recorded (garbage in it), and with everything written but the layout version."""
    made = _unpack(LAYOUT_4, tmp_path)
    d = load_domain("planar", planner={"name": "rrt_connect", "max_checks": 4000})
    before = _values(made, ("scores",))
    for point in ("features written", "table written"):
        store = tmp_path / point.replace(" ", "_")
        shutil.copytree(made, store)
        s = ScoreStore(store)
        _add_instance_features(s, d)
        if point == "features written":  # the table as layout 4 had it: not recorded yet
            s.array("instances/features")[...] = -1.0
            shutil.rmtree(store / "integrity" / "instances")
            shutil.copytree(made / "integrity" / "instances", store / "integrity" / "instances")
        assert s.layout_version == 4
        res = _run_old(store, "stage=generate")
        assert res.returncode == 0, (point, res.stderr + res.stdout)
        assert not _status(store)["damaged"], point
        assert zarr.open_group(store, mode="r").attrs["layout_version"] == LAYOUT_VERSION
        assert stored_features(store).values.tobytes() == fresh_old_identity.tobytes(), point
        assert _values(store, ("scores",)) == before, point


def test_damaged_specs_get_their_features_when_stage_instances_repairs_them(tmp_path,
                                                                          fresh_old_identity):
    store = _unpack(LAYOUT_4, tmp_path)
    (store / "instances" / "spec" / "c" / "1").unlink()
    res = _run_old(store, "stage=generate")
    assert res.returncode == 0, res.stderr + res.stdout
    assert "features of 8 instances (1 damaged blocks left to stage instances)" in res.stdout
    assert "instances: damaged" in res.stdout and "repaired" in res.stdout
    assert not _status(store)["damaged"]
    assert stored_features(store).values.tobytes() == fresh_old_identity.tobytes()


def test_exports_carry_the_instance_features(made, tmp_path):
    from typer.testing import CliRunner

    from pipeline.cli import app

    store, _ = made
    found = stored_features(store)
    runner = CliRunner()
    for fmt, out in (("npz", tmp_path / "d.npz"), ("csv", tmp_path / "d"),
                     ("netcdf", tmp_path / "d.nc"), ("parquet", tmp_path / "d.parquet")):
        res = runner.invoke(app, ["export", str(store), "--format", fmt, "-o", str(out)])
        assert res.exit_code == 0, res.output
    with np.load(tmp_path / "d.npz") as data:
        assert data["instance_features"].tobytes() == found.values.tobytes()
        assert json.loads(str(data["metadata"]))["instance_features"] == {
            "names": list(found.names), "units": list(found.units)}
    import pandas as pd

    table = pd.read_csv(tmp_path / "d" / "instances.csv")
    np.testing.assert_array_equal(table[list(found.names)].to_numpy(), found.values)
    with xr.open_dataset(tmp_path / "d.nc", engine="h5netcdf") as ds:
        assert list(ds["instance_feature"].values) == list(found.names)
        np.testing.assert_array_equal(ds["instance_features"].values, found.values)
    from pipeline.export import read_export

    for out in ("d.nc", "d.parquet"):
        assert read_export(tmp_path / out)[0].instance_features.tobytes() == \
            found.values.tobytes(), out
    # every export box evaluate reads gives the contextual selectors the store's features
    args = ["--selectors", "contextual", "--json", "--no-overhead"]
    want = json.loads(runner.invoke(app, ["evaluate", str(store), *args]).output)
    for out in ("d.npz", "d.nc", "d.parquet"):
        res = runner.invoke(app, ["evaluate", str(tmp_path / out), *args])
        assert res.exit_code == 0, res.output
        assert json.loads(res.output)["selectors"] == want["selectors"], out


def test_a_domain_without_instance_features_stores_none(tmp_path):
    """q = 0 (the example plug-in's slalom declares none): no ``features`` array, and the
    store is of layout 5 all the same, undamaged."""
    from pipeline.plugins import plugin_targets

    if "slalom" not in plugin_targets("domain"):
        pytest.skip("the example plug-in is not installed (pip install -e "
                    "examples/box-example-plugin)")
    assert load_domain("slalom").instance_features(load_domain("slalom").sample_instance(1)) \
        .shape == (0,)
    store = tmp_path / "slalom.zarr"
    for _ in range(2):
        res = subprocess.run([sys.executable, "-m", "pipeline", "stage=instances",
                              "domain=slalom", "instances.n=6", "progress=false",
                              f"store.path={store}"], capture_output=True, text=True,
                             cwd=tmp_path, env=pr.env(), timeout=600)
        assert res.returncode == 0, res.stderr + res.stdout
    assert "instances: already complete" in res.stdout
    assert stored_features(store) is None
    assert "features" not in xr.open_zarr(store, group="instances")
    doc = _status(store)
    assert doc["layout_version"] == LAYOUT_VERSION and not doc["damaged"]
