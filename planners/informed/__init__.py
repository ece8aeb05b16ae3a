"""The informed planner (ours): ``InformedPlanner`` and its settings; the parts are its submodules."""

from planners.informed.config import InformedPlannerConfig
from planners.informed.information import ScoredMotion
from planners.informed.planner import InformedPlanner

__all__ = ["InformedPlanner", "InformedPlannerConfig", "ScoredMotion"]
