"""The settings of ``planner=biased_rrt`` (:mod:`box_example.biased_rrt`): the class the
entry point names.  Imported whenever the pipeline registers its configs (it joins Hydra's
ConfigStore as the option ``planner/biased_rrt``, so its keys are checked up front), so it
imports no planning library."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pipeline.planning.settings import RRTConnectSettings


@dataclass
class BiasedRRTSettings(RRTConnectSettings):
    """The keys of rrt_connect (budget, resolution, range, shortcutting) and ``goal_bias``:
    the share of samples RRT draws at the goal."""

    planner_class: ClassVar[str] = "box_example.biased_rrt:BiasedRRT"

    name: str = "biased_rrt"
    goal_bias: float = 0.2

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 <= self.goal_bias <= 1.0:
            raise ValueError(f"planner.goal_bias must be in [0, 1], got {self.goal_bias}")
