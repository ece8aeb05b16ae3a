"""Offscreen rendering: the GL backend is chosen when a renderer is created, never at import.

As gymnasium's ``mujoco_rendering`` does, ``MUJOCO_GL`` is read when the first renderer is built: a value
the user set is honoured; otherwise EGL (Mesa's software EGL works on CPU-only machines) when its library
is present, else OSMesa. Nothing writes ``os.environ``, and importing MuJoCo for kinematics (the
real-robot side) never touches GL.

MuJoCo's Python package picks its GL context class once, when it is imported, from ``MUJOCO_GL``
(unset: GLFW, which needs a display). ``create_renderer`` therefore hands ``mujoco.Renderer`` the
context class of the backend chosen here (``mujoco.rendering.classic.gl_context.GLContext``, the one
hook ``mujoco.Renderer`` reads when it is built).
"""

from __future__ import annotations

import ctypes.util
import importlib
import os

import mujoco

from solver.errors import ArcCalibError

#: Backends ``create_renderer`` can use on Linux, with the MuJoCo module that provides each context.
_BACKENDS = {"egl": "mujoco.egl", "osmesa": "mujoco.osmesa", "glfw": "mujoco.glfw"}


class RenderingError(ArcCalibError):
    """No offscreen GL context could be created (the message says which backend and how to fix it)."""


def gl_backend() -> str:
    """The backend a renderer will use: the user's ``MUJOCO_GL``, else "egl" if libEGL exists, else "osmesa"."""
    chosen = os.environ.get("MUJOCO_GL", "").lower().strip()
    if chosen:
        return chosen
    if ctypes.util.find_library("EGL") is None and ctypes.util.find_library("OSMesa") is not None:
        return "osmesa"
    return "egl"


def create_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer`` (height x width px) on the backend ``gl_backend`` names.

    Raises:
        RenderingError: the backend is unknown here or its context cannot be created (no library,
            no display); the message names it and what to install.
    """
    backend = gl_backend()
    hint = "Install Mesa's EGL (apt libegl1) or OSMesa (libosmesa6) and set MUJOCO_GL to egl or osmesa."
    if backend not in _BACKENDS:
        raise RenderingError(f"offscreen rendering: MUJOCO_GL={backend!r} is not one of {sorted(_BACKENDS)}. {hint}")
    from mujoco.rendering.classic import gl_context

    try:
        context_class = importlib.import_module(_BACKENDS[backend]).GLContext
    except Exception as exc:  # ImportError, OSError from ctypes, PyOpenGL's own errors
        raise RenderingError(f"offscreen rendering failed with MUJOCO_GL={backend!r}: {exc}. {hint}") from exc
    gl_context.GLContext = context_class  # what mujoco.Renderer instantiates
    try:
        return mujoco.Renderer(model, height, width)
    except Exception as exc:
        raise RenderingError(f"offscreen rendering failed with MUJOCO_GL={backend!r}: {exc}. {hint}") from exc
