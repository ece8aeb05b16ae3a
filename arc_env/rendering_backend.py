"""Choose MuJoCo's offscreen GL backend before MuJoCo is imported: EGL, else OSMesa.

MuJoCo reads ``MUJOCO_GL`` when it first creates a context. A value the user set is kept; otherwise
EGL (Mesa's software EGL works on CPU-only machines) when its library is present, else OSMesa.
"""

from __future__ import annotations

import ctypes.util
import os


def configure() -> str:
    """Set ``MUJOCO_GL`` if unset and return the backend in use ("egl", "osmesa" or the user's)."""
    if "MUJOCO_GL" not in os.environ:
        if ctypes.util.find_library("EGL") is None and ctypes.util.find_library("OSMesa") is not None:
            os.environ["MUJOCO_GL"] = "osmesa"
            os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
        else:
            os.environ["MUJOCO_GL"] = "egl"
    return os.environ["MUJOCO_GL"]
