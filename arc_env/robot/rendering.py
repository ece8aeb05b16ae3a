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
import functools
import importlib
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
from numpy.typing import NDArray

from solver.errors import ArcCalibError, InvalidInputError

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


#: A pixel window (u0, v0, u1, v1) of an image: columns u0 <= u < u1, rows v0 <= v < v1 (row 0 at the top).
Window = tuple[int, int, int, int]


def render_geoms_and_depth(renderer: mujoco.Renderer, window: Window | None = None
                           ) -> tuple[NDArray[np.int32], NDArray[np.float64]]:
    """The geom id and the depth of every pixel of the renderer's scene (or of a window of it), from one render.

    ``mujoco.Renderer`` renders the scene once for its segmentation image and again for its depth image, in the
    same mode (segmentation colours: its depth rendering uses them for precision); here one render is read out for
    both, with the conversions ``mujoco.Renderer.render`` makes. The scene must be up to date (``update_scene``)
    and its camera a perspective one. It reads the renderer's own context (``_mjr_context``, ``_rect``,
    ``_gl_context``): where a MuJoCo release names them otherwise, the two renders of the public path are made.

    Args:
        renderer: the renderer, its scene updated.
        window: read out and convert only these pixels (the whole scene is rendered either way); None: all.

    Returns:
        (h, w) int32 geom id (-1 where no geom is drawn, or a drawn object is not a geom), and (h, w) float64 depth
        along the optical axis, metres (the far clipping distance where nothing is drawn); (h, w) is the window's
        size, or the renderer's (H, W).
    """
    u0, v0, u1, v1 = (0, 0, renderer.width, renderer.height) if window is None else window
    if not (0 <= u0 < u1 <= renderer.width and 0 <= v0 < v1 <= renderer.height):
        raise InvalidInputError(f"window {window} is not a non-empty part of a {renderer.width}x{renderer.height} "
                                "image")
    context, rect = getattr(renderer, "_mjr_context", None), getattr(renderer, "_rect", None)
    scene = renderer.scene
    if context is None or rect is None or not hasattr(renderer, "_gl_context") or scene.camera[0].orthographic:
        geoms, depth = _geoms_and_depth_two_renders(renderer)
        return np.ascontiguousarray(geoms[v0:v1, u0:u1]), np.ascontiguousarray(depth[v0:v1, u0:u1])
    flags = scene.flags.copy()
    try:
        scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = True
        scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = True
        if renderer._gl_context:
            renderer._gl_context.make_current()
        rgb = np.empty((v1 - v0, u1 - u0, 3), np.uint8)
        raw = np.empty((v1 - v0, u1 - u0), np.float32)
        mujoco.mjr_render(rect, scene, context)
        # GL's rows count from the bottom (the contexts here read the bottom row first: flipped below)
        bottom = renderer.height - v1 if renderer._gl_context else v0
        mujoco.mjr_readPixels(rgb, raw, mujoco.MjrRect(u0, bottom, u1 - u0, v1 - v0), context)
    finally:
        np.copyto(scene.flags, flags)
    # segmentation colours: segid + 1 in the 24 bits of (r, g, b), 0 where nothing is drawn
    segid = rgb[..., 0].astype(np.int32) | (rgb[..., 1].astype(np.int32) << 8) | (rgb[..., 2].astype(np.int32) << 16)
    geom_of = np.full(scene.ngeom + 2, -1, np.int32)
    for g in scene.geoms[:scene.ngeom]:
        if g.segid != -1 and g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
            geom_of[g.segid + 1] = g.objid
    geoms = geom_of[np.minimum(segid, scene.ngeom + 1)]
    depth = _metric_depth(raw, renderer.model)
    if renderer._gl_context:  # EGL, OSMesa and GLFW read the image bottom row first
        geoms, depth = geoms[::-1], depth[::-1]
    return np.ascontiguousarray(geoms), np.ascontiguousarray(depth)


def _metric_depth(raw: NDArray[np.float32], model: mujoco.MjModel) -> NDArray[np.float64]:
    """Metres along the optical axis from a reversed-z depth buffer of a perspective camera, as ``mujoco.Renderer``.

    The same float32 constants as ``mujoco.Renderer.render`` (close to glFrustum's), so that both agree.
    """
    extent = model.stat.extent
    zfar, znear = np.float32(model.vis.map.zfar * extent), np.float32(model.vis.map.znear * extent)
    c = np.float32(-0.5) * (-(zfar + znear) / (zfar - znear)) - np.float32(0.5)
    d = np.float32(-0.5) * (-(np.float32(2) * zfar * znear) / (zfar - znear))
    return (d / (raw.astype(np.float64) + c)).astype(np.float32).astype(np.float64)


def _geoms_and_depth_two_renders(renderer: mujoco.Renderer) -> tuple[NDArray[np.int32], NDArray[np.float64]]:
    renderer.enable_segmentation_rendering()
    try:
        seg = renderer.render()
    finally:
        renderer.disable_segmentation_rendering()
    renderer.enable_depth_rendering()
    try:
        depth = renderer.render().astype(np.float64)
    finally:
        renderer.disable_depth_rendering()
    geoms = np.where((seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (seg[..., 0] >= 0), seg[..., 0], -1)
    return geoms.astype(np.int32), depth


#: What ``offscreen_gl_problem``'s child process runs: a renderer of an empty model, built and closed.
_PROBE = ("import mujoco\nfrom arc_env.robot.rendering import create_renderer\n"
          "create_renderer(mujoco.MjModel.from_xml_string('<mujoco/>'), 8, 8).close()\nprint('ok')")


@functools.cache
def offscreen_gl_problem(timeout_s: float = 120.0) -> str:
    """Why no offscreen GL context can be made here, or "" when one can (asked once per process).

    Tried in a child process with this one's environment, because a backend that cannot start may end the process
    that tries it (seen: GLFW without a display aborted it) rather than raise ``RenderingError``.
    """
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=timeout_s,
                             cwd=Path(__file__).resolve().parents[2])
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"offscreen rendering could not be tried ({type(exc).__name__}: {exc})"
    if out.returncode == 0 and out.stdout.strip().endswith("ok"):
        return ""
    lines = [line.strip() for line in (out.stderr + out.stdout).splitlines() if line.strip()]
    prefix = f"{RenderingError.__module__}.{RenderingError.__name__}: "
    if lines and lines[-1].startswith(prefix):  # create_renderer's own message: the backend and what to install
        return lines[-1][len(prefix):]
    why = lines[-1] if lines else f"exit code {out.returncode}"
    return f"offscreen rendering failed with MUJOCO_GL={gl_backend()!r} ({why})"
