"""Session-wide set-up: MuJoCo's offscreen GL backend is chosen before any test module imports mujoco."""

import arc_env  # noqa: F401  (sets MUJOCO_GL; mujoco reads it at import)
