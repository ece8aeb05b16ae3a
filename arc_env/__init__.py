"""Gymnasium environment around a MuJoCo scene (issue 3; for now it holds the ``arc-calib`` command)."""
