"""Collision-checked exploratory-motion planners.

``collision.CollisionChecker`` answers whether an arm configuration, a single-joint sweep or a
straight joint-space segment is free in a MuJoCo scene (fcl geometry, MuJoCo kinematics).
"""

from planners.collision import CollisionChecker

__all__ = ["CollisionChecker"]
