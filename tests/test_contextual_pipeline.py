"""The contextual selectors inside the pipeline: ``box evaluate`` on a matrix without instance
features gives BOX's numbers, a store's features and checks reach the evaluation, and live
solving runs capped tries as real planning tries that pause and resume with the result of
one uninterrupted call."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import box_core
from box_core.synthetic import score_matrix
from pipeline.configs import CONF_DIR, register_configs
from pipeline.domains.cache import domain_for
from pipeline.solve import solve_instance
from pipeline.store import evaluation as evaluation_store
from pipeline.store.readers import domain_spec_of
from pipeline.store.score_store import ScoreStore
from pipeline.worker import entry_seed

CONTEXTUAL = ("contextual", "contextual_capped")


def box_evaluate(*args) -> subprocess.CompletedProcess:
    box = Path(sys.executable).parent / "box"  # the installed command line
    return subprocess.run([str(box), "evaluate", *args], capture_output=True, text=True,
                          check=False)


def test_box_evaluate_without_instance_features_gives_box_s_numbers(tmp_path):
    data = score_matrix(60, 12, useful=8, per_type=3, seed=3)
    path = tmp_path / "m.npz"
    np.savez(path, scores=data.scores, feasible=data.feasible, times=data.times,
             checks=np.full(data.scores.shape, 10))
    res = box_evaluate(str(path), "--selectors", "box,contextual,contextual_capped",
                       "--no-overhead", "--json")
    assert res.returncode == 0, res.stderr
    lines = {s["name"]: s for s in json.loads(res.stdout)["selectors"]}
    for name in CONTEXTUAL:
        assert lines[name]["mean_time"] == lines["box"]["mean_time"]
        assert lines[name]["mean_tries"] == lines["box"]["mean_tries"]


def test_box_evaluate_reads_instance_features_and_refuses_a_wrong_shape(tmp_path):
    data = score_matrix(60, 12, useful=8, per_type=3, seed=4)
    path = tmp_path / "m.npz"
    np.savez(path, scores=data.scores, feasible=data.feasible, times=data.times,
             instance_features=np.zeros((59, 3)))
    res = box_evaluate(str(path), "--selectors", "box,contextual")
    assert res.returncode == 2
    assert "instance_features" in res.stderr and len(res.stderr.strip().splitlines()) == 1


@pytest.fixture(scope="module")
def grasp_arm():
    register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["domain=grasp_arm"])
    spec = domain_spec_of(OmegaConf.to_container(cfg, resolve=True, enum_to_str=True))
    domain = domain_for(spec)
    return spec, domain, domain.constraints().features


def test_live_capped_tries_pause_resume_and_end_as_uninterrupted_calls(grasp_arm):
    """A contextual_capped selector with a small cap, live on a real grasp_arm instance:
    tries pause at the cap and resume; every ended try has the status and path length of
    one uninterrupted planning call of its entry."""
    spec, domain, theta = grasp_arm
    rng = np.random.default_rng(0)
    n, m = 40, theta.shape[0]
    feasible = rng.random((n, m)) < 0.3
    train = np.where(feasible, -rng.uniform(1, 5, (n, m)), -10.0)
    # training rows where plans come within a few dozen checks and failures run out of
    # budget: capping pays, and this instance's real entries need more than the cap
    checks = np.where(feasible, rng.integers(5, 50, (n, m)), 20000)
    times = np.where(feasible, 0.002, 0.5)
    features = rng.normal(size=(n, len(domain.omega_features)))
    settings = box_core.tuned_settings("contextual_capped", train, feasible=feasible,
                                       times=times, checks=checks, instance_features=features,
                                       k=10, cap_quantile=0.9, select_features=0)
    assert math.isfinite(settings["cap"])
    run_seed, paused_seen, resumed = 0, 0, 0
    for inst_seed in range(100, 110):  # instances whose first plans need more than the cap
        instance = domain.sample_instance(inst_seed)
        record = solve_instance(spec, instance, inst_seed, run_seed, train, theta, -10.0,
                                ["contextual_capped"],
                                {"contextual_capped": {"settings": settings}}, 30, None,
                                train_feasible=feasible, train_times=times,
                                train_checks=checks, train_features=features)
        tries = record["selectors"]["contextual_capped"]["tries"]
        paused = [t for t in tries if t["status"] == "paused"]
        ended = [t for t in tries if t["status"] != "paused"]
        paused_seen += len(paused)
        resumed += len({t["constraint"] for t in paused} & {t["constraint"] for t in ended})
        assert len(ended) <= 30 and all(t["allowance"] == settings["cap"] for t in paused)
        assert len({t["constraint"] for t in ended}) == len(ended)  # each ends once
        inst = domain.check_instance(instance)
        for t in ended:  # resumed or not, the result of one uninterrupted call
            j = t["constraint"]
            whole = domain.plan(inst, theta[j], seed=entry_seed(run_seed, inst_seed, j))
            assert t["status"] == whole.status.name.lower()
            assert t["length"] == (whole.length if whole.feasible else None)
    assert paused_seen > 0 and resumed > 0


def test_a_capped_order_longer_than_the_others_is_stored_with_theirs_padded(made, tmp_path):
    """CONTEXTUAL+CAPS may try a column twice (paused, then resumed), so its order can be
    up to 2m wide while the others' are m: ``evaluation/`` holds the longest, the others
    padded with -1 (the write once failed to broadcast m into 2m)."""
    copy = tmp_path / "s.zarr"
    shutil.copytree(made[0], copy)
    store = ScoreStore(copy)
    stored = evaluation_store.read(store)
    box = stored.order["box"]
    wide = np.concatenate([box, box], axis=1)  # stands for a trace with resumptions
    stored.order["contextual_capped"] = wide
    stored.selectors = [*stored.selectors, "contextual_capped"]
    for table in (stored.first_feasible_time, stored.best_score, stored.first_feasible_step):
        table["contextual_capped"] = table["box"]
    evaluation_store.write(store, stored, score_units=store.score_units())
    back = evaluation_store.read(ScoreStore(copy, read_only=True))
    assert back.order["contextual_capped"].tolist() == wide.tolist()
    assert back.order["box"][:, :box.shape[1]].tolist() == box.tolist()
    assert (back.order["box"][:, box.shape[1]:] == -1).all()
