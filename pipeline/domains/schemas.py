"""The schemas of ``conf/domain/*.yaml``: one dataclass per domain, checked by Hydra and
by :func:`pipeline.domains.load_domain`.  Plain data, so that registering the pipeline's
configs loads no domain (and no simulator)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class PlanarConfig:
    """Schema of ``conf/domain/planar.yaml``."""

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


@dataclass
class GraspArmConfig:
    """Schema of ``conf/domain/grasp_arm.yaml``."""

    name: str = "grasp_arm"
    obstacles_min: int = 0
    obstacles_max: int = 20
    obstacle_size: list[float] = field(default_factory=lambda: [0.03, 0.08])  # edge, metres
    obstacle_height: list[float] = field(default_factory=lambda: [0.05, 0.20])
    target_size: list[float] = field(default_factory=lambda: [0.04, 0.04, 0.12])
    pregrasp_offset: float = 0.10
    ik_restarts: int = 4


@dataclass
class GraspBaseConfig:
    """Schema of ``conf/domain/grasp_base.yaml``."""

    name: str = "grasp_base"
    obstacles: int = 20
    obstacle_size: list[float] = field(default_factory=lambda: [0.04, 0.10])  # edge, metres
    obstacle_height: list[float] = field(default_factory=lambda: [0.06, 0.25])
    target_size: list[float] = field(default_factory=lambda: [0.04, 0.04, 0.12])
    reach_radius: float = 0.855  # the Panda's reach: RAWPLANNER's base-pose disc, metres
    pregrasp_offset: float = 0.10
    ik_restarts: int = 10
    raw_base_samples: int = 40  # collision-free base poses RAWPLANNER tries before giving up


@dataclass
class PickPlaceConfig:
    """Schema of ``conf/domain/pick_place.yaml``."""

    name: str = "pick_place"
    obstacles: int = 28
    obstacle_size: list[float] = field(default_factory=lambda: [0.05, 0.12])  # edge, metres
    obstacle_height: list[float] = field(default_factory=lambda: [0.06, 0.25])
    rod_lengths: list[float] = field(default_factory=lambda: [0.5, 0.7, 0.9])
    door_width: float = 0.9
    reach_radius: float = 0.855  # the Panda's reach; RAWPLANNER's disc for k_b around the placement
    pregrasp_offset: float = 0.10
    ik_restarts: int = 10
    psi_scale: float = 0.5  # metres per radian of base rotation (path metric)
    arm_weight: float = 0.1  # metres per radian of arm motion (score)
    base_max_checks: int = 4000  # collision checks per base path, both legs together
    base_resolution: float = 0.04  # metres between checked base states
    raw_grasps: int = 81  # RAWPLANNER: grasps tried at most
    raw_placements: int = 6  # placements per grasp
    raw_base_samples: int = 6  # collision-free k_b per placement
    step_order: str = "paper"  # or "cheap_first" (pipeline.domains.pick_place.ORDERS)


#: domain name -> schema (the names of pipeline.domains.DOMAINS)
DOMAIN_SCHEMAS = {"planar": PlanarConfig, "grasp_arm": GraspArmConfig,
                  "grasp_base": GraspBaseConfig, "pick_place": PickPlaceConfig}
