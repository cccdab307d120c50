"""The slalom domain's config schema: its keys, defaults and checks.  Imported whenever the
pipeline registers its configs (every run), so it imports nothing but the standard
library; the domain itself lives in :mod:`box_example.slalom`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar


@dataclass
class SlalomConfig:
    """``domain=slalom``: a square robot crosses a ``size`` x ``size`` room from left to
    right through two walls, each with ``doors`` door places evenly spaced, each open with
    probability ``open_share`` (at least one per wall)."""

    domain_class: ClassVar[str] = "box_example.slalom:SlalomDomain"

    name: str = "slalom"
    size: float = 10.0  # the room is [0, size]²; the walls stand at size/3 and 2 size/3
    half_width: float = 0.25  # the robot is a square of side 2 half_width
    wall_thickness: float = 0.3
    door_width: float = 1.5
    doors: int = 3  # door places per wall
    open_share: float = 0.5
    pillars_max: int = 6  # pillars (square obstacles) per instance: 0 to this many
    pillar_size: float = 0.8  # a pillar's side
    raw_max_tries: int = 40  # door-height pairs RAWPLANNER draws before giving up

    def __post_init__(self):
        if not (self.size > 0 and 0 < self.half_width < self.size / 8):
            raise ValueError("domain: need size > 0 and 0 < half_width < size / 8")
        if self.doors < 1 or not 0 <= self.open_share <= 1:
            raise ValueError("domain: need doors >= 1 and 0 <= open_share <= 1")
        if not 2 * self.half_width < self.door_width < self.size / (self.doors + 1):
            raise ValueError("domain.door_width must lie between the robot's width "
                             f"({2 * self.half_width:g}) and size / (doors + 1)")
        if not (0 < self.wall_thickness < self.size / 6 and 0 < self.pillar_size):
            raise ValueError("domain: need 0 < wall_thickness < size / 6 and pillar_size > 0")
        if self.pillars_max < 0 or self.raw_max_tries < 1:
            raise ValueError("domain: need pillars_max >= 0 and raw_max_tries >= 1")
