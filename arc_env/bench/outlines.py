"""The outline fit (``solver.outlines``) on rendered benchmark episodes, against the tracks' estimate.

Renders the first ``spec.motions`` motions of a benchmark episode (random planner, ``arc_env.bench.episodes``'
scenes and camera poses, the episode's tracker and calibrator), takes ``frames_per_motion`` evenly spaced frames
of each sweep, and fits the camera pose to the robot's outlines in them, starting from the calibrator's estimate
after the last motion. The model's contours come from a second scene holding the robot as shipped (its model's
own materials; none of the realistic appearance's labels and cables, which a user's model file does not have
either), rendered at the pose being tried (``Scene.depth`` and ``Scene.robot_mask``).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace
from typing import Any

import cv2
import numpy as np

from arc_env.bench.episodes import EpisodeSpec, make_env
from arc_env.bench.tracking_truth import rendered_motions
from arc_env.sim.imaging import CameraEffects
from arc_env.sim.scene import Scene
from solver.arrays import FloatArray
from solver.errors import ArcCalibError
from solver.frames import pose_difference
from solver.outlines import (
    ContourModel,
    ContourPoints,
    OutlineConfig,
    contour_from_depth,
    fit_outline_pose,
    image_edges,
)


@dataclass(frozen=True)
class OutlineRun:
    """One episode's outline fit.

    Attributes:
        spec: the episode.
        motions: motions rendered.
        frames: images the fit used.
        start_error: (rad, m) the calibrator's estimate after the last motion against the truth; None without one.
        outline_error: (rad, m) the outline fit's; None when it did not run (``note`` says why).
        outline_depth_error_m: the fit's translation error along the optical axis (true minus fitted), metres.
        n_pairs: contour points paired with an image edge at the fit's last solve.
        median_abs_px: their median distance to their edges, pixels.
        seconds_episode: rendering, tracking and calibrating the motions, s.
        seconds_fit: the outline fit, s.
        note: why the fit did not run, or "".
    """

    spec: EpisodeSpec
    motions: int
    frames: int
    start_error: tuple[float, float] | None
    outline_error: tuple[float, float] | None
    outline_depth_error_m: float | None
    n_pairs: int
    median_abs_px: float | None
    seconds_episode: float
    seconds_fit: float
    note: str


def sim_contour_model(scene: Scene, views: list[tuple[FloatArray, int, float]], K: FloatArray,
                      stride: int) -> ContourModel:
    """The robot's contours in each view (q (n,) rad, joint, delta rad), rendered by ``scene`` at a camera pose."""

    def model(T_camera_base: FloatArray) -> list[ContourPoints]:
        contours = []
        for q, joint, delta in views:
            scene.robot.set_swept(q, joint, delta)
            contours.append(contour_from_depth(scene.depth(T_camera_base), scene.robot_mask(T_camera_base),
                                               T_camera_base, K, stride=stride))
        return contours

    return model


def run_outline_episode(spec: EpisodeSpec, frames_per_motion: int = 3, stride: int = 3,
                        config: OutlineConfig | None = None) -> OutlineRun:
    """Render ``spec``'s first motions and fit the pose to the robot's outlines from the calibrator's estimate."""
    t0 = time.perf_counter()
    env, obs = make_env(spec)
    try:
        seen = rendered_motions(env, obs, spec)
        seconds_episode = time.perf_counter() - t0
        T_true = env.T_camera_base_true.copy()
        intrinsics = env.session.intrinsics
        empty = OutlineRun(spec, len(seen), 0, None, None, None, 0, None, seconds_episode, 0.0, "")
        if not seen:
            return replace(empty, note="no motion was made")
        state = seen[-1].calibrator.state
        if state.T_camera_base is None:
            return replace(empty, note=f"no estimate after {len(seen)} motions to start from")
        if intrinsics.has_distortion:
            return replace(empty, note="the rendered contours are pinhole; this camera has distortion")
        start = pose_difference(state.T_camera_base, T_true)
        views, edges = [], []
        for motion in seen:
            if motion.frames is None:  # rendered_motions keeps the rendered ones only
                continue
            n = len(motion.frames)
            for k in sorted({int(i) for i in np.linspace(0, n - 1, frames_per_motion).round()}):
                views.append((motion.q_start, motion.joint, float(motion.deltas[k])))
                edges.append(image_edges(cv2.cvtColor(np.asarray(motion.frames[k]), cv2.COLOR_RGB2GRAY)))
        model_scene = Scene(replace(env.scene.config, appearance="as_shipped", effects=CameraEffects(),
                                    shadows=False))
        try:
            t1 = time.perf_counter()
            start_error = (float(np.linalg.norm(start[:3])), float(np.linalg.norm(start[3:])))
            try:
                fit = fit_outline_pose(state.T_camera_base, edges,
                                       sim_contour_model(model_scene, views, intrinsics.K, stride), intrinsics, config)
            except ArcCalibError as e:
                return replace(empty, frames=len(edges), start_error=start_error, seconds_fit=time.perf_counter() - t1,
                               note=f"{type(e).__name__}: {e}")
            seconds_fit = time.perf_counter() - t1
        finally:
            model_scene.close()
        err = pose_difference(fit.T_camera_base, T_true)
        return OutlineRun(spec, len(seen), len(edges), start_error,
                          (float(np.linalg.norm(err[:3])), float(np.linalg.norm(err[3:]))), float(err[5]),
                          fit.n_pairs, fit.median_abs_px, seconds_episode, seconds_fit, "")
    finally:
        env.close()


def run_record(run: OutlineRun) -> dict[str, Any]:
    """``run`` as JSON-ready values (the spec as its fields)."""
    return {**asdict(run), "spec": asdict(run.spec)}
