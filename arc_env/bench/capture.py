"""What a benchmark episode's calibrator was given, captured once and replayed through the solver alone.

Rendering a realistic 1080p episode takes minutes per motion; the solver's part of it takes seconds. A capture keeps
every ``Calibrator.add_motion`` call's arguments of a benchmark episode (``arc_env.bench.episodes``' scenes, camera
poses and planners) -- the tracks, and the outline stage's frames as grey images (PNG), so that the edges too are
found again by the code as it is now -- with the camera, the calibrator's settings, the robot and the true pose.
``replay`` feeds them to a fresh ``Calibrator`` (with the robot's outlines rendered from its model, as ``calibrate``
does) and returns the state after each motion; ``rescore`` turns that into the episode's record as the solver of
this checkout would have written it. So a change of the solver is measured on the same frames in a minute per
episode instead of ten. ``capture_episode`` runs one episode for its capture; ``bench_episode.py --keep-captures``
keeps one beside every record it stores. Captures are pickles: load only those you made.
"""

from __future__ import annotations

import copy
import pickle
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from arc_env.bench.episodes import (
    EpisodeSpec,
    EpisodeStore,
    bench_calibrator_config,
    capturable,
    code_version,
    fresh_solver_fields,
    note_calibrator,
    note_state,
    run_arc_episode,
    run_episode,
)
from arc_env.robot.contours import RobotContours
from arc_env.robot.exports import write_files_atomic
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.session import motion_outline_images, outline_image
from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics
from solver.outline_fusion import OutlineImage
from solver.pipeline import CalibrationState, Calibrator, CalibratorConfig

__all__ = ["CallRecorder", "Capture", "CapturedOutline", "capture_episode", "episode_task", "load_capture", "replay",
           "rescore", "run_and_capture", "save_capture", "stored_capture"]


@dataclass(frozen=True)
class CapturedOutline:
    """An outline-stage image as captured: the grey frame, its edges found again on replay (``image``).

    Attributes:
        png: the grey frame (H, W) uint8, PNG-encoded (lossless).
        q: (n,) rad, the arm's configuration in it.
        group: the ``OutlineImage.group`` it was given.
    """

    png: bytes
    q: FloatArray
    group: int

    @classmethod
    def of(cls, grey: ImageArray, image: OutlineImage) -> CapturedOutline:
        """The capture of ``image``, made from the grey frame (H, W) uint8 ``grey``."""
        ok, buffer = cv2.imencode(".png", np.ascontiguousarray(grey))
        if not ok:
            raise InvalidInputError("a grey frame could not be PNG-encoded for the capture")
        return cls(buffer.tobytes(), np.array(image.q, dtype=np.float64), int(image.group))

    def grey(self) -> ImageArray:
        """The grey frame (H, W) uint8."""
        grey = cv2.imdecode(np.frombuffer(self.png, np.uint8), cv2.IMREAD_GRAYSCALE)
        if grey is None:
            raise InvalidInputError("a captured outline frame does not decode")
        return grey

    def image(self, first: ImageArray | None = None) -> OutlineImage:
        """The outline stage's image of the frame, its edges found by the code as it is now.

        ``first``: as ``arc_env.robot.session.outline_image``'s, its motion's first frame when this is not that one.
        """
        return outline_image(self.grey(), self.q, self.group, first)


@dataclass(frozen=True)
class Capture:
    """A benchmark episode's calibrator inputs.

    Attributes:
        spec: the episode.
        calls: per accepted motion, ``Calibrator.add_motion``'s (observation, update, outline images); the
            images are ``CapturedOutline`` (``OutlineImage`` in captures made before the grey frames were kept).
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


class CallRecorder:
    """Keeps what a running benchmark env's calibrator is given, for a ``Capture``.

    Wraps the env's ``session.outline_images`` (to keep each outline image's grey frame) and its calibrator's
    ``add_motion`` (to keep the call and the estimate after it). Attach after the env's last ``reset``.

    Args:
        env: the benchmark's ``ArcCalibEnv`` (``arc_env.bench.episodes.make_env``).
    """

    def __init__(self, env: Any) -> None:
        session = env.session
        self._env = env
        self._calls: list[tuple[Any, bool, tuple[Any, ...]]] = []
        self._estimates: list[FloatArray | None] = []
        self._greys: dict[int, tuple[OutlineImage, CapturedOutline]] = {}
        calibrator = session.calibrator
        add_motion = calibrator.add_motion

        def images_spy(q_start: FloatArray, joint: int, deltas: FloatArray, frames: Any) -> list[OutlineImage]:
            greys = session.outline_greys(q_start, joint, deltas, frames)
            images = motion_outline_images(greys)
            for (grey, _), image in zip(greys, images, strict=True):
                self._greys[id(image)] = (image, CapturedOutline.of(grey, image))
            return images

        def add_motion_spy(observation: Any, update: bool = True, outlines: Any = ()) -> Any:
            kept = []
            for image in outlines:
                held = self._greys.pop(id(image), None)
                kept.append(held[1] if held is not None and held[0] is image else image)
            self._calls.append((observation, update, tuple(kept)))
            report = add_motion(observation, update, outlines)
            T = calibrator.state.T_camera_base
            self._estimates.append(None if T is None else np.array(T, dtype=np.float64))
            return report

        session.outline_images = images_spy
        calibrator.add_motion = add_motion_spy

    def capture(self, spec: EpisodeSpec) -> Capture:
        """What has been kept so far, as ``spec``'s capture."""
        session = self._env.session
        return Capture(spec, tuple(self._calls), session.intrinsics, session.calibrator.config, session.robot.source,
                       np.asarray(self._env.T_camera_base_true, dtype=np.float64).copy(), spec.outline_frames,
                       tuple(self._estimates))


def run_and_capture(spec: EpisodeSpec) -> tuple[dict[str, Any], Capture]:
    """Run ``spec``'s episode (random or informed planner, as the benchmark): its record and its calibrator's inputs."""
    if not capturable(spec):
        raise InvalidInputError(f"a capture needs a tracked random or informed episode, got {spec}")
    kept: list[Capture] = []

    def watch(env: Any) -> Any:
        recorder = CallRecorder(env)
        return lambda: kept.append(recorder.capture(spec))

    record = run_arc_episode(spec, watch)
    return record, kept[0]


def capture_episode(spec: EpisodeSpec) -> Capture:
    """Run ``spec``'s episode (random or informed planner, as the benchmark) and keep its calibrator's inputs."""
    return run_and_capture(spec)[1]


def stored_capture(source: EpisodeStore, spec: EpisodeSpec) -> tuple[dict[str, Any], Path] | None:
    """``spec``'s record in ``source`` and the path of its capture there, or None unless it has both."""
    record, path = source.get(spec), source.capture_path(spec)
    return (record, path) if record is not None and path.is_file() else None


def episode_task(spec: EpisodeSpec, capture_root: Path | None = None,
                 replay_from: Path | None = None) -> dict[str, Any]:
    """One study episode's record (``arc_env.bench.episodes.run_episodes``' task): replayed when it can be, else run.

    When the store at ``replay_from`` has both ``spec``'s record and its capture, the capture is replayed through
    the solver of this checkout (``rescore``). Otherwise the episode is run, and with ``capture_root`` (a store's
    directory) a tracked ARC-Calib episode's capture is written there (``EpisodeStore.capture_path``).
    """
    stored = stored_capture(EpisodeStore(replay_from), spec) if replay_from is not None else None
    if stored is not None:
        return rescore(stored[0], load_capture(stored[1]))
    if capture_root is None or not capturable(spec):
        return run_episode(spec)
    record, capture = run_and_capture(spec)
    path = EpisodeStore(capture_root).capture_path(spec)
    path.parent.mkdir(parents=True, exist_ok=True)
    save_capture(capture, path)
    return record


def _calibrator(capture: Capture, config: CalibratorConfig | None) -> Calibrator:
    robot = RobotModel.load(capture.robot)
    contours = RobotContours(robot, capture.intrinsics) if capture.outline_frames else None
    return Calibrator(capture.intrinsics, robot.axis_and_point, config or capture.config, contours=contours)


def _outlines(outlines: tuple[Any, ...]) -> list[OutlineImage]:
    """A captured call's outline images as the session makes them now (the second on with the first frame)."""
    first = outlines[0].grey() if outlines and isinstance(outlines[0], CapturedOutline) else None
    return [o.image(first if i else None) if isinstance(o, CapturedOutline) else o for i, o in enumerate(outlines)]


def replay(capture: Capture, config: CalibratorConfig | None = None) -> list[CalibrationState]:
    """The states of a fresh ``Calibrator`` (``config``, default the captured one) fed the captured calls in turn."""
    calibrator = _calibrator(capture, config)
    states = []
    for observation, update, outlines in capture.calls:
        calibrator.add_motion(observation, update, _outlines(outlines))
        states.append(calibrator.state)
    return states


def rescore(record: dict[str, Any], capture: Capture) -> dict[str, Any]:
    """``record``, an episode's stored record, as the solver of this checkout would have written it from ``capture``.

    The captured calls are replayed through a fresh calibrator with the benchmark's settings of today
    (``bench_calibrator_config``) and the solver's fields (``arc_env.bench.episodes.note_state`` and
    ``note_calibrator``) are computed again from its states; the
    tracks, frames, planning and rendering are the episode's (its frames are not rendered again, its motions are
    the ones it made). ``commit`` becomes this checkout's, ``seconds`` gets the replay's solver and report time,
    and ``replayed_from`` keeps the original's ``commit`` and ``seconds``.

    Raises:
        InvalidInputError: the capture is of another episode, or holds a different number of motions than the
            record (an episode whose motions did not all reach the calibrator).
    """
    spec = EpisodeSpec(**record["spec"])
    if capture.spec != spec:
        raise InvalidInputError(f"the capture is of {capture.spec.key}, the record of {spec.key}")
    if len(capture.calls) != len(record["curve"]):
        raise InvalidInputError(f"{spec.key}: the capture holds {len(capture.calls)} motions, the record "
                                f"{len(record['curve'])}")
    out = {**copy.deepcopy(record), **fresh_solver_fields()}
    calibrator = _calibrator(capture, bench_calibrator_config())
    started = time.perf_counter()
    for observation, update, outlines in capture.calls:
        calibrator.add_motion(observation, update, _outlines(outlines))
        note_state(out, calibrator.state, capture.T_true)
    note_calibrator(out, calibrator)
    solver = time.perf_counter() - started
    original = dict(record.get("seconds", {}))
    seconds = dict(original)
    seconds["report"] = float(calibrator.report_seconds)
    seconds["solver"] = solver - seconds["report"]
    seconds["total"] = original.get("total", 0.0) - original.get("solver", 0.0) - original.get("report", 0.0) + solver
    out.update(commit=code_version(), seconds=seconds,
               replayed_from={"commit": record.get("commit", "unknown"), "seconds": original})
    return out


def save_capture(capture: Capture, path: Path) -> None:
    """Write a capture (a pickle) atomically."""
    write_files_atomic({Path(path): pickle.dumps(capture, protocol=pickle.HIGHEST_PROTOCOL)})


def load_capture(path: Path) -> Capture:
    """Read a capture written by ``save_capture`` (a pickle: only your own)."""
    try:
        with open(path, "rb") as f:
            capture = pickle.load(f)  # noqa: S301  (the project's own files)
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError) as exc:
        raise InvalidInputError(f"{path}: not a readable capture ({exc})") from exc
    if not isinstance(capture, Capture):
        raise InvalidInputError(f"{path}: not a capture")
    return capture
