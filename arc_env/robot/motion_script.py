"""A motion script: N exploratory motions and the transits between them as one timed joint trajectory.

``arc-calib plan`` writes what a robot's own controller replays while ``ros2 bag record`` records the camera
and the joint states; ``arc-calib calibrate`` then finds the motions in the bag's joint stream
(``arc_env.robot.segmentation``). Nothing here needs a camera image or a driver.

Planning (``plan_motion_script``): the random planner (``planners.random_planner``, the paper's selection)
draws each motion (Q, J, Delta) through a ``ScriptContext`` -- the robot model with its collision checker
(the robot, a ground plane at z = 0 and the ``--obstacles``; ``planners.collision``), its limits, and
optionally the camera's intrinsics with a guess of ``T_camera_base``: with both, a motion is kept only when
at least ``RandomPlannerConfig.min_in_view`` of the moving links' surface points project into the image
(20 px inside its border) at both ends of the sweep, i.e. the links stay inside the camera's view cone.
Without them, no visibility test is made. The transit from where the arm is (the start configuration, then
the end of the previous sweep) to each Q is planned by ``planners.transit`` (the straight joint-space
segment if it is free, else OMPL RRTConnect), every segment checked so that no point of the arm moves more
than 5 mm between collision checks; a motion whose transit fails is replaced by another draw.

Timing (``ScriptConfig``): every point of the trajectory is a stop (velocity zero), and each segment between
two points is a cubic from rest to rest -- what ``joint_trajectory_controller`` interpolates when it is given
positions and velocities -- so the arm follows the straight joint-space segment between the two points,
the one that was collision-checked. A segment changing the joints by dq (rad) lasts::

    T = max(1.5 * max|dq| / speed, sqrt(6 * max|dq| / max_accel))

so the fastest joint peaks at ``speed`` (a rest-to-rest cubic peaks at 1.5 times its mean speed) and its
acceleration at most at ``max_accel``. Transits use ``max_speed`` (default 0.5 rad/s), sweeps
``sweep_speed`` (default 0.5 rad/s); ``max_accel`` defaults to 1 rad/s^2. The arm rests ``rest_s``
(default 0.5 s) at the start, before each sweep and after it, so segmentation sees every sweep as a span of
its own, separated from the transits (several joints moving) by rests. Before a script is returned, its
trajectory is sampled at 200 Hz and segmented as ``calibrate`` will segment the bag: the sweeps found must
be the planned ones (same joints, turns within ``SEGMENT_DELTA_TOL``), else ``PlanningError``.

Output (``trajectory_message``, ``trajectory_csv``, ``sweeps_document``): a ``trajectory_msgs/JointTrajectory``
as a YAML mapping (``header``, ``joint_names``, ``points`` with ``positions``, ``velocities`` and
``time_from_start: {sec, nanosec}``), the same waypoints as CSV (``t`` then one column per joint), and the
list of sweeps (joint, Q, Delta, start and stop times, the points they span) for the user to check.
``read_trajectory`` reads such a YAML back (the simulator replays it: ``arc-calib record --trajectory``) and
``trajectory_positions`` samples it at any times as a controller would.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from arc_env.robot.model import RobotModel
from arc_env.robot.segmentation import SegmentConfig, segment_motions
from arc_env.robot.session import motion_refusal_reason
from arc_env.robot.timing import check_times
from planners.collision import CollisionChecker
from planners.context import observation_from_estimate
from planners.errors import PlanningError, TransitError
from planners.random_planner import RandomPlanner, RandomPlannerConfig
from planners.transit import TransitConfig, plan_transit
from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import check_transform, transform_from_rt
from solver.observations import CameraIntrinsics

#: A rest-to-rest cubic's peak speed is this times its mean speed (and its peak acceleration 6 dq / T^2).
CUBIC_PEAK = 1.5
#: Hz: the self-check samples the trajectory at this rate (a typical joint_states rate).
CHECK_HZ = 200.0
#: rad: a segment found in the sampled trajectory matches a planned sweep when its turn is this close.
#: The segmentation's span starts where the joint has moved rest_rad (2 mrad) over a 0.1 s window, so it
#: misses at most about that much of each end of the cubic.
SEGMENT_DELTA_TOL = 5e-3
_JOINT_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_:./-]{0,199}")


def check_joint_name(name: object, what: str) -> str:
    """``name`` if it is a joint name fit for a trajectory (letters, digits, ``_ : . / -``), else InvalidInputError."""
    if not isinstance(name, str) or not _JOINT_NAME.fullmatch(name):
        raise InvalidInputError(f"{what}: joint name {name!r} is not usable in a trajectory: use 1 to 200 letters, "
                                "digits, '_', ':', '.', '/' and '-', not starting with a digit or punctuation")
    return name


@dataclass(frozen=True)
class ScriptConfig:
    """How ``plan_motion_script`` plans and times a script (the module docstring gives the rules).

    Attributes:
        max_speed: rad/s, the fastest joint's peak speed on a transit.
        sweep_speed: rad/s, the turning joint's peak speed on a sweep.
        max_accel: rad/s^2, the largest joint acceleration anywhere.
        rest_s: s, the rest at the start, before each sweep and after it.
        min_delta: rad, smallest |Delta| (the session's and the segmentation's minimum).
        max_delta: rad, largest |Delta|.
        collision_step_m: m, a sweep is checked at steps that move no point by more than this.
        attempts_per_motion: motions drawn for one slot before giving up (a draw is lost when its transit fails).
        planner: the random planner's settings (|Delta| range, limit margin, in-view fraction and margin).
        transit: the transit planner's settings.
        segmentation: the self-check's segmentation (``calibrate``'s default).
    """

    max_speed: float = 0.5
    sweep_speed: float = 0.5
    max_accel: float = 1.0
    rest_s: float = 0.5
    min_delta: float = 0.2
    max_delta: float = 1.5
    collision_step_m: float = 0.005
    attempts_per_motion: int = 20
    planner: RandomPlannerConfig = field(default_factory=RandomPlannerConfig)
    transit: TransitConfig = field(default_factory=TransitConfig)
    segmentation: SegmentConfig = field(default_factory=SegmentConfig)

    def __post_init__(self) -> None:
        for name in ("max_speed", "sweep_speed", "max_accel", "rest_s", "collision_step_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InvalidInputError(f"{name} must be a finite number > 0, got {value}")
        if not 0 < self.min_delta < self.max_delta:
            raise InvalidInputError(f"need 0 < min_delta < max_delta, got {self.min_delta}, {self.max_delta}")
        if self.attempts_per_motion < 1:
            raise InvalidInputError(f"attempts_per_motion must be >= 1, got {self.attempts_per_motion}")


def segment_duration(dq: FloatArray, speed: float, max_accel: float) -> float:
    """s: how long a rest-to-rest cubic takes for the change dq (n,) rad at peak ``speed`` rad/s, ``max_accel``."""
    step = float(np.max(np.abs(dq)))
    return max(CUBIC_PEAK * step / speed, math.sqrt(6.0 * step / max_accel))


class ScriptContext:
    """What the random planner reads while planning a script (``planners.context.PlanningContext``).

    The robot model and its collision checker, the limits and the Delta bounds of ``ScriptConfig``; no
    renderer, no calibrator. ``intrinsics`` is None without a camera: the planner reads it only with an
    estimate (a ``T_camera_base`` guess), which ``plan_motion_script`` gives only together with intrinsics.
    """

    def __init__(self, robot: RobotModel, intrinsics: CameraIntrinsics | None, config: ScriptConfig,
                 rng: np.random.Generator):
        self.robot = robot
        self.intrinsics = intrinsics
        self.config = config
        self.renderer = None
        self.calibrator = None
        self.executed: list[tuple[FloatArray, int, float]] = []
        self.np_random = rng
        self._checker = CollisionChecker(robot.model, robot.arm_joints, qpos_ref=robot.data.qpos.copy())

    @property
    def checker(self) -> CollisionChecker:
        """The arm's collision checker (robot, ground plane, obstacles)."""
        return self._checker

    @property
    def min_delta(self) -> float:
        """rad; smallest |Delta|."""
        return self.config.min_delta

    @property
    def max_delta(self) -> float:
        """rad; largest |Delta|."""
        return self.config.max_delta

    def refusal_reason(self, q: FloatArray, joint: int, delta: float) -> str:
        """Why the motion (q (n,) rad, joint, delta rad) is not valid, or "" if it is (the session's check)."""
        c = self.config
        return motion_refusal_reason(self.robot, self.checker, c.min_delta, c.max_delta, c.collision_step_m,
                                     q, joint, delta)


@dataclass(frozen=True)
class PlannedSweep:
    """One exploratory motion of a script.

    Attributes:
        joint: index of the turning joint (``MotionScript.joint_names`` order).
        q_start: (n,) rad, Q: where the sweep starts.
        delta: rad, the turn.
        t_start: s from the trajectory's start: the turn begins (after a rest at Q).
        t_stop: s: the turn ends (a rest follows).
        first_point: index of the trajectory point at Q where the turn begins.
        last_point: index of the point where it ends.
    """

    joint: int
    q_start: FloatArray
    delta: float
    t_start: float
    t_stop: float
    first_point: int
    last_point: int


@dataclass(frozen=True)
class MotionScript:
    """A timed joint trajectory holding exploratory motions.

    Attributes:
        joint_names: the n joints, in the order of every position row.
        times: (K,) s from the start, strictly increasing (0 first).
        positions: (K, n) rad, the waypoints.
        sweeps: the exploratory motions, in time order.
        transit_planned: per sweep, whether its transit needed OMPL (the straight segment was blocked).
    """

    joint_names: tuple[str, ...]
    times: FloatArray
    positions: FloatArray
    sweeps: tuple[PlannedSweep, ...]
    transit_planned: tuple[bool, ...] = ()

    @property
    def velocities(self) -> FloatArray:
        """(K, n) rad/s: zero at every point (each segment is a rest-to-rest cubic)."""
        return np.zeros_like(self.positions)

    @property
    def duration(self) -> float:
        """s, the time of the last point."""
        return float(self.times[-1])


def trajectory_positions(times: FloatArray, positions: FloatArray, velocities: FloatArray | None,
                         t: FloatArray) -> FloatArray:
    """Where a controller following the trajectory has the joints at times t: (M, n) rad.

    Between two points: the cubic Hermite through their positions and velocities (what
    ``joint_trajectory_controller`` does when velocities are given), or linear interpolation without
    velocities. Before the first point the arm holds the first position, after the last the last one.

    Args:
        times: (K,) s, strictly increasing.
        positions: (K, n) rad.
        velocities: (K, n) rad/s, or None.
        t: (M,) s, any order.
    """
    times, positions = np.asarray(times, np.float64), np.asarray(positions, np.float64)
    t = np.clip(np.asarray(t, np.float64), times[0], times[-1])
    if len(times) == 1:
        return np.repeat(positions[:1], len(t), axis=0)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    h = (times[i + 1] - times[i])[:, None]
    s = (t[:, None] - times[i][:, None]) / h
    p0, p1 = positions[i], positions[i + 1]
    if velocities is None:
        return p0 + s * (p1 - p0)
    v0, v1 = velocities[i], velocities[i + 1]
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * p0 + (s3 - 2 * s2 + s) * h * v0 + (-2 * s3 + 3 * s2) * p1
            + (s3 - s2) * h * v1)


def _check_start(robot: RobotModel, checker: CollisionChecker, start: FloatArray) -> FloatArray:
    q = robot.check_q(start)
    out = np.nonzero((q < robot.lower - 1e-9) | (q > robot.upper + 1e-9))[0]
    if out.size:
        k = int(out[0])
        raise InvalidInputError(f"the start configuration's {robot.joint_names[k]} = {q[k]:.3f} rad is outside its "
                                f"limits [{robot.lower[k]:.3f}, {robot.upper[k]:.3f}]")
    hit, why = checker.in_collision(q)
    if hit:
        raise InvalidInputError(f"the start configuration is in collision: {why}")
    return q


def plan_motion_script(robot: RobotModel, n_motions: int, *, intrinsics: CameraIntrinsics | None = None,
                       T_camera_base_guess: FloatArray | None = None, start: FloatArray | None = None,
                       config: ScriptConfig | None = None, rng: np.random.Generator | None = None,
                       on_motion: Callable[[str], None] | None = None) -> MotionScript:
    """Plan ``n_motions`` collision-free exploratory motions and the timed trajectory through them.

    Args:
        robot: the robot model, with its obstacles (``RobotModel.load(source, obstacles=...)``).
        n_motions: motions to plan, >= 1.
        intrinsics: the camera (needed with ``T_camera_base_guess``).
        T_camera_base_guess: (4, 4) float64, a guess of the camera pose: keeps the moving links in view.
        start: (n,) rad where the arm is when the trajectory starts; None: the robot's home.
        config: speeds, rests and planner settings.
        rng: draws the motions and seeds the transit planner; None: a fresh generator.
        on_motion: called with a one-line status after each planned motion.

    Raises:
        InvalidInputError: a guess without intrinsics, n_motions < 1, a bad joint name, or the start is
            outside the limits or in collision.
        PlanningError: no valid (visible) motion with a free transit within the budget, or the trajectory
            would not segment into its sweeps.
    """
    cfg = config or ScriptConfig()
    if n_motions < 1:
        raise InvalidInputError(f"--motions must be >= 1, got {n_motions}")
    if T_camera_base_guess is not None and intrinsics is None:
        raise InvalidInputError("a camera pose guess needs the camera's intrinsics (--camera-info)")
    names = tuple(check_joint_name(n, "the robot model") for n in robot.joint_names)
    rng = rng if rng is not None else np.random.default_rng()
    context = ScriptContext(robot, intrinsics, cfg, rng)
    q_now = _check_start(robot, context.checker, robot.home if start is None else start)
    planner = RandomPlanner(context, rng, cfg.planner)
    observation = observation_from_estimate(T_camera_base_guess)
    times, points = [0.0, cfg.rest_s], [q_now, q_now]
    sweeps: list[PlannedSweep] = []
    planned: list[bool] = []
    for _ in range(n_motions):
        transit = None
        for _attempt in range(cfg.attempts_per_motion):
            action = planner.plan(observation)
            q, joint, delta = np.asarray(action["Q"], np.float64), int(action["J"]), float(action["delta"][0])
            try:
                transit = plan_transit(context.checker, robot.lower, robot.upper, q_now, q, cfg.transit,
                                       seed=int(rng.integers(2**31 - 1)))
                break
            except TransitError:
                continue
        if transit is None:
            raise PlanningError(f"motion {len(sweeps) + 1}: no collision-free transit to any of "
                                f"{cfg.attempts_per_motion} valid motions")
        for a, b in zip(transit.waypoints[:-1], transit.waypoints[1:], strict=True):
            if np.max(np.abs(b - a)) > 0:
                times.append(times[-1] + segment_duration(b - a, cfg.max_speed, cfg.max_accel))
                points.append(b)
        times.append(times[-1] + cfg.rest_s)
        points.append(q)
        end = q.copy()
        end[joint] += delta
        t_start = times[-1]
        times.append(t_start + segment_duration(end - q, cfg.sweep_speed, cfg.max_accel))
        points.append(end)
        sweeps.append(PlannedSweep(joint, q.copy(), delta, t_start, times[-1], len(points) - 2, len(points) - 1))
        planned.append(transit.planned)
        times.append(times[-1] + cfg.rest_s)
        points.append(end)
        context.executed.append((q.copy(), joint, delta))
        q_now = end
        if on_motion is not None:
            on_motion(f"{names[joint]} delta {delta:+.3f} rad, transit {'planned' if transit.planned else 'straight'}")
    script = MotionScript(names, np.asarray(times), np.asarray(points), tuple(sweeps), tuple(planned))
    check_segmentation(script, cfg.segmentation)
    return script


def check_segmentation(script: MotionScript, segmentation: SegmentConfig | None = None) -> None:
    """Raise PlanningError unless the script's trajectory, sampled at ``CHECK_HZ``, segments into its sweeps."""
    t = np.arange(0.0, script.duration + 1e-9, 1.0 / CHECK_HZ)
    values = trajectory_positions(script.times, script.positions, script.velocities, t)
    found, _ = segment_motions(t, values, script.joint_names, segmentation)
    pairs = [(s.joint, round(s.delta, 3)) for s in found]
    planned = [(s.joint, round(s.delta, 3)) for s in script.sweeps]
    if len(found) != len(script.sweeps) or any(
            f.joint != p.joint or abs(f.delta - p.delta) > SEGMENT_DELTA_TOL
            for f, p in zip(found, script.sweeps, strict=True)):
        raise PlanningError(f"the trajectory would not segment into its sweeps: planned (joint, delta) {planned}, "
                            f"found {pairs}")


def _duration_msg(t: float) -> dict[str, int]:
    ns = int(round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def trajectory_message(script: MotionScript, frame_id: str = "") -> dict[str, Any]:
    """The script as a ``trajectory_msgs/JointTrajectory`` mapping (for ``yaml.safe_dump``)."""
    return {
        "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": frame_id},
        "joint_names": list(script.joint_names),
        "points": [{"positions": [float(v) for v in p], "velocities": [0.0] * len(p),
                    "time_from_start": _duration_msg(float(t))}
                   for t, p in zip(script.times, script.positions, strict=True)],
    }


def trajectory_csv(script: MotionScript) -> str:
    """The waypoints as CSV: a header ``t`` and the joint names, then one row per point (s, rad)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["t", *script.joint_names])
    for t, p in zip(script.times, script.positions, strict=True):
        writer.writerow([repr(float(t)), *(repr(float(v)) for v in p)])
    return buffer.getvalue()


def sweeps_document(script: MotionScript, about: dict[str, Any]) -> dict[str, Any]:
    """The list of sweeps (for ``yaml.safe_dump``): which span of the trajectory is which exploratory motion.

    Args:
        script: the script.
        about: what produced it (robot, base body, seed, speeds...), copied in first.
    """
    return {
        **about,
        "duration_s": script.duration,
        "n_points": len(script.times),
        "sweeps": [{"index": k, "joint": script.joint_names[s.joint], "joint_index": s.joint,
                    "Q": [float(v) for v in s.q_start], "delta": s.delta, "t_start": float(s.t_start),
                    "t_stop": float(s.t_stop), "points": [s.first_point, s.last_point],
                    "transit_planned": bool(script.transit_planned[k]) if script.transit_planned else None}
                   for k, s in enumerate(script.sweeps)],
    }


@dataclass(frozen=True)
class JointTrajectory:
    """A ``trajectory_msgs/JointTrajectory`` read from YAML.

    Attributes:
        joint_names: the n joints.
        times: (K,) s from the start (time_from_start), strictly increasing.
        positions: (K, n) rad.
        velocities: (K, n) rad/s, or None when the points give none.
    """

    joint_names: tuple[str, ...]
    times: FloatArray
    positions: FloatArray
    velocities: FloatArray | None

    def positions_at(self, t: FloatArray) -> FloatArray:
        """(M, n) rad at the times t (M,) s (``trajectory_positions``)."""
        return trajectory_positions(self.times, self.positions, self.velocities, t)


def _seconds(value: Any, where: str) -> float:
    if not isinstance(value, dict) or set(value) != {"sec", "nanosec"}:
        raise InvalidInputError(f"{where}: time_from_start must be {{sec: int, nanosec: int}}, got {value!r}")
    sec, nanosec = value["sec"], value["nanosec"]
    if any(isinstance(v, bool) or not isinstance(v, int) for v in (sec, nanosec)) or not 0 <= nanosec < 10**9:
        raise InvalidInputError(f"{where}: time_from_start needs integer sec and nanosec in [0, 1e9), got {value!r}")
    return sec + nanosec * 1e-9


def _row(point: dict, key: str, n: int, where: str) -> FloatArray | None:
    values = point.get(key)
    if values is None or values == []:
        return None
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{where}: {key} must be {n} numbers") from exc
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{where}: {key} must be {n} finite numbers, got {values!r}")
    return arr


def read_trajectory(path: str | Path) -> JointTrajectory:
    """A JointTrajectory YAML (``arc-calib plan``'s output, or any in that shape) -> JointTrajectory.

    Raises:
        InvalidInputError: unreadable, not a mapping with joint_names and points, a bad joint name, a point
            with the wrong number of positions or a non-finite value, or times not strictly increasing
            (messages name the file and the point).
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InvalidInputError(f"{path}: not a readable YAML file: {exc}") from exc
    if not isinstance(data, dict) or not isinstance(data.get("joint_names"), list) \
            or not isinstance(data.get("points"), list) or not data["points"]:
        raise InvalidInputError(f"{path}: not a trajectory_msgs/JointTrajectory (a mapping with joint_names and a "
                                "non-empty list of points)")
    names = tuple(check_joint_name(n, str(path)) for n in data["joint_names"])
    if not names or len(set(names)) != len(names):
        raise InvalidInputError(f"{path}: joint_names must be non-empty and unique, got {list(names)}")
    times, positions, velocities = [], [], []
    for k, point in enumerate(data["points"]):
        where = f"{path}: point {k}"
        if not isinstance(point, dict):
            raise InvalidInputError(f"{where}: must be a mapping with positions and time_from_start")
        p = _row(point, "positions", len(names), where)
        if p is None:
            raise InvalidInputError(f"{where}: has no positions")
        positions.append(p)
        velocities.append(_row(point, "velocities", len(names), where))
        times.append(_seconds(point.get("time_from_start"), where))
    t = check_times(np.asarray(times), f"{path}: time_from_start")
    given = [v is not None for v in velocities]
    if any(given) and not all(given):
        raise InvalidInputError(f"{path}: velocities are given for some points only (give them for all or none)")
    v = np.asarray(velocities, dtype=np.float64) if all(given) else None
    return JointTrajectory(names, t, np.asarray(positions), v)


def read_camera_pose(path: str | Path) -> FloatArray:
    """A camera pose from a YAML or JSON file -> ``T_camera_base`` (4, 4) float64 (base points into the camera's
    OpenCV optical frame, metres).

    The file is one of:

    * a mapping with ``T_camera_base``: a 4x4 nested list (``arc-calib calibrate``'s result.json and a
      simulated recording's ground truth qualify);
    * a mapping with ``T_base_camera``: the inverse, the optical frame's pose in the base frame (what
      ``ros2 run tf2_ros tf2_echo BASE OPTICAL_FRAME`` prints as a matrix);
    * a mapping with ``translation`` [x, y, z] (metres) and ``quaternion_xyzw`` (or ``quaternion``)
      [x, y, z, w] of ``T_camera_base``;
    * a bare 4x4 nested list, ``T_camera_base``.

    Raises:
        InvalidInputError: unreadable, none of these shapes, or not a rigid transform.
    """  # noqa: D205
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InvalidInputError(f"{path}: not a readable YAML or JSON file: {exc}") from exc
    try:
        if isinstance(data, list):
            return check_transform(np.asarray(data, dtype=np.float64), f"{path}: T_camera_base")
        if isinstance(data, dict) and "T_camera_base" in data:
            return check_transform(np.asarray(data["T_camera_base"], dtype=np.float64), f"{path}: T_camera_base")
        if isinstance(data, dict) and "T_base_camera" in data:
            T = check_transform(np.asarray(data["T_base_camera"], dtype=np.float64), f"{path}: T_base_camera")
            return np.linalg.inv(T)
        if isinstance(data, dict) and "translation" in data:
            quat = data.get("quaternion_xyzw", data.get("quaternion"))
            t = np.asarray(data["translation"], dtype=np.float64)
            q = np.asarray(quat, dtype=np.float64)
            if t.shape != (3,) or q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-6:
                raise InvalidInputError(f"{path}: translation must be 3 numbers and quaternion_xyzw 4 numbers "
                                        "(x, y, z, w), not zero")
            R = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
            return check_transform(transform_from_rt(R, t), f"{path}: T_camera_base")
    except (TypeError, ValueError) as exc:
        if isinstance(exc, InvalidInputError):
            raise
        raise InvalidInputError(f"{path}: the camera pose is not numeric: {exc}") from exc
    raise InvalidInputError(f"{path}: not a camera pose: give T_camera_base (4x4), T_base_camera (4x4), or "
                            "translation [x, y, z] with quaternion_xyzw [x, y, z, w] (of T_camera_base)")


def dump_yaml(data: Any) -> str:
    """``data`` as block YAML (``yaml.safe_dump``, keys in the given order)."""
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)


__all__ = ["CHECK_HZ", "CUBIC_PEAK", "SEGMENT_DELTA_TOL", "JointTrajectory", "MotionScript", "PlannedSweep",
           "ScriptConfig", "ScriptContext", "check_joint_name", "check_segmentation", "dump_yaml",
           "plan_motion_script", "read_camera_pose", "read_trajectory", "segment_duration", "sweeps_document",
           "trajectory_csv", "trajectory_message", "trajectory_positions"]
