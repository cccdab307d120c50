"""IK's wrist-reach test (pipeline.sim.panda.wrist_out_of_reach), which answers NO_IK
without running IK: its constants against pybullet's forward kinematics of the URDF the
domains load, and its verdict against both IKs run in full on the poses it refuses."""

import numpy as np
import pybullet as pb
import pybullet_data
import pytest

from pipeline.sim import panda as P
from pipeline.sim.mobile import MobilePanda

WRIST_LINK = 5  # panda_link6: its origin is where the axes of joints 5 and 6 meet
SLACK = P.IK_POS_TOL + 2 * np.sin(P.IK_ANG_TOL / 2) * np.hypot(P.WRIST_BACK, P.WRIST_RADIUS)


@pytest.fixture(scope="module")
def client():
    c = pb.connect(pb.DIRECT)
    pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
    yield c
    pb.disconnect(c)


def wrist_and_tcp(arm: P.Panda):
    """(the wrist point, the TCP position, the TCP rotation matrix) where ``arm`` is set."""
    w = pb.getLinkState(arm.body, WRIST_LINK, computeForwardKinematics=True,
                        physicsClientId=arm.client)[4]
    tcp = pb.getLinkState(arm.body, P.TCP_LINK, computeForwardKinematics=True,
                          physicsClientId=arm.client)
    R = np.array(pb.getMatrixFromQuaternion(tcp[5])).reshape(3, 3)
    return np.array(w), np.array(tcp[4]), R


def random_turn(rng, angle: float) -> np.ndarray:
    """A rotation by ``angle`` about a random axis."""
    k = rng.normal(size=3)
    k /= np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def quat(R: np.ndarray) -> np.ndarray:
    from pipeline.sim.transforms import quaternion

    return np.asarray(quaternion(R), float)


def check_geometry(arm: P.Panda, set_q, shoulder, rng, n: int) -> float:
    """Asserts the wrist circle and reach on ``n`` random configurations (beyond the
    limits too); returns the largest wrist distance seen."""
    far = 0.0
    for _ in range(n):
        set_q(rng.uniform(P.LOWER - 0.5, P.UPPER + 0.5))
        wrist, tcp, R = wrist_and_tcp(arm)
        local = R.T @ (wrist - tcp)
        assert local[2] == pytest.approx(-P.WRIST_BACK, abs=1e-6)
        assert np.hypot(local[0], local[1]) == pytest.approx(P.WRIST_RADIUS, abs=1e-6)
        d = float(np.linalg.norm(wrist - shoulder()))
        assert d <= P.WRIST_REACH + 1e-6  # pybullet's link offsets carry float32 rounding
        far = max(far, d)
    return far


def test_the_wrist_stays_on_its_circle_and_within_its_reach(client):
    rng = np.random.default_rng(0)
    arm = P.Panda(client, (0.3, -0.2, 0.1))
    far = check_geometry(arm, arm.set, lambda: arm.joint2, rng, 3000)
    assert far > P.WRIST_REACH - 0.01  # the bound is the arm's, not a loose one
    robot = MobilePanda(client)
    for pose in rng.uniform([-2, -2, -np.pi], [2, 2, np.pi], size=(5, 3)):
        robot.set_base(pose)
        check_geometry(robot.arm, robot.set_arm, lambda: robot.joint2, rng, 300)


def test_poses_within_the_tolerances_of_a_reachable_one_are_never_refused(client):
    rng = np.random.default_rng(1)
    arm = P.Panda(client, (0.0, 0.0, 0.0))
    stretched = 0
    for _ in range(3000):
        q = rng.uniform(P.LOWER, P.UPPER)
        q[3] = rng.uniform(-0.8, -0.1)  # the elbow near its longest: the wrist far out
        arm.set(q)
        wrist, tcp, R = wrist_and_tcp(arm)
        stretched += np.linalg.norm(wrist - arm.joint2) > P.WRIST_REACH - 0.005
        # the tolerances' worst case: the position pushed away from the shoulder, turned
        away = (tcp - arm.joint2) / np.linalg.norm(tcp - arm.joint2)
        pos = tcp + P.IK_POS_TOL * away
        orn = quat(random_turn(rng, P.IK_ANG_TOL) @ R)
        assert not P.wrist_out_of_reach(arm.joint2, pos, orn)
        assert not P.wrist_out_of_reach(arm.joint2, tcp, quat(R))
    assert stretched > 100


def refused_poses(arm: P.Panda, rng, n: int):
    """Poses within REACH that the wrist test refuses, half of them just past its
    threshold: a stretched arm's pose moved out along the shoulder-to-wrist direction."""
    out = []
    while len(out) < n:
        if len(out) % 2:
            pos = arm.joint2 + rng.normal(size=3) * 0.5
            orn = quat(random_turn(rng, rng.uniform(0, np.pi)))
        else:
            q = rng.uniform(P.LOWER, P.UPPER)
            q[3] = -0.43
            arm.set(q)
            wrist, tcp, R = wrist_and_tcp(arm)
            out_dir = (wrist - arm.joint2) / np.linalg.norm(wrist - arm.joint2)
            push = P.WRIST_REACH - np.linalg.norm(wrist - arm.joint2) + SLACK + 0.0015
            pos, orn = tcp + push * out_dir, quat(R)
        if np.linalg.norm(pos - arm.joint2) <= P.REACH and P.wrist_out_of_reach(
                arm.joint2, pos, orn):
            out.append((pos, orn))
    return out


def test_a_refused_pose_is_one_that_neither_ik_reaches(client):
    rng = np.random.default_rng(2)
    arm = P.Panda(client, (0.0, 0.0, 0.0))
    for k, (pos, orn) in enumerate(refused_poses(arm, rng, 120)):
        for q, checks, reached in (arm.ik(pos, orn, P.ik_starts([k, 7], 4)),
                                   arm.analytic_ik(pos, orn, 4)):
            assert q is None and checks == 0 and not reached


def test_the_ik_step_answers_refused_poses_without_running_ik(client):
    """pipeline.domains.ik.solve_ik: a pose the wrist test refuses is NO_IK with no IK run
    (damped or analytic) and no check; a reachable one runs the IK as before."""
    from pipeline.domains.ik import solve_ik
    from pipeline.planning import Status

    rng = np.random.default_rng(3)
    arm = P.Panda(client, (0.0, 0.0, 0.0))
    runs = []
    for name in ("ik", "analytic_ik"):  # the arm's own methods, counted
        method = getattr(arm, name)
        setattr(arm, name, lambda *a, _m=method, _n=name, **k: runs.append(_n) or _m(*a, **k))
    for method in ("damped", "analytic"):
        for pos, orn in refused_poses(arm, rng, 20):
            out = solve_ik(arm, pos, orn, [0, 7], 4, method)
            assert (out.q, out.checks, out.status) == (None, 0, Status.NO_IK)
    assert runs == []
    arm.set(P.HOME)
    _, tcp, R = wrist_and_tcp(arm)
    for method in ("damped", "analytic"):  # reached (the module's other arms may be in the way)
        assert solve_ik(arm, tcp, quat(R), [0, 7], 4, method).status is not Status.NO_IK
    # damped IK runs from home, then (when home gave nothing the check accepts) once more
    # over the random starts; analytic IK once
    assert runs in (["ik", "analytic_ik"], ["ik", "ik", "analytic_ik"])


def test_reach_is_the_domains_rule_not_a_bound_of_the_arm(client):
    """docs/domains.md: REACH refuses some poses an IK would reach; the TCP of about a fifth
    of the configurations within the limits lies beyond it, none beyond 0.95 m."""
    rng = np.random.default_rng(0)
    arm = P.Panda(client, (0.0, 0.0, 0.0))
    far = np.array([np.linalg.norm(arm.tcp_pose(rng.uniform(P.LOWER, P.UPPER))[0]
                                   - arm.shoulder) for _ in range(2000)])
    assert 0.15 < (far > P.REACH).mean() < 0.25
    assert P.REACH < far.max() < 0.95
