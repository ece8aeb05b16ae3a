"""The planners' errors: finding no motion is not invalid input.

Both derive from ``solver.errors.ArcCalibError`` (every error raised on purpose does), not from
``InvalidInputError``: the command line exits 2 only for invalid input, and a planner that finds no
valid motion, or no collision-free transit, has been given nothing invalid.
"""

from __future__ import annotations

from solver.errors import ArcCalibError


class PlanningError(ArcCalibError):
    """No valid motion was found within the planner's budget (the message says how hard it looked)."""


class TransitError(PlanningError):
    """No collision-free transit was found (the message says why)."""


__all__ = ["PlanningError", "TransitError"]
