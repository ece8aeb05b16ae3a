"""Collision-checked exploratory-motion planners: random (the paper's) and informed (ours).

A planner reads a ``planners.context.PlanningContext`` (robot model, limits, collision checker, camera
intrinsics, calibration state, executed motions; never a true pose) and returns the next motion as
``{"Q", "J", "delta"}``. ``collision.CollisionChecker`` answers whether an arm configuration, a
single-joint sweep or a straight joint-space segment is free (fcl geometry, MuJoCo kinematics);
``transit`` plans the way to a start configuration (OMPL); ``ik`` places a link (mink).

Importing ``planners`` imports no ``arc_env`` module and sets no ``MUJOCO_GL``.
"""

from planners.collision import CollisionChecker
from planners.errors import PlanningError, TransitError

__all__ = ["CollisionChecker", "PlanningError", "TransitError"]
