"""Self-contacts of the Panda's wrist, certified from a table over the last two joints.

The forearm (link 4), the wrist (link 5), the flange (link 6), the hand and the fingers
pass within 2 cm of each other in most configurations, too close for spheres to tell
apart.  Their poses relative to the forearm depend on q5 and q6 only, so pybullet's
distances of those link pairs are tabulated once over a grid of (q5, q6).  Between grid
points a distance changes by at most ρ5·|Δq5| + ρ6·|Δq6| (ρj: how far the moving
geometry reaches from joint j's axis, bounded by distances from the joint's origin), so a
configuration is certified free of these contacts when its nearest grid point's distance
exceeds that bound for half a grid step, plus ``SLACK``.

The table ships with the package (``wrist_table.npz``, made by ``python -m
pipeline.sim.wrist``), stamped with what it was computed from (pybullet's version, the
URDF and meshes, the grid, the pairs, the bound).  When the stamp does not match, cells
are computed when first needed instead (about 0.4 ms each; a planning process visits a
few thousand of the 38,000).
"""

from __future__ import annotations

import atexit
import functools
import hashlib
import json
from pathlib import Path

import numpy as np
import pybullet as pb

from pipeline.sim import collide, spheres

TABLE_FILE = Path(__file__).with_name("wrist_table.npz")
#: link pairs whose relative pose depends on q5 and q6 only (forearm, wrist vs the rest)
PAIRS = tuple((a, b) for a in (4, 5) for b in (6, 8, 9, 10) if (a, b) != (5, 6))
STEP = 0.025  # radians between grid points
SLACK = 0.002  # metres on top of the interpolation bound


class WristTable:
    """The grid over (q5, q6), filled lazily: a cell is computed with pybullet (its own
    headless client) the first time a configuration falls into it, then kept."""

    def __init__(self, pairs, lower, upper, bound: float):
        self.pairs, self.bound = tuple(pairs), bound
        self.lower = np.asarray(lower, float)
        shape = np.rint((np.asarray(upper, float) - self.lower) / STEP).astype(int) + 1
        self.state = np.zeros(shape, dtype=np.int8)  # 0 unknown, 1 free, 2 maybe in contact
        self._client = None
        self._body = None
        self.stamp = json.dumps({
            "pybullet": pb.getAPIVersion(), "model": _model_digest(), "step": STEP,
            "slack": SLACK, "pairs": self.pairs, "bound": round(float(bound), 12),
            "lower": self.lower.round(12).tolist(), "shape": [int(v) for v in shape]},
            sort_keys=True)
        if TABLE_FILE.is_file():
            with np.load(TABLE_FILE) as stored:
                if str(stored["stamp"]) == self.stamp:
                    self.state = stored["state"].astype(np.int8)

    def fill(self) -> None:
        """Compute every cell still unknown."""
        for i, k in zip(*np.nonzero(self.state == 0), strict=True):
            self.state[i, k] = 1 if self._free(self.lower + STEP * np.array([i, k])) else 2

    def save(self, path=None) -> Path:
        out = Path(path or TABLE_FILE)
        np.savez_compressed(out, state=self.state, stamp=np.array(self.stamp))
        return out

    def uncertain(self, q: np.ndarray) -> np.ndarray:
        """(N,) whether configurations ``q`` (N, 7) may have a wrist self-contact."""
        q = np.ascontiguousarray(q, float)
        pre = np.empty(len(q), dtype=np.bool_)
        if collide.wrist_cells(q, self.lower, STEP, self.state, pre):
            # the kernel's cell arithmetic, so that the cells it asks for get filled
            idx = np.floor((q[:, 5:7] - self.lower) / STEP + 0.5).astype(np.int64)
            idx = np.clip(idx, 0, np.array(self.state.shape) - 1)
            for i, k in {tuple(c) for c in idx if self.state[c[0], c[1]] == 0}:
                self.state[i, k] = 1 if self._free(self.lower + STEP * np.array([i, k])) else 2
            collide.wrist_cells(q, self.lower, STEP, self.state, pre)
        return pre

    def _free(self, q56) -> bool:
        if self._client is None:
            import pybullet_data

            self._client = pb.connect(pb.DIRECT)
            pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=self._client)
            self._body = pb.loadURDF(spheres.URDF, useFixedBase=True,
                                     physicsClientId=self._client)
            for j in (9, 10):
                pb.resetJointState(self._body, j, 0.04, physicsClientId=self._client)
            atexit.register(self.close)
        c, body = self._client, self._body
        pb.resetJointStatesMultiDof(body, [5, 6], [[float(q56[0])], [float(q56[1])]],
                                    physicsClientId=c)
        return all(min((p[8] for p in pb.getClosestPoints(body, body, self.bound, a, b,
                                                          physicsClientId=c)),
                       default=np.inf) > self.bound for a, b in self.pairs)

    def close(self) -> None:
        if self._client is not None:
            pb.disconnect(physicsClientId=self._client)
            self._client = None


def _reach(model: spheres.SphereModel, links, frame: int) -> float:
    """Upper bound of the distance of the ``links``' geometry (their spheres hold it) from
    the origin of arm frame ``frame`` at any q."""
    chain = spheres.panda_chain()
    reach = 0.0
    for link in links:
        m = model.links == link
        # chain of fixed translations from the joint's frame to the link's own frame
        along = sum(np.linalg.norm(chain.origins[k, :3, 3])
                    for k in range(frame + 1, spheres.FRAME_OF_LINK[link]))
        local = np.linalg.norm(model.centres[m], axis=1) + model.radii[m]
        reach = max(reach, along + float(local.max()))
    return reach


@functools.lru_cache(maxsize=4)
def wrist_table(ignored: frozenset, lower5: float, upper5: float, lower6: float,
                upper6: float) -> WristTable:
    """The (per-process) table for an arm whose filtered link pairs are ``ignored``
    (pybullet does not check those), over the given joint ranges."""
    pairs = [p for p in PAIRS if p not in ignored and p[::-1] not in ignored]
    model = spheres.panda_spheres(margin=0.0)
    bound = (_reach(model, (5, 6, 8, 9, 10), 5) + _reach(model, (6, 8, 9, 10), 6)) * STEP / 2
    return WristTable(pairs, (lower5, lower6), (upper5, upper6), bound + SLACK)


def _model_digest() -> str:
    """SHA-256 of the URDF and the collision meshes the table was computed from."""
    h = hashlib.sha256((spheres._data_path() / spheres.URDF).read_bytes())
    for _, (path, _) in sorted(spheres.panda_chain().meshes.items()):
        h.update(Path(path).read_bytes())
    return h.hexdigest()


if __name__ == "__main__":  # python -m pipeline.sim.wrist: compute and store the table
    from pipeline.sim import panda as P
    from pipeline.sim.world import connect

    client = connect()
    arm = P.Panda(client, (0.0, 0.0, 0.0))
    table = wrist_table(arm.ignored_pairs, P.LOWER[5], P.UPPER[5], P.LOWER[6], P.UPPER[6])
    table.fill()
    print(f"{table.save()}: {table.state.size} cells, {np.mean(table.state == 1):.1%} free")
