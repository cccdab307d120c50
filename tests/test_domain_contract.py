"""The contract every registered domain and planner keeps (docs/architecture.md), checked
for each of them in the spirit of scikit-learn's ``parametrize_with_checks``: a new domain
or planner registered in ``DOMAINS``/``PLANNERS``, or a domain of an installed plug-in
package, is checked here without a new test (``pytest tests/test_domain_contract.py -k
<name>`` checks one).

Per (domain, planner): the registry either refuses the pair with its one message or the
domain plans with it deterministically (across call order and across processes), refuses
bad specs and constraints, reports statuses and failed steps the store can hold, renders,
and extracts a usable constraint from RAWPLANNER's solution; every feasible path, re-checked
densely by the domain's exact robot model in a fresh scene (not by the planner's own
checks), is collision-free, and no call reports more checks than its budget allows.  Per
planner: it plans on a plain robot model, or is refused for it.  Per domain: its instance
features (none, or those it declares) are finite, of the declared length and a function of
the spec.
"""

from __future__ import annotations

import functools
import json
import subprocess
import sys

import numpy as np
import pytest

from pipeline.domains import ConstraintSet, InstanceError, domain_names, load_domain
from pipeline.domains.planar import PlanarScene
from pipeline.environment import agree
from pipeline.planning import (
    PLANNERS,
    PlannerSettings,
    PlanResult,
    Status,
    make_planner,
    path_is_free,
)
from pipeline.planning.base import CAPABILITIES, capabilities
from pipeline.planning.registry import planner_class, planners
from tests.replay import child_env, code_paths

DOMAINS = domain_names()  # the built-in ones and the installed plug-ins'
PLANNER_NAMES = list(planners())  # likewise
PAIRS = [(d, p) for d in DOMAINS for p in PLANNER_NAMES]
ENTRIES = 2  # planning calls per check: pick_place and trajopt calls cost ~0.1-1 s each


def make(domain: str, planner: str):
    """The domain with this planner, or None when the registry refuses the pair (then the
    refusal must be the registry's one message)."""
    try:
        return _make(domain, planner)
    except ValueError as exc:
        cls = planner_class(planner)
        assert cls.requires, f"{planner} requires nothing, yet {domain} refused it: {exc}"
        assert f"planner={planner} needs" in str(exc) and "does not provide" in str(exc)
        return None


#: the wall-clock safety net out of reach: a loaded machine must not turn a call into
#: "timeout" (the only machine-dependent status) and break a determinism check
NO_WALL_CAP = 1e6


@functools.cache
def _make(domain: str, planner: str):
    return load_domain(domain, planner={"name": planner, "wall_cap_s": NO_WALL_CAP})


@functools.cache
def solved(domain: str):
    """(instance spec, RawResult) for the first of a few instances RAWPLANNER solves, with
    rrt_connect (its constraint serves every planner)."""
    d = _make(domain, "rrt_connect")
    for seed in range(1, 5):
        spec = d.sample_instance(seed)
        raw = d.raw_plan(spec, seed=seed)
        if raw.plan.feasible:
            return spec, raw
    pytest.fail(f"RAWPLANNER solved none of 4 {domain} instances")


def entries(domain: str):
    """A few (instance spec, constraint row) pairs: the solved instance with its own
    extracted constraint, then other instances and constraints."""
    d = _make(domain, "rrt_connect")
    spec, raw = solved(domain)
    if d.fixed_constraints:
        rows = d.constraints().features[:: max(1, d.constraints().m // ENTRIES)][:ENTRIES - 1]
    else:
        rows = [raw.constraint] * (ENTRIES - 1)
    return [(spec, raw.constraint)] + [(d.sample_instance(10 + k), r) for k, r in
                                       enumerate(rows)]


def calls(domain: str) -> list[tuple]:
    """(spec, constraint row, seed) of the checked planning calls."""
    return [(spec, row, 1000 + k) for k, (spec, row) in enumerate(entries(domain))]


@functools.cache
def planned(domain: str, planner: str) -> list[PlanResult]:
    """The checked calls, planned in order (shared by the checks below)."""
    d = _make(domain, planner)
    return [d.plan(spec, row, seed=s) for spec, row, s in calls(domain)]


def summary(result: PlanResult) -> tuple:
    return (int(result.status), result.checks, result.step, repr(result.score),
            result.path.tobytes().hex())


def domain_or_skip(domain: str, planner: str):
    d = make(domain, planner)
    if d is None:
        pytest.skip(f"the registry refuses planner={planner} for {domain} (checked)")
    return d


# -- domains × planners ----------------------------------------------------------------------
@pytest.mark.parametrize("domain,planner", PAIRS)
def test_registry_accepts_or_refuses_with_one_message(domain, planner):
    d = make(domain, planner)
    if d is not None:
        assert d.name == domain and d.planner.name == planner
        assert load_domain(domain, planner=planner).planner.name == planner
        assert d.steps and len(set(d.steps)) == len(d.steps)


@pytest.mark.parametrize("domain,planner", PAIRS)
def test_plans_are_deterministic_across_call_order(domain, planner):
    d = domain_or_skip(domain, planner)
    forward = [summary(r) for r in planned(domain, planner)]
    backward = [summary(d.plan(spec, row, seed=s)) for spec, row, s in reversed(calls(domain))]
    assert forward == backward[::-1]


@pytest.mark.parametrize("domain,planner", PAIRS)
def test_feasible_paths_recheck_free_and_checks_stay_in_budget(domain, planner):
    """The planner contract (docs/architecture.md): a feasible path is collision-free when
    every edge is re-checked by the exact checker, and checks <= max_checks (per call:
    the domain's ``check_limit``, its budgets and its own checks together)."""
    d = domain_or_skip(domain, planner)
    for (spec, row, _), r in zip(calls(domain), planned(domain, planner), strict=True):
        assert 0 <= r.checks <= d.check_limit(), (r.status, r.step)
        if r.feasible:
            rechecked = d.recheck(spec, row, r)
            assert rechecked and all(rechecked.values()), rechecked


PROCESS_CODE = """
import json, sys, traceback
import numpy as np
from pipeline.domains import load_domain
out = {}
for domain, planner, sent in json.loads(sys.stdin.read()):
    try:
        d = load_domain(domain, planner={"name": planner, "wall_cap_s": 1e6})
        out[f"{domain}/{planner}"] = [
            [int(r.status), r.checks, r.step, repr(r.score), r.path.tobytes().hex()]
            for r in (d.plan(spec, np.asarray(row, float), seed=seed) for spec, row, seed in sent)]
    except Exception:
        out[f"{domain}/{planner}"] = traceback.format_exc()
print(json.dumps(out))
"""


@functools.cache
def in_child(env: tuple[tuple[str, str], ...]) -> dict[str, list | str]:
    """The checked calls of every pair the registry accepts, planned pair after pair in one
    fresh process with ``env`` set (and nothing this process's environment picked up, such
    as a Dask nanny's OPENBLAS_NUM_THREADS=1): "domain/planner" -> their summaries, or the
    child's traceback for that pair.  One process for all pairs: each would otherwise pay
    the interpreter's start and imports (about 1.5 s) for two planning calls."""
    sent = [(domain, planner, [(spec, [float(v) for v in row], s)
                               for spec, row, s in calls(domain)])
            for domain, planner in PAIRS if make(domain, planner) is not None]
    out = subprocess.run([sys.executable, "-c", PROCESS_CODE], input=json.dumps(sent),
                         capture_output=True, text=True, check=True, env=child_env(dict(env)))
    return json.loads(out.stdout.strip().splitlines()[-1])


def child_summaries(domain: str, planner: str, env: dict[str, str]) -> list[list]:
    found = in_child(tuple(sorted(env.items())))[f"{domain}/{planner}"]
    assert not isinstance(found, str), found  # the child's traceback
    return found


@pytest.mark.parametrize("threads", ["1", "2"])
@pytest.mark.parametrize("domain,planner", PAIRS)
def test_plans_are_identical_in_another_process(domain, planner, threads):
    """Bitwise, in a process with one BLAS thread (a Dask worker) or two (a notebook)."""
    domain_or_skip(domain, planner)
    here = [list(summary(r)) for r in planned(domain, planner)]
    assert child_summaries(domain, planner, {"OPENBLAS_NUM_THREADS": threads}) == here


@pytest.mark.parametrize("domain,planner", PAIRS)
def test_plans_keep_the_contract_on_other_cpu_code_paths(domain, planner):
    """With NumPy and OpenBLAS forced onto an older CPU's kernels: statuses, checks and
    steps exact, scores and every path coordinate within the contract's tolerance
    (docs/reproducibility.md)."""
    domain_or_skip(domain, planner)
    forced = [(k, v) for k, v in code_paths().items() if not k.startswith("blas-")]
    if not forced:
        pytest.skip("no other CPU code path can be forced on this machine")
    name, env = forced[-1]  # all of them together where this machine can (test_replay: each)
    here = [summary(r) for r in planned(domain, planner)]
    for a, b in zip(here, child_summaries(domain, planner, env), strict=True):
        assert list(a[:3]) == b[:3], name
        assert agree(float(a[3]), float(b[3])), name
        assert agree(*(np.frombuffer(bytes.fromhex(x[4])) for x in (a, b))), name


@pytest.mark.parametrize("domain,planner", PAIRS)
def test_statuses_and_steps_are_what_the_store_holds(domain, planner):
    d = domain_or_skip(domain, planner)
    for r in planned(domain, planner):
        assert isinstance(r.status, Status) and r.checks >= 0 and r.time > 0
        assert r.feasible == (r.status is Status.OK)
        if d.skips_plans:
            assert r.status is Status.SKIPPED and r.checks == 0
        if r.feasible:
            assert r.step == "" and r.score == -r.length <= 0 and len(r.path) >= 1
        else:
            assert np.isnan(r.score)
            assert r.step in (*d.steps, ""), r.step
            assert r.step or r.status in (Status.SKIPPED, Status.ERROR)
            assert r.status is not Status.ERROR, r.error


@pytest.mark.parametrize("domain,planner", PAIRS)
def test_raw_solutions_give_usable_constraints(domain, planner):
    d = domain_or_skip(domain, planner)
    spec, _ = solved(domain)
    raw = d.raw_plan(spec, seed=3)  # RAWPLANNER plans even where π plans nothing (noop)
    assert raw.constraint.shape == (d.n_features,) and raw.tries >= 1
    assert raw.plan.status is not Status.SKIPPED
    if raw.plan.feasible:
        assert np.all(np.isfinite(raw.constraint))
        d.constraint(raw.constraint)  # accepted as θ
        assert all(d.recheck(spec, raw.constraint, raw.plan).values())
    else:
        assert np.all(np.isnan(raw.constraint)) and raw.plan.step in d.steps
    rows = np.stack([raw.constraint, np.full(d.n_features, np.nan)])
    kept = d.constraints(None if d.fixed_constraints else ConstraintSet(rows, np.array([0, 1])))
    assert kept.features.shape[1] == d.n_features and np.all(np.isfinite(kept.features))


# -- domains ---------------------------------------------------------------------------------
@pytest.mark.parametrize("domain", DOMAINS)
def test_instances_are_json_and_a_function_of_the_seed(domain):
    d = _make(domain, "rrt_connect")
    spec = d.sample_instance(5)
    assert json.loads(json.dumps(spec)) == spec == d.sample_instance(5)
    assert spec["domain"] == domain and spec["seed"] == 5
    assert spec != d.sample_instance(6)
    d.check_instance(json.loads(json.dumps(spec)))


@pytest.mark.parametrize("domain", DOMAINS)
def test_instance_features_are_declared_finite_and_a_function_of_the_spec(domain):
    d = _make(domain, "rrt_connect")
    q = d.n_instance_features
    assert len({f.name for f in d.omega_features}) == q  # names unique (a coordinate)
    assert all(f.units and f.description for f in d.omega_features)
    rows = []
    for seed in range(6):
        spec = d.sample_instance(seed)
        x = d.instance_features(spec)
        assert x.shape == (q,) and x.dtype == np.float64 and np.all(np.isfinite(x))
        again = d.instance_features(d.check_instance(json.loads(json.dumps(spec))))
        assert again.tobytes() == x.tobytes()
        rows.append(x)
    table = d.instance_feature_rows([json.dumps(d.sample_instance(s)) for s in range(6)])
    assert table.shape == (6, q) and table.tobytes() == np.stack(rows).tobytes()
    if q:
        assert len({row.tobytes() for row in rows}) > 1, "every instance looks the same"


@pytest.mark.parametrize("domain", DOMAINS)
def test_bad_specs_and_constraints_are_refused_naming_the_input(domain):
    d = _make(domain, "rrt_connect")
    spec, raw = solved(domain)
    for bad, field in (("not an object", "JSON object"), ({}, "seed"),
                       ({**spec, "seed": "7"}, "seed"), ({**spec, "obstacles": 3}, "obstacles")):
        with pytest.raises(InstanceError, match=field):
            d.check_instance(bad)
        with pytest.raises(InstanceError, match=field):
            d.plan(bad, raw.constraint)
    for bad in ([1.0] * (d.n_features + 1), [np.nan] * d.n_features, "θ"):
        with pytest.raises(ValueError, match="constraint"):
            d.plan(spec, bad)


@pytest.mark.parametrize("domain", DOMAINS)
def test_scenes_and_renders(domain, tmp_path):
    d = _make(domain, "rrt_connect")
    spec, raw = solved(domain)
    scene = d.build_scene(spec)
    try:
        assert hasattr(scene, "client_id") and hasattr(scene, "robot_ids")
        assert callable(scene.set_configuration)
    finally:
        getattr(scene, "close", lambda: None)()
    out = d.render(spec, raw.plan, tmp_path / "scene.png", constraint=raw.constraint)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 2000
    assert d.render(spec, None, tmp_path / "bare.png").stat().st_size > 2000


# -- planners --------------------------------------------------------------------------------
def open_room():
    return PlanarScene(np.array([[5.0, 8.0, 1.0, 1.0]]), 0.25, np.full(2, 0.25),
                       np.full(2, 9.75))


@pytest.mark.parametrize("planner", PLANNER_NAMES)
def test_planner_declares_what_it_needs(planner):
    cls = planner_class(planner)
    assert cls.name == planner and cls.requires <= set(CAPABILITIES)
    if cls.stand_in is not None:
        assert cls.plans_nothing and cls.stand_in in PLANNERS


@pytest.mark.parametrize("planner", PLANNER_NAMES)
def test_planner_plans_on_a_plain_robot_or_is_refused(planner):
    settings = PlannerSettings(name=planner)
    robot = open_room()
    if planner_class(planner).requires - capabilities(robot):
        with pytest.raises(ValueError, match=f"planner={planner} needs .* does not provide"):
            make_planner(settings, type(robot))
        return
    chosen = make_planner(settings, type(robot))
    start, goal = np.array([1.0, 5.0]), np.array([9.0, 5.0])
    a = chosen.plan(robot, start, goal, seed=4)
    b = chosen.plan(robot, start, goal, seed=4)
    assert summary(a) == summary(b)
    assert a.feasible and np.allclose(a.path[0], start) and np.allclose(a.path[-1], goal)
    assert np.all(a.path >= robot.lower) and np.all(a.path <= robot.upper)
    assert path_is_free(a.path, robot, settings.resolution)  # every state, not coarse-to-fine
    assert 0 < a.checks <= settings.max_checks
    tight = make_planner(PlannerSettings(name=planner, max_checks=25), type(robot))
    walled = PlanarScene(np.array([[5.0, 5.0, 0.5, 9.0]]), 0.25, robot.lower, robot.upper)
    assert tight.plan(walled, start, goal, seed=4).checks <= 25
    inside = chosen.plan(robot, start, np.array([5.0, 8.0]), seed=4)
    assert inside.status is Status.GOAL_IN_COLLISION
