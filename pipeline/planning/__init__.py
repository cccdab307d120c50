"""Motion planning (docs/architecture.md): results and statuses, the base every planner
and robot share (robot model, checks, budget), the planner interface, planning tries that
pause and resume (``resumable``), one module per planner (``rrt_connect``, ``ompl``,
``trajopt``, ``noop``; the OMPL ones share ``ompl_adapter``), their settings
(``settings``) and the registry.  Importing this package loads no planner (and so neither
OMPL nor scipy's optimisers)."""

from pipeline.planning.base import Budget, Robot, RobotModel, interpolate, path_is_free
from pipeline.planning.interface import Planner
from pipeline.planning.registry import PLANNERS, make_planner
from pipeline.planning.result import PlanResult, Status, path_length
from pipeline.planning.resumable import PlanningTry
from pipeline.planning.settings import PlannerSettings

__all__ = ["PLANNERS", "Budget", "PlanResult", "Planner", "PlannerSettings", "PlanningTry",
           "Robot", "RobotModel", "Status", "interpolate", "make_planner", "path_is_free",
           "path_length"]
