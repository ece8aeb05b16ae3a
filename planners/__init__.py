"""Collision-checked exploratory-motion planners.

``collision.CollisionChecker`` answers whether an arm configuration, a single-joint sweep or a
straight joint-space segment is free in a MuJoCo scene (fcl geometry, MuJoCo kinematics).
"""

import arc_env  # noqa: F401  (chooses MuJoCo's offscreen GL backend before mujoco is first imported)
from planners.collision import CollisionChecker

__all__ = ["CollisionChecker"]
