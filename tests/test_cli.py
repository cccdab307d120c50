import json

import numpy as np
import pytest
import scipy.io
from typer.testing import CliRunner

from pipeline.cli import app
from tests.matrices import degenerate

runner = CliRunner()


@pytest.fixture
def matrix():
    D = degenerate(20, 8, seed=1, constant=2, duplicate=1, rank=2)
    times = np.random.default_rng(0).uniform(0.01, 0.1, D.shape)
    return D, D > -10, times, np.random.default_rng(1).normal(size=(8, 2))


def test_evaluate_npz_prints_the_summary_table(tmp_path, matrix):
    D, F, T, theta = matrix
    path = tmp_path / "d.npz"
    np.savez(path, scores=D, feasible=F, times=T, features=theta)
    res = runner.invoke(app, ["evaluate", str(path)])
    assert res.exit_code == 0, res.output
    for name in ("box", "static", "rand", "doo"):
        assert name in res.output


def test_evaluate_json_holds_the_loocv_numbers(tmp_path, matrix):
    import box_core

    D, F, T, _ = matrix
    path = tmp_path / "d.npz"
    np.savez(path, scores=D, feasible=F, times=T)
    res = runner.invoke(app, ["evaluate", str(path), "--json", "--no-overhead",
                              "--selectors", "box,static", "-k", "5"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    direct = box_core.loocv(D, feasible=F, times=T, selectors=("box", "static"), k=5,
                            measure_overhead=False).summary()
    assert [s["name"] for s in doc["selectors"]] == ["box", "static"]
    assert doc["selectors"][1]["mean_time"] == pytest.approx(direct.line("static").mean_time)
    assert (doc["n"], doc["m"], doc["k"]) == (20, 8, 5)


def test_evaluate_mat_with_named_variables(tmp_path, matrix):
    D, F, T, _ = matrix
    path = tmp_path / "d.mat"
    scipy.io.savemat(path, {"D": D, "ok": F.astype(np.uint8), "T": T})
    res = runner.invoke(app, ["evaluate", str(path), "--scores-var", "D", "--feasible-var", "ok",
                              "--times-var", "T", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["rows_with_feasible"] == int(F.any(axis=1).sum())


@pytest.mark.parametrize("setup, args, message", [
    (lambda p: None, [], "no such file"),
    (lambda p: np.savez(p, other=np.ones((4, 4))), [], "no array named 'scores'"),
    (lambda p: np.savez(p, scores=np.ones((4, 4)) + np.eye(4), times=np.ones((3, 4))), [],
     "times has shape"),
    (lambda p: np.savez(p, scores=np.array([[1.0, np.nan]] * 4)), [], "NaN"),
    (lambda p: p.write_bytes(b"not a zip"), [], "cannot read"),
    (lambda p: np.savez(p, scores=np.ones((4, 4)) + np.eye(4)), ["-k", "9"], "k must be"),
])
def test_bad_input_is_one_line_and_exit_code_2(tmp_path, setup, args, message):
    path = tmp_path / "d.npz"
    setup(path)
    res = runner.invoke(app, ["evaluate", str(path), *args])
    assert res.exit_code == 2
    assert message in res.output
    assert len(res.output.strip().splitlines()) == 1


def test_unsupported_format_is_refused(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text("1,2\n")
    res = runner.invoke(app, ["evaluate", str(path)])
    assert res.exit_code == 2 and "unsupported format" in res.output


def test_demo_writes_a_matrix_and_evaluates_it(tmp_path):
    path = tmp_path / "demo.npz"
    res = runner.invoke(app, ["demo", "--n", "60", "--m", "20", "--path", str(path)])
    assert res.exit_code == 0, res.output
    with np.load(path) as f:
        assert f["scores"].shape == (60, 20)
    assert "pembo" in res.output


def test_demo_rerun_reuses_its_file_but_keeps_a_different_one(tmp_path):
    path = tmp_path / "demo.npz"
    args = ["demo", "--n", "30", "--m", "10", "--path", str(path)]
    assert runner.invoke(app, args).exit_code == 0
    kept = path.read_bytes()
    assert runner.invoke(app, args).exit_code == 0  # same matrix: fine
    other = runner.invoke(app, [*args, "--seed", "1"])
    assert other.exit_code == 2 and "--overwrite" in other.output
    assert path.read_bytes() == kept  # the seed-0 matrix is untouched
    assert runner.invoke(app, [*args, "--seed", "1", "--overwrite"]).exit_code == 0
    assert path.read_bytes() != kept


def test_demo_refuses_a_path_that_is_not_npz(tmp_path):
    res = runner.invoke(app, ["demo", "--n", "30", "--m", "10", "--path", str(tmp_path / "x")])
    assert res.exit_code == 2 and ".npz" in res.output


def test_version_is_the_installed_distribution():
    from importlib.metadata import version

    res = CliRunner().invoke(app, ["--version"])
    assert res.exit_code == 0 and res.output.strip() == f"box-planning {version('box-planning')}"


def test_completion_is_offered_and_every_selector_is_listed_in_help():
    import box_core

    res = CliRunner().invoke(app, ["--help"], terminal_width=200)
    assert "--install-completion" in res.output
    res = CliRunner().invoke(app, ["evaluate", "--help"], terminal_width=400)
    text = " ".join(res.output.split())
    for name in box_core.SELECTORS:
        assert name in text, name


@pytest.mark.parametrize("command", [["-m", "pipeline"], ["box-pipeline"]])
def test_pipeline_help_names_the_command_and_lists_only_real_choices(command):
    """``python -m pipeline --help`` and the ``box-pipeline`` console script: the command's
    name (not "__main__ is powered by Hydra"), and each group's options (no schemas)."""
    import subprocess
    import sys
    from pathlib import Path

    args = ([sys.executable, *command] if command[0] == "-m"
            else [str(Path(sys.executable).parent / command[0])])
    res = subprocess.run([*args, "--help"], capture_output=True, text=True, check=True)
    assert res.stdout.startswith("box-pipeline (python -m pipeline)")
    assert "domain: grasp_arm, grasp_base, pick_place, planar" in res.stdout
    assert "planner: noop, ompl, rrt_connect, trajopt" in res.stdout
    assert "_schema" not in res.stdout and "powered by Hydra" not in res.stdout


def test_box_pipeline_bash_completion_offers_real_choices_and_keys(tmp_path):
    """Hydra's bash completion installed as a user installs it (``eval`` of ``box-pipeline
    -sc install=bash``), then asked as bash asks it: the real options of a group (no
    schema entries) and the config's keys."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from tests import pipeline_runs as pr

    script = tmp_path / "complete.sh"
    script.write_text("""
eval "$(box-pipeline -sc install=bash)"
complete -p box-pipeline
ask() {
  COMP_LINE="$1"; COMP_POINT=${#1}; local w=($1)
  COMP_CWORD=$(( ${#w[@]} - 1 )); [[ "$1" == *" " ]] && COMP_CWORD=${#w[@]}
  COMPREPLY=(); hydra_bash_completion; echo "${COMPREPLY[*]}"
}
ask "box-pipeline domain="
ask "box-pipeline planner="
ask "box-pipeline "
ask "box-pipeline domain=planar domain.rob"
""")
    env = {**pr.env(), "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    res = subprocess.run(["bash", str(script)], capture_output=True, text=True, env=env,
                         cwd=tmp_path, check=True, timeout=600)
    registered, domains, planners, top, keys = res.stdout.splitlines()
    assert registered.endswith("-F hydra_bash_completion box-pipeline")
    from pipeline.plugins import plugin_targets  # installed plug-in domains are offered too

    assert domains.split() == [f"domain={d}" for d in sorted(
        {"grasp_arm", "grasp_base", "pick_place", "planar", *plugin_targets("domain")})]
    assert planners.split() == ["planner=noop", "planner=ompl", "planner=rrt_connect",
                                "planner=trajopt"]
    assert {"stage=", "domain=", "store.", "cluster.", "progress="} <= set(top.split())
    assert keys == "domain.robot_radius="
    fish = subprocess.run(["box-pipeline", "-sc", "query=fish"], capture_output=True,
                          text=True, env={**env, "COMP_LINE": "box-pipeline cluster="},
                          cwd=tmp_path, check=True, timeout=600)
    assert fish.stdout.splitlines() == ["cluster=address", "cluster=local", "cluster=slurm"]
