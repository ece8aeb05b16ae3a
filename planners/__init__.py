"""Collision-checked exploratory-motion planners (issue 4; not built yet)."""
