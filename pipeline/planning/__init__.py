"""Motion planning shared by every domain: results, statuses and the RRT-Connect planner."""

from pipeline.planning.result import PlanResult, Status
from pipeline.planning.rrt import PlannerSettings, RRTConnect, interpolate

__all__ = ["PlanResult", "PlannerSettings", "RRTConnect", "Status", "interpolate"]
