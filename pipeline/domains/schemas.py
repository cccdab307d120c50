"""The schemas of ``conf/domain/*.yaml``: one dataclass per domain, checked by Hydra and
by :func:`pipeline.domains.load_domain`.  Plain data, so that registering the pipeline's
configs loads no domain (and no simulator).  Each schema checks its values when it is
built (``__post_init__``, ValueError naming the key), so the up-front validation refuses
a bad value before anything is written.

A schema is where its domain is declared: ``pipeline.domains.DOMAINS`` (and a plug-in's
entry point) names the schema, and the schema's ``domain_class`` names the Domain subclass
("module:Class"), imported only when the domain is used."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar


@dataclass
class PlanarConfig:
    """Schema of ``conf/domain/planar.yaml``."""

    domain_class: ClassVar[str] = "pipeline.domains.planar:PlanarDomain"
    name: str = "planar"
    size: float = 10.0  # the room is [0, size]²
    robot_radius: float = 0.25
    start: list[float] = field(default_factory=lambda: [1.0, 5.0])
    goal: list[float] = field(default_factory=lambda: [9.0, 5.0])
    obstacles_min: int = 4
    obstacles_max: int = 12
    obstacle_size_min: float = 0.5
    obstacle_size_max: float = 3.0
    raw_max_tries: int = 50  # via-points RAWPLANNER draws before giving up

    def __post_init__(self):
        if not (self.size > 0 and 0 < self.robot_radius < self.size / 4):
            raise ValueError("domain: need size > 0 and 0 < robot_radius < size / 4")
        _obstacle_range(self.obstacles_min, self.obstacles_max)
        if not 0 < self.obstacle_size_min <= self.obstacle_size_max:
            raise ValueError("domain: need 0 < obstacle_size_min <= obstacle_size_max")
        if self.raw_max_tries < 1:
            raise ValueError("domain.raw_max_tries must be >= 1")
        lower, upper = self.robot_radius, self.size - self.robot_radius
        for key in ("start", "goal"):
            q = getattr(self, key)
            if len(q) != 2 or not all(lower <= v <= upper for v in q):
                raise ValueError(f"domain.{key} must be 2 numbers inside the room")


@dataclass
class GraspArmConfig:
    """Schema of ``conf/domain/grasp_arm.yaml``."""

    domain_class: ClassVar[str] = "pipeline.domains.grasp_arm:GraspArmDomain"
    name: str = "grasp_arm"
    obstacles_min: int = 0
    obstacles_max: int = 20
    obstacle_size: list[float] = field(default_factory=lambda: [0.03, 0.08])  # edge, metres
    obstacle_height: list[float] = field(default_factory=lambda: [0.05, 0.20])
    target_size: list[float] = field(default_factory=lambda: [0.04, 0.04, 0.12])
    pregrasp_offset: float = 0.10
    ik_restarts: int = 4  # damped: IK runs; analytic: solutions collision-checked; at most
    ik: str = "damped"  # or "analytic": frankik's closed-form IK (pipeline.sim.analytic_ik)
    contacts: str = "fresh"  # or "cached": stores made before 2026-11-27 (docs/contacts.md)

    def __post_init__(self):
        _obstacle_range(self.obstacles_min, self.obstacles_max)
        _sizes(self)
        if self.ik_restarts < 1 or self.pregrasp_offset < 0:
            raise ValueError("domain: need ik_restarts >= 1 and pregrasp_offset >= 0")
        _ik(self.ik)
        _contacts(self.contacts)


@dataclass
class GraspBaseConfig:
    """Schema of ``conf/domain/grasp_base.yaml``."""

    domain_class: ClassVar[str] = "pipeline.domains.grasp_base:GraspBaseDomain"
    name: str = "grasp_base"
    obstacles: int = 20
    obstacle_size: list[float] = field(default_factory=lambda: [0.04, 0.10])  # edge, metres
    obstacle_height: list[float] = field(default_factory=lambda: [0.06, 0.25])
    target_size: list[float] = field(default_factory=lambda: [0.04, 0.04, 0.12])
    reach_radius: float = 0.855  # the Panda's reach: RAWPLANNER's base-pose disc, metres
    pregrasp_offset: float = 0.10
    ik_restarts: int = 10  # damped: IK runs; analytic: solutions collision-checked; at most
    ik: str = "damped"  # or "analytic": frankik's closed-form IK (pipeline.sim.analytic_ik)
    contacts: str = "fresh"  # or "cached": stores made before 2026-11-27 (docs/contacts.md)
    raw_base_samples: int = 40  # collision-free base poses RAWPLANNER tries before giving up

    def __post_init__(self):
        _mobile(self)
        if not self.reach_radius > 0 or self.raw_base_samples < 1:
            raise ValueError("domain: need reach_radius > 0 and raw_base_samples >= 1")


@dataclass
class PickPlaceConfig:
    """Schema of ``conf/domain/pick_place.yaml``."""

    domain_class: ClassVar[str] = "pipeline.domains.pick_place:PickPlaceDomain"
    name: str = "pick_place"
    obstacles: int = 28
    obstacle_size: list[float] = field(default_factory=lambda: [0.05, 0.12])  # edge, metres
    obstacle_height: list[float] = field(default_factory=lambda: [0.06, 0.25])
    rod_lengths: list[float] = field(default_factory=lambda: [0.5, 0.7, 0.9])
    door_width: float = 0.9
    reach_radius: float = 0.855  # the Panda's reach; RAWPLANNER's disc for k_b around the placement
    pregrasp_offset: float = 0.10
    ik_restarts: int = 10  # damped: IK runs; analytic: solutions collision-checked; at most
    ik: str = "damped"  # or "analytic": frankik's closed-form IK (pipeline.sim.analytic_ik)
    contacts: str = "fresh"  # or "cached": stores made before 2026-11-27 (docs/contacts.md)
    psi_scale: float = 0.5  # metres per radian of base rotation (path metric)
    arm_weight: float = 0.1  # metres per radian of arm motion (score)
    base_max_checks: int = 4000  # collision checks per base path, both legs together
    base_resolution: float = 0.04  # metres between checked base states
    raw_grasps: int = 81  # RAWPLANNER: grasps tried at most
    raw_placements: int = 6  # placements per grasp
    raw_base_samples: int = 6  # collision-free k_b per placement
    step_order: str = "paper"  # or "cheap_first" (pipeline.domains.pick_place.ORDERS)

    def __post_init__(self):
        _mobile(self)
        if not self.rod_lengths or any(not 0.1 <= v <= 1.2 for v in self.rod_lengths):
            raise ValueError("domain.rod_lengths: need one or more lengths in [0.1, 1.2] m")
        if not 0.6 <= self.door_width <= PICK_PLACE_DOOR_MAX:
            raise ValueError(f"domain.door_width must be in [0.6, {PICK_PLACE_DOOR_MAX:g}] m "
                             "(the platform is 0.5 m wide)")
        if not (self.reach_radius > 0 and self.psi_scale > 0 and self.arm_weight >= 0
                and self.base_max_checks >= 1 and self.base_resolution > 0):
            raise ValueError("domain: need reach_radius, psi_scale, base_resolution > 0, "
                             "arm_weight >= 0 and base_max_checks >= 1")
        if self.step_order not in PICK_PLACE_ORDERS:
            raise ValueError(f"domain.step_order must be one of {', '.join(PICK_PLACE_ORDERS)}"
                             f", got {self.step_order!r}")
        if min(self.raw_grasps, self.raw_placements, self.raw_base_samples) < 1:
            raise ValueError("domain.raw_*: need at least 1 of each")


#: the values of ``domain.ik`` in the arm domains (pipeline.domains.ik.solve_ik): pybullet's
#: damped IK from seeded restarts, or frankik's closed-form solutions
IK_METHODS = ("damped", "analytic")

#: the values of ``domain.contacts`` in the Panda domains: pybullet's contact points as it
#: caches them between checks (the answers of every store made before the setting), or
#: every cached penetration confirmed afresh, a function of the poses alone
#: (pipeline.sim.contacts, docs/contacts.md)
CONTACTS = ("cached", "fresh")

#: pick_place's step orders (the keys of pipeline.domains.pick_place.plan_steps.ORDERS) and
#: its widest door (the wall between the rooms less the platform's margins), metres
PICK_PLACE_ORDERS = ("paper", "cheap_first")
PICK_PLACE_DOOR_MAX = 3.0


def _obstacle_range(low: int, high: int) -> None:
    if not 0 <= low <= high:
        raise ValueError(f"domain: need 0 <= obstacles_min <= obstacles_max, got {low} and "
                         f"{high}")


def _sizes(c) -> None:
    """``obstacle_size`` and ``obstacle_height``: [min, max] with 0 < min <= max."""
    for key in ("obstacle_size", "obstacle_height"):
        pair = getattr(c, key)
        if len(pair) != 2 or not 0 < pair[0] <= pair[1]:
            raise ValueError(f"domain.{key} must be [min, max] with 0 < min <= max")


def _mobile(c) -> None:
    """The settings both mobile domains share."""
    _sizes(c)
    if c.obstacles < 0 or c.ik_restarts < 1 or c.pregrasp_offset < 0:
        raise ValueError("domain: need obstacles >= 0, ik_restarts >= 1 and "
                         "pregrasp_offset >= 0")
    _ik(c.ik)
    _contacts(c.contacts)


def _contacts(value: str) -> None:
    if value not in CONTACTS:
        raise ValueError(f"domain.contacts must be one of {', '.join(CONTACTS)}, got "
                         f"{value!r}")


def _ik(method: str) -> None:
    """``domain.ik``: one of IK_METHODS; ``analytic`` needs the frankik package."""
    if method not in IK_METHODS:
        raise ValueError(f"domain.ik must be one of {', '.join(IK_METHODS)}, got {method!r}")
    if method == "analytic":
        import importlib.util

        if importlib.util.find_spec("frankik") is None:
            raise ValueError("domain.ik=analytic needs the frankik package (pip install "
                             "frankik)")

