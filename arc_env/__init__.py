"""The simulated side of ARC-Calib: a MuJoCo scene, rendering, tracking and the Gymnasium env.

Importing ``arc_env`` chooses MuJoCo's offscreen GL backend (``MUJOCO_GL``: EGL, else OSMesa)
unless the user already set it, so it must come before the first ``import mujoco``.
"""

from arc_env import rendering_backend

rendering_backend.configure()

import gymnasium  # noqa: E402

gymnasium.register(id="ArcCalib-v0", entry_point="arc_env.env:ArcCalibEnv")
