"""Damped numerical IK (pybullet, as Panda.ik runs it) against the analytic ``frankik``
wheel, on the grasp_arm domain's pre-grasp poses within reach, one core.

Prints per method: ms per pose and the share of poses with a solution within the domain's
tolerances (5 mm, 0.05 rad) and the joint limits, checked with pybullet's own forward
kinematics.  frankik solves for the flange; its hand offset (0.1034 m) is not the URDF's
TCP (0.105 m), so the target handed to it is T_tcp · inv(flange → TCP of the URDF).
Collision checks are left out (the same for both).

Run: python benchmarks/bench_ik.py [--instances 5]   (needs: pip install frankik)
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from pipeline.domains import load_domain
from pipeline.sim import panda as P
from pipeline.sim import spheres as S
from pipeline.sim.fast_check import base_link_frame
from pipeline.sim.world import pose_matrix


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--instances", type=int, default=5)
    args = ap.parse_args()
    try:
        import frankik
    except ImportError:
        raise SystemExit("bench_ik.py needs the frankik wheel: pip install frankik") from None
    import pybullet as pb

    domain = load_domain("grasp_arm")
    offsets = S.fixed_offsets()
    flange_tcp = np.linalg.inv(offsets[7]) @ offsets[S.TCP_LINK]
    poses = []
    for seed in range(args.instances):
        inst = domain.check_instance(domain.sample_instance(seed))
        scene = domain.scene(inst)
        for g in domain.grasps:
            arm = scene.arms[g.arm]
            pos, orn = domain.pregrasp_pose(inst, g)
            if np.linalg.norm(pos - arm.shoulder) <= P.REACH:
                R = np.asarray(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
                poses.append((arm, pos, np.asarray(orn), pose_matrix(pos, R)))

    def reached(arm, q, pos, orn) -> bool:
        if q is None or np.any(q < P.LOWER) or np.any(q > P.UPPER):
            return False
        p, o = arm.tcp_pose(q)
        return bool(np.linalg.norm(p - pos) <= 0.005 and P._angle(o, orn) <= 0.05)

    rows = {}
    for name in ("pybullet (4 restarts)", "frankik ik_sample_q7"):
        ok, t = 0, 0.0
        for k, (arm, pos, orn, T) in enumerate(poses):
            t0 = time.perf_counter()
            if name.startswith("pybullet"):  # Panda.ik without the collision check
                q, _, _ = arm.ik(pos, orn, P.ik_starts(k, 4), collides=lambda q: False)
            else:
                local = np.linalg.inv(base_link_frame(arm.client, arm.body)) @ T
                sols = frankik.ik_sample_q7(local @ np.linalg.inv(flange_tcp), P.HOME,
                                            sample_size=60, sample_interval=330, full_ik=True)
                q = np.asarray(sols[0]).ravel() if len(sols) else None
            t += time.perf_counter() - t0
            ok += reached(arm, q, pos, orn)
            arm.set(P.HOME)
        rows[name] = (t / len(poses) * 1e3, ok / len(poses))
    print(f"IK on {len(poses)} grasp_arm pre-grasp poses within reach, one core")
    for name, (ms, share) in rows.items():
        print(f"  {name:<24} {ms:7.3f} ms per pose, solved {share:.1%}")


if __name__ == "__main__":
    main()
