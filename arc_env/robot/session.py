"""The one calibration loop: check -> transit -> execute -> track -> ``Calibrator.add_motion``.

Every way ARC-Calib calibrates runs through ``CalibrationSession``: the Gymnasium env (``arc_env.sim.env``,
the simulator executing motions), ``arc-calib run`` (a ``RobotDriver`` executing them, ``DriverExecutor``),
``arc-calib record`` (the env, in oracle mode) and ``arc-calib calibrate`` (``calibrate_recording``:
recorded motions need no check, transit or execution, only tracking and the calibrator).

A session is also what the planners read (``planners.context.PlanningContext``): the robot model, its
limits and collision checker, the camera's intrinsics, the calibrator and the executed motions, and
optionally a renderer. It holds no ground truth.

A recording's result is *usable* -- written, exit code 0 -- only when all of these hold:

* the bundle adjustment produced it (``stage == "refined"``): a pose and a covariance;
* at least ``min_motions`` motions inform it;
* every 1-sigma rotation component is at most ``max_std_deg`` and every translation one at most
  ``max_std_mm`` (the convergence monitor's thresholds are tighter, so a converged estimate qualifies).

Otherwise nothing is written: never a pose from too little evidence.

With ``SessionConfig.overlap`` the robot does not wait for the computer: ``step`` executes its motion on
the calling thread while one worker thread tracks the previous motion's frames and adds it to the
calibrator, and returns that previous motion's result (lagged by one; the first such step returns a
``pending`` result, ``flush`` processes the last motion). The calibrator still takes every motion in order
and completely before ``step`` returns, so the planner, which runs between steps, never meets a worker.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from typing import Protocol

import cv2
import numpy as np

from arc_env.robot.contours import RobotContours
from arc_env.robot.driver import RobotDriver, Sweep
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.recording import RecordedMotion, Recording
from arc_env.robot.tracking import TrackerConfig, track_keypoints
from planners.collision import CollisionChecker
from planners.errors import TransitError
from planners.transit import TransitConfig, TransitPath, plan_transit
from solver.arrays import FloatArray, ImageArray, evenly_spaced
from solver.errors import ArcCalibError, InvalidInputError
from solver.mask_start import change_mask
from solver.observations import CameraIntrinsics, KeypointTrack, MotionObservation
from solver.outline_fusion import OutlineImage
from solver.outlines import image_edges
from solver.pipeline import CalibrationState, Calibrator, CalibratorConfig, FocalCheck, MotionReport


def motion_refusal_reason(robot: RobotModel, checker: CollisionChecker, min_delta: float, max_delta: float,
                          collision_step_m: float, q: FloatArray, joint: int, delta: float) -> str:
    """Why an exploratory motion (q (n,) rad, joint, delta rad) is not valid on ``robot``, or "" if it is.

    The joint exists, Q is within the limits, min_delta <= |delta| <= max_delta (rad), the sweep stays
    within the joint's limits, and neither Q nor the sweep (checked every ``collision_step_m`` m) collides.
    """
    r = robot
    if not 0 <= joint < r.n_joints:
        return f"joint {joint} is not in [0, {r.n_joints})"
    out = np.nonzero((q < r.lower - 1e-9) | (q > r.upper + 1e-9))[0]
    if out.size:
        k = int(out[0])
        return f"Q[{k}] = {q[k]:.3f} rad is outside the limits [{r.lower[k]:.3f}, {r.upper[k]:.3f}]"
    if abs(delta) < min_delta:
        return f"|delta| = {abs(delta):.3f} rad is below the minimum {min_delta} rad"
    if abs(delta) > max_delta + 1e-9:
        return f"|delta| = {abs(delta):.3f} rad is above the maximum {max_delta} rad"
    end = q[joint] + delta
    if not r.lower[joint] - 1e-9 <= end <= r.upper[joint] + 1e-9:
        return (f"the sweep ends at {end:.3f} rad, outside joint {joint}'s limits "
                f"[{r.lower[joint]:.3f}, {r.upper[joint]:.3f}]")
    hit, why = checker.in_collision(q)
    if hit:
        return f"start configuration in collision: {why}"
    free, why = checker.sweep_free(q, joint, delta, collision_step_m)
    return "" if free else f"sweep in collision: {why}"


#: Images per motion for the outline stage by default (``SessionConfig.outline_frames``, ``--outline-frames``): on
#: realistic images the robot's outlines fixed what its few, short tracks could not (README, "The robot's outlines
#: join the calibration"), and on clean painted ones they cost accuracy nowhere measured.
OUTLINE_FRAMES = 3


def outline_image(grey: ImageArray, q: FloatArray, group: int = 0, first: ImageArray | None = None) -> OutlineImage:
    """The outline stage's image of a grey frame (H, W) uint8 taken with the arm at q (n,) rad: its edges.

    ``first``: its motion's first outline frame (H, W) uint8, when it is not that one: the image then also carries
    where it differs from it (``OutlineImage.changed``, ``solver.mask_start.change_mask``; None for an image too
    small for the mask's cells).
    """
    changed = None
    if first is not None:
        try:
            changed = change_mask([first, grey])
        except InvalidInputError:
            changed = None
    return OutlineImage(image_edges(grey), q, group, changed)


def motion_outline_images(greys: Sequence[tuple[ImageArray, FloatArray]]) -> list[OutlineImage]:
    """A motion's outline images from its outline frames, each (grey (H, W) uint8, q (n,) rad), in sweep order.

    Each through ``outline_image``, the second on with the first frame (where they changed from it).
    """
    return [outline_image(grey, q, first=greys[0][0] if i else None) for i, (grey, q) in enumerate(greys)]


@dataclass(frozen=True)
class SessionConfig:
    """How a session checks, moves and calibrates.

    Attributes:
        min_delta: rad; smallest |Delta| accepted.
        max_delta: rad; largest |Delta| accepted.
        collision_step_m: m; a sweep is checked at steps that move no point by more than this.
        calibrator: solver settings (every track and frame goes to the bundle adjustment by default).
        tracker: tracking settings.
        transit: how the arm gets from where it is to Q (straight if free, else OMPL RRTConnect).
        overlap: execute each motion while a worker thread tracks and calibrates the previous one;
            ``step`` then returns the previous motion's result (see ``CalibrationSession.step``). Off
            (default): each motion is executed, tracked and calibrated before ``step`` returns.
        outline_frames: images per motion (evenly spaced over its sweep) whose edges go to the outline stage
            (``CalibratorConfig.outlines``; the robot's contours rendered from its model by
            ``arc_env.robot.contours.RobotContours``, which needs an offscreen GL context); 0: off (the tracks
            alone). Default ``OUTLINE_FRAMES``.
    """

    min_delta: float = 0.2
    max_delta: float = 1.5
    collision_step_m: float = 0.005
    calibrator: CalibratorConfig = field(default_factory=CalibratorConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    transit: TransitConfig = field(default_factory=TransitConfig)
    overlap: bool = False
    outline_frames: int = OUTLINE_FRAMES

    def __post_init__(self) -> None:
        if self.outline_frames < 0:
            raise InvalidInputError(f"outline_frames must be >= 0, got {self.outline_frames}")
        if not 0 < self.min_delta < self.max_delta:
            raise InvalidInputError(f"need 0 < min_delta < max_delta, got {self.min_delta}, {self.max_delta}")
        if not self.collision_step_m > 0:
            raise InvalidInputError(f"collision_step_m must be > 0, got {self.collision_step_m}")


@dataclass(frozen=True)
class Acquisition:
    """What executing one exploratory motion gave.

    Attributes:
        q_start: (n,) rad, the configuration at the first frame.
        q_end: (n,) rad, where the arm is afterwards.
        deltas: (F,) rad, the turning joint's offset from q_start at each frame.
        frames: F images (H, W, 3) uint8 RGB to track, or None when ``tracks`` are given.
        tracks: keypoint tracks (e.g. the simulator's oracle), or None to track ``frames``.
        seconds: wall time of the acquisition's parts (e.g. "render", "tracking").
        velocities: (F,) rad/s, the turning joint's velocity at each frame as its log gives it, when the
            log is timed (the bundle adjustment then estimates the joint-camera time offset); None: unknown.
    """

    q_start: FloatArray
    q_end: FloatArray
    deltas: FloatArray
    frames: Sequence[ImageArray] | None = None
    tracks: Sequence[KeypointTrack] | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    velocities: FloatArray | None = None


class MotionExecutor(Protocol):
    """Carries out an exploratory motion: the simulator, or a robot through its driver."""

    def execute(self, q: FloatArray, joint: int, delta: float) -> Acquisition:
        """Move to q (n,) rad, turn joint ``joint`` by delta rad while recording; return what was seen."""
        ...


@dataclass(frozen=True)
class MotionOutcome:
    """What the calibrator made of one motion (the env's ``info["motion"]``).

    Attributes:
        joint: the joint that turned.
        n_tracks: keypoint tracks handed over.
        accepted: the calibrator accepted it (at this update).
        reason: why not ("" when accepted).
        stage_one: "" or why stage one found no axis.
        report: the calibrator's report, None when the motion never reached it.
        n_full_tracks: tracks spanning the sweep (``FULL_TRACK_FRACTION`` of its turn or more).
    """

    joint: int
    n_tracks: int
    accepted: bool
    reason: str
    stage_one: str = ""
    report: MotionReport | None = None
    n_full_tracks: int = 0

    def as_info(self) -> dict[str, object]:
        """The env's ``info["motion"]`` dict."""
        return {"joint": self.joint, "n_tracks": self.n_tracks, "accepted": self.accepted, "reason": self.reason,
                "stage_one": self.stage_one, "n_full_tracks": self.n_full_tracks}


#: A track "spans the sweep" when it follows its point over at least this fraction of the joint's turn.
FULL_TRACK_FRACTION = 0.9


def full_tracks(tracks: Sequence[KeypointTrack], deltas: FloatArray) -> int:
    """How many tracks cover at least ``FULL_TRACK_FRACTION`` of the turn deltas (F,) rad."""
    turn = float(np.ptp(deltas)) if len(deltas) else 0.0
    return sum(float(np.ptp(t.delta)) >= FULL_TRACK_FRACTION * turn for t in tracks) if turn > 0 else 0


@dataclass(frozen=True)
class SeenMotion:
    """One motion as the calibrator took it, for an observer (``CalibrationSession.observer``, e.g. a viewer's log).

    Attributes:
        index: the motion's position: the session's count of executed motions, or in the recording.
        q_start: (n,) rad, Q.
        joint: the joint that turned.
        deltas: (F,) rad, its offset from Q at each frame.
        frames: the F images (H, W, 3) uint8 RGB, or None (oracle tracks).
        tracks: its keypoint tracks (pixels, the deltas of their frames).
        outcome: the calibrator's verdict.
        calibrator: the calibrator after it took the motion (its ``state`` is the estimate then).
        name: the recording's name of the motion, or "".
    """

    index: int
    q_start: FloatArray
    joint: int
    deltas: FloatArray
    frames: Sequence[ImageArray] | None
    tracks: Sequence[KeypointTrack]
    outcome: MotionOutcome
    calibrator: Calibrator
    name: str = ""


#: Called with every motion the calibrator took (``CalibrationSession.observer``).
MotionObserver = Callable[[SeenMotion], None]


@dataclass(frozen=True)
class StepResult:
    """One ``CalibrationSession.step`` (or ``flush``): the motion the calibrator took, or why there is none.

    Without overlap it describes the motion the step executed. With ``SessionConfig.overlap`` it describes
    the motion the step *processed* (tracked and gave to the calibrator): the one executed by the previous
    step, at position ``index``; a step that executed a motion but had none to process (the first) is
    ``pending``: ``refused`` is "", ``motion`` and ``transit`` are None.

    Attributes:
        refused: "" or why the motion was not executed (the robot did not move).
        transit: the transit to Q of the motion described (None when refused or pending).
        motion: the calibrator's verdict (None when refused or pending).
        n_frames: frames of the sweep.
        seconds: wall time: "transit", "render" (or the robot's sweep), "tracking", "solver"; with overlap
            also "waited": how long the step stayed blocked on the worker after its own execution ended
            (time the robot stood idle; for ``flush``, all of its processing).
        pending: the step executed a motion whose result a later ``step`` or ``flush`` returns (overlap only).
        index: the described motion's position among the session's executed motions (None when refused
            or pending).
    """

    refused: str
    transit: TransitPath | None = None
    motion: MotionOutcome | None = None
    n_frames: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    pending: bool = False
    index: int | None = None


@dataclass(frozen=True)
class _Executed:
    """A motion executed by an overlapped ``step`` and not yet tracked or given to the calibrator."""

    index: int
    joint: int
    transit: TransitPath
    acquired: Acquisition


class CalibrationSession:
    """A calibration in progress: the robot, the camera, the calibrator and the motions executed so far.

    Args:
        robot: the robot model (kinematics, limits, collision geometry).
        intrinsics: the camera the tracks come from.
        executor: carries out motions (None for recordings, which only ``observe``).
        config: checks, transit, tracker and calibrator settings.
        renderer: what planners may render (``planners.context.SceneRenderer``), or None.

    Attributes:
        calibrator: the calibrator (None before ``reset``).
        executed: the executed motions of this session, in order: (Q (n,) rad, J, delta rad).
        last_transit: the last executed transit (None before the first motion).
        n_motions: executed motions (with overlap, the pending one included); ``n_refused``: refused ones.
        np_random: the generator the session was reset with.
        observer: called with a ``SeenMotion`` after each executed motion (None: nothing is called).
    """

    def __init__(self, robot: RobotModel, intrinsics: CameraIntrinsics, executor: MotionExecutor | None = None,
                 config: SessionConfig | None = None, renderer: object | None = None):
        self.robot = robot
        self.intrinsics = intrinsics
        self.executor = executor
        self.config = config or SessionConfig()
        self.renderer = renderer
        self.observer: MotionObserver | None = None
        self.calibrator: Calibrator | None = None
        self.executed: list[tuple[FloatArray, int, float]] = []
        self.last_transit: TransitPath | None = None
        self.n_motions = 0
        self.n_refused = 0
        self.np_random = np.random.default_rng()
        self._checker: CollisionChecker | None = None
        self._transit_seed = 0
        self._pending: _Executed | None = None
        self._contours: RobotContours | None = None

    # -- the planning context ------------------------------------------------------------------
    @property
    def min_delta(self) -> float:
        """rad; smallest |Delta| accepted."""
        return self.config.min_delta

    @property
    def max_delta(self) -> float:
        """rad; largest |Delta| accepted."""
        return self.config.max_delta

    @property
    def checker(self) -> CollisionChecker:
        """The collision checker of the robot's model (built on first use after ``reset``)."""
        if self._checker is None:
            self._checker = CollisionChecker(self.robot.model, self.robot.arm_joints,
                                             qpos_ref=self.robot.data.qpos.copy())
        return self._checker

    @property
    def pending(self) -> bool:
        """An overlapped ``step`` executed a motion the calibrator has not taken yet (``flush`` takes it)."""
        return self._pending is not None

    def reset(self, rng: np.random.Generator | None = None) -> None:
        """Start over: the arm at home, an empty calibrator, no motions (a pending motion is dropped).

        Args:
            rng: draws the calibrator's seed and the transit planner's (in that order); None keeps the
                calibrator config's own seed.
        """
        self._pending = None  # no worker outlives a step: only its unprocessed motion is left to drop
        self.robot.set_q(self.robot.home)
        self._checker = None
        config = self.config.calibrator
        if rng is not None:
            config = replace(config, seed=int(rng.integers(2**31 - 1)))
            self.np_random = rng
        if self.config.outline_frames and self._contours is None:
            self._contours = RobotContours(self.robot, self.intrinsics)
        self.calibrator = Calibrator(self.intrinsics, self.robot.axis_and_point, config,
                                     contours=self._contours if self.config.outline_frames else None)
        self.n_motions = 0
        self.n_refused = 0
        self.executed = []
        self.last_transit = None
        self._transit_seed = int(rng.integers(2**31 - 1)) if rng is not None else 0

    def refusal_reason(self, q: FloatArray, joint: int, delta: float) -> str:
        """Why the motion (q (n,) rad, joint, delta rad) would be refused, or "" if it is valid."""
        c = self.config
        return motion_refusal_reason(self.robot, self.checker, c.min_delta, c.max_delta, c.collision_step_m,
                                     q, joint, delta)

    # -- the loop --------------------------------------------------------------------------------
    def refuse(self, reason: str) -> StepResult:
        """Count a refused action (the robot does not move)."""
        self.n_refused += 1
        return StepResult(reason)

    def step(self, q: FloatArray, joint: int, delta: float) -> StepResult:
        """Check the motion, plan the transit to Q, execute it, track its frames and add it to the calibrator.

        With ``SessionConfig.overlap``, once the transit is planned the motion is executed on the calling
        thread while a worker thread tracks the previous step's motion and adds it to the calibrator; the
        step waits for the worker and returns *that* motion's result (``StepResult.index``), after handing
        it to the ``observer`` on the calling thread. The first step after ``reset`` (or ``flush``) has
        nothing to process and returns a ``pending`` result; ``flush`` processes the last motion. A refused
        motion leaves the pending one as it is. If the execution raises, the worker's motion is finished
        (in the calibrator, given to the observer) before the exception propagates, without a result.
        Whatever the worker raises propagates from this step, as the same exception.

        Raises:
            InvalidInputError: the session has no executor, or the executor returned malformed data.
        """
        if self.calibrator is None:
            raise InvalidInputError("call reset() before step()")
        if self.executor is None:
            raise InvalidInputError("this session has no executor: it only observes recorded motions")
        reason = self.refusal_reason(q, joint, delta)
        transit: TransitPath | None = None
        if not reason:
            try:
                transit = plan_transit(self.checker, self.robot.lower, self.robot.upper, self.robot.q, q,
                                       self.config.transit, seed=self._transit_seed + self.n_motions + self.n_refused)
            except TransitError as exc:
                reason = f"no transit to Q: {exc}"
        if reason or transit is None:
            return self.refuse(reason)
        self.last_transit = transit
        self.executed.append((q.copy(), joint, delta))
        if self.config.overlap:
            return self._step_overlapped(q, joint, delta, transit)
        acquired = self.executor.execute(q, joint, delta)
        seconds = dict(acquired.seconds)
        tracks = acquired.tracks
        if tracks is None:
            t0 = time.perf_counter()
            tracks = self.track(acquired.frames or [], acquired.deltas, acquired.velocities)
            seconds["tracking"] = time.perf_counter() - t0
        self.robot.set_q(acquired.q_end)
        seconds["transit"] = transit.seconds
        t0 = time.perf_counter()
        outcome = self._observe_executed(acquired.q_start, joint, acquired.deltas, tracks, acquired.frames)
        seconds["solver"] = time.perf_counter() - t0
        self.notify(self.n_motions - 1, acquired.q_start, joint, acquired.deltas, acquired.frames, tracks, outcome)
        return StepResult("", transit, outcome, len(acquired.deltas), seconds, index=self.n_motions - 1)

    def flush(self) -> StepResult | None:
        """Track the pending motion of an overlapped ``step`` and add it to the calibrator, on the calling thread.

        Returns its result (``seconds["waited"]`` is all of the processing: the robot waits for it), or None
        when no motion is pending. Whatever the processing raises propagates (the motion is dropped).
        """
        executed = self._pending
        if executed is None:
            return None
        self._pending = None
        t0 = time.perf_counter()
        processed = self._process(executed)
        return self._processed_result(executed, *processed, waited=time.perf_counter() - t0)

    def _step_overlapped(self, q: FloatArray, joint: int, delta: float, transit: TransitPath) -> StepResult:
        """``step``'s execution with overlap: execute this motion while a worker processes the pending one."""
        assert self.executor is not None
        previous, self._pending = self._pending, None
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="arc-calib-process") as worker:
            future = worker.submit(self._process, previous) if previous is not None else None
            try:
                acquired = self.executor.execute(q, joint, delta)
            except BaseException as exc:
                if previous is not None and future is not None:
                    self._finish_after_failure(previous, future, exc)
                raise
            self.robot.set_q(acquired.q_end)
            self._pending = _Executed(self.n_motions, joint, transit, acquired)
            self.n_motions += 1
            if previous is None or future is None:
                return StepResult("", seconds={"waited": 0.0}, pending=True)
            t0 = time.perf_counter()
            processed = future.result()  # the worker's exception, if any, is raised here
            waited = time.perf_counter() - t0
        return self._processed_result(previous, *processed, waited=waited)

    def _finish_after_failure(self, previous: _Executed, future: Future[tuple[list[KeypointTrack], MotionOutcome,
                                                                              dict[str, float]]],
                              exc: BaseException) -> None:
        """The execution raised ``exc``: let the worker finish its motion (the observer sees it), or note its error."""
        wait([future])
        failed = future.exception()
        if failed is None:
            self._processed_result(previous, *future.result(), waited=0.0)
        else:
            exc.add_note(f"meanwhile processing motion {previous.index} raised {type(failed).__name__}: {failed}")

    def _process(self, executed: _Executed) -> tuple[list[KeypointTrack], MotionOutcome, dict[str, float]]:
        """Track an executed motion's frames and give it to the calibrator (the worker's part; nothing else).

        Touches only the calibrator (and the robot model's locked kinematics): no counters, no observer.
        """
        acquired = executed.acquired
        seconds: dict[str, float] = {}
        tracks = acquired.tracks
        if tracks is None:
            t0 = time.perf_counter()
            tracks = self.track(acquired.frames or [], acquired.deltas, acquired.velocities)
            seconds["tracking"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        outlines = self.outline_images(acquired.q_start, executed.joint, acquired.deltas, acquired.frames or [])
        outcome = replace(self.observe(acquired.q_start, executed.joint, tracks, outlines=outlines),
                          n_full_tracks=full_tracks(tracks, acquired.deltas))
        seconds["solver"] = time.perf_counter() - t0
        return list(tracks), outcome, seconds

    def _processed_result(self, executed: _Executed, tracks: list[KeypointTrack], outcome: MotionOutcome,
                          parts: dict[str, float], waited: float) -> StepResult:
        """Hand a processed motion to the observer (calling thread) and describe it as a ``StepResult``."""
        acquired = executed.acquired
        seconds = {**acquired.seconds, **parts, "transit": executed.transit.seconds, "waited": waited}
        self.notify(executed.index, acquired.q_start, executed.joint, acquired.deltas, acquired.frames, tracks,
                    outcome)
        return StepResult("", executed.transit, outcome, len(acquired.deltas), seconds, index=executed.index)

    def notify(self, index: int, q_start: FloatArray, joint: int, deltas: FloatArray,
               frames: Sequence[ImageArray] | None, tracks: Sequence[KeypointTrack], outcome: MotionOutcome,
               name: str = "") -> None:
        """Hand the motion the calibrator just took to the ``observer``, if any (arguments as ``SeenMotion``'s)."""
        if self.observer is not None and self.calibrator is not None:
            self.observer(SeenMotion(index, q_start, joint, np.asarray(deltas, dtype=np.float64), frames, tracks,
                                     outcome, self.calibrator, name))

    def _observe_executed(self, q_start: FloatArray, joint: int, deltas: FloatArray, tracks: Sequence[KeypointTrack],
                          frames: Sequence[ImageArray] | None = None) -> MotionOutcome:
        """``observe`` an executed motion (deltas (F,) rad) and count it; the outcome counts its full tracks.

        Its ``frames``, when given, give the outline stage its images (``outline_images``).
        """
        outlines = self.outline_images(q_start, joint, deltas, frames or [])
        outcome = replace(self.observe(q_start, joint, tracks, outlines=outlines),
                          n_full_tracks=full_tracks(tracks, deltas))
        self.n_motions += 1
        return outcome

    def track(self, frames: Sequence[ImageArray], deltas: FloatArray,
              velocities: FloatArray | None = None) -> list[KeypointTrack]:
        """Keypoint tracks of one motion's frames (F images) with the joint offset deltas (F,) rad of each.

        With ``velocities`` (F,) rad/s (a timed joint log) each track also carries the joint's velocity at
        its frames: the tracker hands each track the values of its frames from the per-frame array it is
        given, so given the frame indices each track tells which frames it spans.
        """
        if velocities is None:
            return list(track_keypoints(frames, deltas, self.config.tracker).tracks)
        indexed = track_keypoints(frames, np.arange(len(deltas), dtype=np.float64), self.config.tracker).tracks
        tracks = []
        for t in indexed:
            k = np.rint(t.delta).astype(np.int64)
            tracks.append(KeypointTrack(t.pixels, np.asarray(deltas)[k], np.asarray(velocities)[k]))
        return tracks

    def replay(self, q_start: FloatArray, joint: int, deltas: FloatArray, tracks: Sequence[KeypointTrack],
               frames: Sequence[ImageArray] | None = None) -> MotionOutcome:
        """Add a motion executed before (a recording being resumed): it counts as executed, like ``step``'s.

        Args:
            q_start: (n,) rad, Q.
            joint: the joint that turned.
            deltas: (F,) rad, its offset at each frame (the last is the turn Delta).
            tracks: its keypoint tracks.
            frames: its images, for the ``observer`` only (None: not at hand).
        """
        if self.calibrator is None:
            raise InvalidInputError("call reset() before replay()")
        if self._pending is not None:
            raise InvalidInputError("an overlapped step's motion is pending: flush() it before replay()")
        q_start = self.robot.check_q(q_start)
        self.executed.append((q_start.copy(), joint, float(deltas[-1])))
        self.robot.set_swept(q_start, joint, float(deltas[-1]))
        outcome = self._observe_executed(q_start, joint, deltas, tracks, frames)
        self.notify(self.n_motions - 1, q_start, joint, deltas, frames, tracks, outcome)
        return outcome

    def outline_greys(self, q_start: FloatArray, joint: int, deltas: FloatArray,
                      frames: Sequence[ImageArray]) -> list[tuple[ImageArray, FloatArray]]:
        """``SessionConfig.outline_frames`` of a motion's F RGB frames (deltas (F,) rad), evenly spaced, in grey.

        Each as (grey (H, W) uint8, the arm's configuration (n,) rad in it); empty when the outline stage is
        off or there are no frames.
        """
        if not self.config.outline_frames or not len(frames):
            return []
        greys = []
        for k in evenly_spaced(len(frames), self.config.outline_frames):
            q = np.array(q_start, dtype=np.float64)
            q[joint] += float(deltas[k])
            greys.append((cv2.cvtColor(np.asarray(frames[k]), cv2.COLOR_RGB2GRAY), q))
        return greys

    def outline_images(self, q_start: FloatArray, joint: int, deltas: FloatArray,
                       frames: Sequence[ImageArray]) -> list[OutlineImage]:
        """The outline stage's images of a motion (``outline_greys``, through ``motion_outline_images``)."""
        return motion_outline_images(self.outline_greys(q_start, joint, deltas, frames))

    def observe(self, q_start: FloatArray, joint: int, tracks: Sequence[KeypointTrack],
                update: bool = True, outlines: Sequence[OutlineImage] = ()) -> MotionOutcome:
        """Hand one motion's tracks to the calibrator (after checking the robot model accepts the motion).

        Args:
            q_start: (n,) rad, Q.
            joint: the joint that turned.
            tracks: its keypoint tracks.
            update: recompute the estimate now (Algorithm 1 updates once three motions are in).
            outlines: its images for the outline stage (``outline_images``).
        """
        if self.calibrator is None:
            raise InvalidInputError("call reset() before observe()")
        try:  # checked here: a motion the kinematics reject must not reach the calibrator
            self.robot.axis_and_point(q_start, joint)
        except ArcCalibError as exc:
            return MotionOutcome(joint, len(tracks), False, f"the robot model rejects this motion: {exc}")
        try:
            report = self.calibrator.add_motion(MotionObservation(q_start=q_start, joint=joint, tracks=tuple(tracks)),
                                                update=update, outlines=outlines)
        except ArcCalibError as exc:
            return MotionOutcome(joint, len(tracks), False, f"solver error: {exc}")
        return MotionOutcome(joint, len(tracks), report.accepted, report.reason, report.stage_one, report)


class DriverExecutor:
    """Executes motions on a robot through its ``RobotDriver``: move to Q, sweep, read the joints per frame.

    Args:
        driver: the robot.
        on_sweep: called with (motion index, q_start (n,) rad, joint, Sweep) after every sweep (e.g. to
            record it).
    """

    def __init__(self, driver: RobotDriver, on_sweep: Callable[[int, FloatArray, int, Sweep], None] | None = None):
        self.driver = driver
        self.on_sweep = on_sweep
        self.n_sweeps = 0

    def execute(self, q: FloatArray, joint: int, delta: float) -> Acquisition:
        """Move, sweep and check the driver's answer.

        Raises:
            InvalidInputError: the sweep has fewer than 3 frames, or positions of the wrong shape or not finite.
        """
        t0 = time.perf_counter()
        self.driver.move_to(q)
        sweep = self.driver.sweep(joint, delta)
        positions = np.asarray(sweep.positions, dtype=np.float64)
        n = len(self.driver.joint_names)
        if len(sweep.frames) < 3 or positions.shape != (len(sweep.frames), n) or not np.all(np.isfinite(positions)):
            raise InvalidInputError(f"driver sweep must return >= 3 frames and finite positions "
                                    f"({len(sweep.frames)}, {n}); got {len(sweep.frames)} frames, "
                                    f"positions {positions.shape}")
        seconds = {"render": time.perf_counter() - t0}
        if self.on_sweep is not None:
            self.on_sweep(self.n_sweeps, positions[0], joint, sweep)
        self.n_sweeps += 1
        return Acquisition(positions[0], positions[-1], positions[:, joint] - positions[0, joint], sweep.frames,
                           None, seconds)


@dataclass(frozen=True)
class UsableCriteria:
    """When a calibration result is usable (see the module docstring).

    Attributes:
        min_motions: fewest motions that must inform the estimate.
        max_std_deg: degrees; largest 1-sigma of each rotation component.
        max_std_mm: mm; largest 1-sigma of each translation component.
    """

    min_motions: int = 4
    max_std_deg: float = 0.25
    max_std_mm: float = 3.0

    def __post_init__(self) -> None:
        if self.min_motions < 3 or not self.max_std_deg > 0 or not self.max_std_mm > 0:
            raise InvalidInputError("need min_motions >= 3, max_std_deg > 0 and max_std_mm > 0")


@dataclass
class MotionDiagnostic:
    """What became of one recorded motion."""

    motion: str
    joint: str | None
    frames: int
    tracks: int = 0
    accepted: bool = False
    reason: str = ""
    inlier_tracks: int = 0
    axis_error_rad: float | None = None
    plane_distance_m: float | None = None
    linear: bool = False
    note: str = ""
    seconds: float = 0.0
    front_end: str = ""


@dataclass
class CalibrationRun:
    """A finished calibration: of a recording, or online through a driver.

    Attributes:
        source: what was calibrated (the recording's path, or the driver).
        calibrator: the calibrator after its last update.
        diagnostics: one per motion, in order.
        seconds: wall time per part of the work.
        recording: the recording (None online).
    """

    source: str
    calibrator: Calibrator
    diagnostics: list[MotionDiagnostic]
    seconds: dict[str, float] = field(default_factory=dict)
    recording: Recording | None = None
    focal_check: FocalCheck | None = None

    def check_focal(self) -> None:
        """Run the focal-length consistency check on the final estimate (``Calibrator.focal_check``)."""
        t0 = time.perf_counter()
        self.focal_check = self.calibrator.focal_check()
        self.seconds["intrinsics check"] = time.perf_counter() - t0

    @property
    def n_accepted(self) -> int:
        """Motions informing the estimate."""
        return sum(d.accepted for d in self.diagnostics)

    @property
    def given_time_offset_s(self) -> float:
        """s: the time offset d = t_joint - t_camera the recording's joints were read with (0 online)."""
        return self.recording.time_offset_s if self.recording is not None else 0.0


def driver_session(driver: RobotDriver, config: SessionConfig | None = None,
                   on_sweep: Callable[[int, FloatArray, int, Sweep], None] | None = None,
                   renderer: object | None = None) -> CalibrationSession:
    """A session in which ``driver`` executes the motions, on the driver's robot model.

    The model (``RobotModel.load``: the driver's file, base body and joint order, a collision-only
    ground plane) keeps the joint limits of the model intersected with the driver's; the camera is the
    driver's. Call ``reset`` before stepping.

    Raises:
        InvalidInputError: the model does not load, or the driver's limits are not two (n,) arrays
            with lower < upper.
    """
    source = RobotSource(path=driver.robot.path, base_body=driver.robot.base_body,
                         joints=tuple(driver.joint_names), home=())
    robot = RobotModel.load(source)
    lower, upper = (np.asarray(a, dtype=np.float64) for a in driver.joint_limits)
    n = robot.n_joints
    if lower.shape != (n,) or upper.shape != (n,) or np.any(lower >= upper):
        raise InvalidInputError(f"driver joint_limits must be two ({n},) arrays with lower < upper")
    robot.lower = np.maximum(robot.lower, lower)
    robot.upper = np.minimum(robot.upper, upper)
    return CalibrationSession(robot, driver.intrinsics, DriverExecutor(driver, on_sweep), config, renderer)


def calibrate_recording(recording: Recording, tracker: TrackerConfig | None = None,
                        config: CalibratorConfig | None = None,
                        on_motion: Callable[[str], None] | None = None,
                        observer: MotionObserver | None = None, outline_frames: int = OUTLINE_FRAMES) -> CalibrationRun:
    """Track every usable motion and calibrate; motions pruned on the way keep their reasons.

    Args:
        recording: the validated recording.
        tracker: tracking settings.
        config: solver settings (default ``CalibratorConfig()``: more tracks per motion than online).
        on_motion: called with a one-line status after each motion (a progress display).
        observer: called with each motion the calibrator took, frames included (``SeenMotion``).
        outline_frames: images per motion for the outline stage (``SessionConfig.outline_frames``); 0: off.

    Raises:
        InvalidInputError: a frame or video does not decode (the message names it).
    """
    session = CalibrationSession(recording.robot, recording.intrinsics,
                                 config=SessionConfig(calibrator=config or CalibratorConfig(),
                                                      tracker=tracker or TrackerConfig(),
                                                      outline_frames=outline_frames))
    session.reset()
    session.observer = observer
    calibrator = session.calibrator
    assert calibrator is not None
    names = recording.joint_names
    diagnostics: list[MotionDiagnostic] = []
    by_report: dict[int, MotionDiagnostic] = {}
    seconds = {"decode": 0.0, "tracking": 0.0, "solver": 0.0}
    started = time.perf_counter()
    updated = False
    for m in recording.motions:
        diag = MotionDiagnostic(m.name, names[m.joint] if m.joint is not None else None, m.n_frames)
        diagnostics.append(diag)
        t0 = time.perf_counter()
        if m.pruned:
            diag.reason = m.pruned
        else:
            frames = recording.frames(m)
            t1 = time.perf_counter()
            tracks = track_recorded(session, frames, m)
            t2 = time.perf_counter()
            diag.tracks = len(tracks)
            if not tracks:
                diag.reason = "no keypoint tracks: nothing moved in the images (is the robot in view?)"
            else:
                assert m.joint is not None
                update = len(calibrator.reports) >= 2  # Algorithm 1: update once 3 motions are in
                outlines = session.outline_images(m.q_start, m.joint, m.delta, frames)
                outcome = session.observe(m.q_start, m.joint, tracks, update=update, outlines=outlines)
                if outcome.report is None:
                    diag.reason = outcome.reason
                else:
                    by_report[outcome.report.index] = diag
                    updated = update
            seconds["decode"] += t1 - t0
            seconds["tracking"] += t2 - t1
            seconds["solver"] += time.perf_counter() - t2
            if tracks:
                session.notify(len(diagnostics) - 1, m.q_start, m.joint, m.delta, frames, tracks, outcome, m.name)
            del frames
        diag.seconds = time.perf_counter() - t0
        if on_motion is not None:
            what = diag.reason[:60] if diag.reason and not diag.tracks else f"{diag.tracks} tracks"
            on_motion(f"motion {m.name} joint {diag.joint or '-'}: {m.n_frames} frames, {what}; "
                      f"{estimate_status(calibrator.state)}")
    if calibrator.reports and not updated:  # the last motion added did not update (or failed)
        t0 = time.perf_counter()
        calibrator.update()
        seconds["solver"] += time.perf_counter() - t0
    for r in calibrator.reports:
        copy_report(r, by_report[r.index])
    run = CalibrationRun(str(recording.path), calibrator, diagnostics, seconds, recording)
    run.check_focal()
    seconds["total"] = time.perf_counter() - started
    return run


#: ``calibrate_reading_offset`` stops once the time-offset correction is below this, s ...
OFFSET_PASS_TOL_S = 1e-3
#: ... or within this many of its 1-sigma.
OFFSET_PASS_SIGMAS = 2.0


def calibrate_reading_offset(read: Callable[[float], Recording], given_s: float = 0.0,
                             tracker: TrackerConfig | None = None, config: CalibratorConfig | None = None,
                             on_motion: Callable[[str], None] | None = None, max_passes: int = 3,
                             observer: MotionObserver | None = None,
                             outline_frames: int = OUTLINE_FRAMES) -> CalibrationRun:
    """``calibrate_recording``, read again at the corrected time offset while the correction is large.

    The bundle adjustment's time-offset estimate is first order in the correction (each frame's turn
    delta + v s, ``solver.refinement``), so where a sweep starts or stops abruptly a large correction comes
    out short (``scripts/bench_latency.py``: 17.7 ms for a 20 ms latency, 29.8 for 40). So while the
    correction exceeds ``OFFSET_PASS_TOL_S`` and ``OFFSET_PASS_SIGMAS`` of its 1-sigma, the recording is
    read again with its joints interpolated at the corrected offset (``read(offset)``) and calibrated again,
    at most ``max_passes`` times in all; the last run is returned (its ``given_time_offset_s`` is the offset
    it read the joints at). Recordings without joint velocities (format 1) or with the estimate off take one
    pass.

    Args:
        read: the recording with its joints read at a time offset d = t_joint - t_camera, s.
        given_s: s, the first pass's offset (the user's ``--time-offset``).
        tracker: tracking settings, as ``calibrate_recording``'s.
        config: solver settings, as ``calibrate_recording``'s.
        on_motion: progress callback, as ``calibrate_recording``'s (called again on every pass).
        max_passes: most calibrations; >= 1.
        observer: as ``calibrate_recording``'s (called again on every pass).
        outline_frames: as ``calibrate_recording``'s.
    """
    if max_passes < 1:
        raise InvalidInputError(f"max_passes must be >= 1, got {max_passes}")
    offset = given_s
    for _ in range(max_passes):
        run = calibrate_recording(read(offset), tracker, config, on_motion, observer, outline_frames=outline_frames)
        s = run.calibrator.state
        if (s.time_offset_s is None or s.time_offset_std_s is None
                or abs(s.time_offset_s) <= max(OFFSET_PASS_TOL_S, OFFSET_PASS_SIGMAS * s.time_offset_std_s)):
            break
        offset += s.time_offset_s
    return run


def track_recorded(session: CalibrationSession, frames: Sequence[ImageArray], motion: RecordedMotion
                   ) -> list[KeypointTrack]:
    """Keypoint tracks of a recorded motion's frames, with the joint's velocity at each frame when it is known.

    The motion's delta (F,) rad and ``joint_velocity`` (F,) rad/s (what the bundle adjustment's time-offset
    estimate reads) go to ``CalibrationSession.track``.
    """
    return session.track(frames, motion.delta, motion.joint_velocity)


def estimate_status(state: CalibrationState) -> str:
    """The estimate in a few words for progress lines: ``refined estimate, 7 accepted`` or ``no estimate yet``."""
    if state.T_camera_base is None:
        return "no estimate yet"
    return f"{state.stage} estimate, {state.n_accepted} accepted"


def copy_report(report: MotionReport, diag: MotionDiagnostic) -> None:
    """Fill a diagnostic from the calibrator's final report on that motion."""
    diag.accepted, diag.inlier_tracks, diag.linear = report.accepted, report.n_inlier_tracks, report.linear
    diag.reason, diag.front_end = report.reason, report.front_end
    diag.axis_error_rad, diag.plane_distance_m = report.eps_a, report.eps_d
    diag.note = f"no axis for the linear stage: {report.stage_one}" if report.stage_one and report.accepted else ""


def unusable_reason(run: CalibrationRun, criteria: UsableCriteria) -> str:
    """"" when the result is usable, else why not."""
    if not run.calibrator.reports:
        return (f"none of the {len(run.diagnostics)} motions gave keypoint tracks (pruned, or nothing moved "
                "in the images: is the robot in view?)")
    why = state_unusable_reason(run.calibrator.state, run.n_accepted, criteria)
    if run.focal_check is not None and not run.focal_check.fits:  # said whatever else is wrong: it may be the cause
        where = f" ({run.recording.camera_source})" if run.recording is not None else ""
        why = "; ".join(filter(None, (why, run.focal_check.message + where)))
    return why


def state_unusable_reason(s: CalibrationState, n_accepted: int, criteria: UsableCriteria) -> str:
    """"" when the calibration state (with n_accepted motions informing it) is usable, else why not."""
    if s.T_camera_base is None:
        return f"no estimate: {s.message}"
    if s.stage != "refined" or s.std is None:
        return f"only a {s.stage} estimate (the bundle adjustment gave none: {s.message or 'see motions'})"
    if s.start == "outlines":  # the rescue marks no motion accepted: say what the pose rests on instead
        return ("the pose rests on the robot's outlines fixing a direction the tracks leave free (the tracks alone "
                "give no refined pose yet); record more motions, of joints whose axes do not all meet in one point")
    if n_accepted < criteria.min_motions:
        return f"only {n_accepted} motion(s) inform the estimate (need {criteria.min_motions})"
    std_deg, std_mm = np.degrees(s.std[:3]), s.std[3:] * 1e3
    if np.any(std_deg > criteria.max_std_deg) or np.any(std_mm > criteria.max_std_mm):
        return (f"the estimate is too uncertain: 1-sigma rotation {np.round(std_deg, 3).tolist()} deg "
                f"(limit {criteria.max_std_deg}), translation {np.round(std_mm, 2).tolist()} mm "
                f"(limit {criteria.max_std_mm}); record more motions")
    return ""


