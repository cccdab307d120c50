"""``pick_place`` (paper §V-C): carry a long rod from one room into the next.

Two rooms side by side, split by a wall at x = 0 with a door of ``door_width`` in it.  The
mobile Panda (:mod:`pipeline.sim.mobile`) starts at the same pose in the first room, facing
a table with a rod (one of ``rod_lengths``) lying on it at a fixed pose.  Per instance,
``obstacles`` boxes lie at random, half on that table and half on the goal table in the
second room.

A constraint θ = (grasp g, placement o, pre-place base pose k_b, subgoal base pose k_sg).
The 81 grasps: 9 positions along the rod × 3 wrist rotations × 3 approach tilts about the
rod's axis.  While driving, the arm holds the rod along the heading at a fixed carry point
above the platform (the carry configuration depends on g only).  π(ω, θ), each step named
in a failed result's ``step``:

``carry``       IK for the carry configuration (cached per grasp and rod length)
``placement``   the rod at o on the goal table is collision-free
``base_pose``   k_sg and k_b are collision-free with the rod carried
``place_ik``    IK at k_b for putting the rod down at o, rod in hand
``pick_ik``     IK at the start for g's pre-grasp (10 cm back along the approach)
``pick_path``   arm path home → pre-grasp, base at the start
``place_path``  arm path carry → place at k_b, the rod collision-checked in the hand
``base_path``   base path start → k_sg → k_b in (x, y, ψ), arm in carry, rod checked

``step_order: paper`` (the default) runs them motion by motion as the paper's π does:
pick_ik, pick_path, carry, base_pose, base_path, placement, place_ik, place_path, so that a
θ whose placement is blocked is refuted only after the pick and the drive, the expensive
refutations the paper describes; ``cheap_first`` runs them in the order listed above
(same outcome, feasible or not, with far cheaper refutations).  Grasping,
lifting and stowing the rod in the carry configuration are not planned (the paper's π
plans the same three motions).  Score = -(base path length + ``arm_weight`` × arm path
lengths): base length in the metric sqrt(dx² + dy² + (``psi_scale`` · dψ)²), metres; arm
lengths in radians of joint space.  ψ does not wrap around (a turn from π to -π goes the
long way); base states are (x, y, psi_scale · ψ) so the planner's per-coordinate
resolution is metres everywhere.

RAWPLANNER follows the paper's six steps with backtracking: grasps without replacement
until one has a pick IK and a pick path (1-2); a collision-free placement on the goal table
(3); k_b from the disc of radius ``reach_radius`` around o, collision-free with the rod
carried (4); a base path start → k_b (5); the place IK and path (6).  A failure in 4-6
draws a new k_b, then a new placement, then a new grasp.  The extracted k_sg is where the base
path crosses x = -``SUBGOAL_GAP``, in front of the door.

Modules: :mod:`.world` (the world and θ as data), :mod:`.scene` (the pybullet scene),
:mod:`.steps` (π's typed steps and their orders), :mod:`.raw` (RAWPLANNER) and
:mod:`.domain` (the Domain).
"""

from pipeline.domains.pick_place.domain import PickPlaceDomain
from pipeline.domains.pick_place.steps import ORDERS, STEPS
from pipeline.domains.pick_place.world import GOAL_TABLE, Route, rod_grasps
from pipeline.domains.schemas import PickPlaceConfig

__all__ = ["GOAL_TABLE", "ORDERS", "STEPS", "PickPlaceConfig", "PickPlaceDomain", "Route",
           "rod_grasps"]
