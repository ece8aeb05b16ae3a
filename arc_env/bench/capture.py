"""What a benchmark episode's calibrator was given, captured once and replayed through the solver alone.

Rendering a realistic 1080p episode takes minutes per motion; the solver's part of it takes seconds. ``capture_episode``
runs a benchmark episode (``arc_env.bench.episodes``' scenes, camera poses and random planner) and keeps every
``Calibrator.add_motion`` call's arguments, the camera, the calibrator's settings, the robot and the true pose;
``replay`` feeds them to a fresh ``Calibrator`` of the code as it is now (with the robot's outlines rendered from its
model, as ``calibrate`` does) and returns the state after each motion, so a change of the solver is measured on the
same tracks and images in a minute. Captures are pickles: load only those you made.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arc_env.bench.episodes import EpisodeSpec, episode_planner, make_env
from arc_env.robot.contours import RobotContours
from arc_env.robot.exports import write_files_atomic
from arc_env.robot.model import RobotModel, RobotSource
from solver.arrays import FloatArray
from solver.errors import ArcCalibError, InvalidInputError
from solver.observations import CameraIntrinsics
from solver.pipeline import CalibrationState, Calibrator, CalibratorConfig

__all__ = ["Capture", "capture_episode", "load_capture", "replay", "save_capture"]


@dataclass(frozen=True)
class Capture:
    """A benchmark episode's calibrator inputs.

    Attributes:
        spec: the episode.
        calls: per accepted motion, ``Calibrator.add_motion``'s (observation, update, outline images).
        intrinsics: the camera.
        config: the calibrator's settings.
        robot: the robot's model source.
        T_true: (4, 4) float64: the true T_camera_base.
        outline_frames: the session's outline images per motion (0: the calibrator had no contour renderer).
        estimates: per call, the episode's own T_camera_base (4, 4) after it, or None (what ``replay`` repeats
            while the solver is unchanged).
    """

    spec: EpisodeSpec
    calls: tuple[tuple[Any, bool, tuple[Any, ...]], ...]
    intrinsics: CameraIntrinsics
    config: CalibratorConfig
    robot: RobotSource
    T_true: FloatArray
    outline_frames: int
    estimates: tuple[FloatArray | None, ...]


def capture_episode(spec: EpisodeSpec) -> Capture:
    """Run ``spec``'s episode (random or informed planner, as the benchmark) and keep its calibrator's inputs."""
    if spec.method not in ("random", "informed") or spec.oracle:
        raise InvalidInputError(f"a capture needs a tracked random or informed episode, got {spec}")
    calls: list[tuple[Any, bool, tuple[Any, ...]]] = []
    estimates: list[FloatArray | None] = []
    env, obs = make_env(spec)
    try:
        calibrator = env.session.calibrator
        original = calibrator.add_motion

        def spy(observation: Any, update: bool = True, outlines: Any = ()) -> Any:
            calls.append((observation, update, tuple(outlines)))
            report = original(observation, update, outlines)
            T = calibrator.state.T_camera_base
            estimates.append(None if T is None else np.array(T, dtype=np.float64))
            return report

        calibrator.add_motion = spy  # type: ignore[method-assign]
        planner = episode_planner(env, spec)
        done = 0
        while done < spec.motions:
            try:
                action = planner.plan(obs)
            except ArcCalibError:
                break
            obs, _, _, truncated, info = env.step(action)
            if not info["refused"]:
                done += 1
            elif truncated:
                break
        return Capture(spec, tuple(calls), env.session.intrinsics, calibrator.config, env.session.robot.source,
                       np.asarray(env.T_camera_base_true, dtype=np.float64).copy(), spec.outline_frames,
                       tuple(estimates))
    finally:
        env.close()


def replay(capture: Capture, config: CalibratorConfig | None = None) -> list[CalibrationState]:
    """The states of a fresh ``Calibrator`` (``config``, default the captured one) fed the captured calls in turn."""
    robot = RobotModel.load(capture.robot)
    contours = RobotContours(robot, capture.intrinsics) if capture.outline_frames else None
    calibrator = Calibrator(capture.intrinsics, robot.axis_and_point, config or capture.config, contours=contours)
    states = []
    for observation, update, outlines in capture.calls:
        calibrator.add_motion(observation, update, outlines)
        states.append(calibrator.state)
    return states


def save_capture(capture: Capture, path: Path) -> None:
    """Write a capture (a pickle) atomically."""
    write_files_atomic({Path(path): pickle.dumps(capture)})


def load_capture(path: Path) -> Capture:
    """Read a capture written by ``save_capture`` (a pickle: only your own)."""
    with open(path, "rb") as f:
        capture = pickle.load(f)  # noqa: S301  (the project's own files)
    if not isinstance(capture, Capture):
        raise InvalidInputError(f"{path}: not a capture")
    return capture
