"""``arc-calib record``: a simulated episode written as a recording, its ground truth beside it.

The episode is ``ArcCalib-v0`` with the random planner. The env runs in oracle-keypoint mode: its
calibrator (fed projected mesh points) only steers the planner's in-view check, while the recording
gets what a real robot would give: rendered frames and the joint positions of every frame. The true
``T_camera_base`` is written to ``<out>.ground_truth.json``, outside the recording directory, so that
nothing reading the recording can see it.

A camera with distortion (``--dist``) is simulated by rendering a pinhole camera with a wider view and
resampling every frame through the distortion (``arc_env.sim.distortion.Distorter``).

A joint log whose clock disagrees with the camera's (``--joint-latency-ms``, ``RecordSettings.joint_latency_s``):
a real rig pairs each frame with the joint reading stamped at the frame's time, and when the joint states
are stamped late by L seconds, that reading is where the joint was L seconds before the frame was exposed.
The frames are rendered at the true positions; the swept joint's logged position is the true one minus
L times its velocity (the sweep's per-frame step times the frame rate, at most ``EnvConfig.joint_speed``),
the same shift at every frame (the sweep is modelled at constant speed from its first frame to its last).
L < 0 is a log that leads the camera. The other joints stand still, so their readings are unaffected.

``--format bag|mcap`` (``record_bag``): the episode as one continuous ROS 2 bag (sqlite3 or MCAP storage,
the rosbags writer, ``arc_env.robot.bag.BagWriter``), as a rig's ``ros2 bag record`` would store it: the
arm rests, transits to each motion's Q along the env's executed transit (its waypoints joined at
``TRANSIT_SPEED``, several joints at once), rests ``REST_S``, turns J by Delta at ``EnvConfig.joint_speed``,
rests again. The camera (``camera_info`` once, then images stamped with their exposure time, rgb8 or JPEG)
runs at ``fps`` throughout, transits included; ``/joint_states`` at ``joint_hz`` on its own clock, stamped
``joint_latency_s`` late: a joint sample of true time t carries the stamp t + L, so the time offset of
``arc_env.robot.timing`` is d = L. Frames are rendered at the true configuration of their exposure time
(clean camera only). Beside the bag: ``<out>.ground_truth.json`` and the robot model in ``<out>.robot/``.

``--trajectory FILE.yaml`` (``record_trajectory``): instead of planning, the simulator replays a
``trajectory_msgs/JointTrajectory`` YAML (``arc-calib plan``'s) as a robot's controller would
(``replay_positions``: cubics through the points' positions and velocities, linear without velocities) and
records it -- as a bag, or with ``--format dir`` as a format-2 recording of the motions that segmentation
finds in the joint log. ``--camera-pose FILE`` places the camera (else it is sampled from the seed). The
replay checks joint names and limits, not collisions: the arm goes where the script says.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arc_env.robot.bag import BagWriter
from arc_env.robot.exports import write_files_atomic
from arc_env.robot.model import RobotSource
from arc_env.robot.motion_script import read_trajectory, trajectory_positions
from arc_env.robot.recording import RecordingWriter, write_robot_model
from arc_env.robot.segmentation import segment_motions
from arc_env.sim.distortion import Distorter
from arc_env.sim.env import ArcCalibEnv, EnvConfig
from arc_env.sim.imaging import realism_settings
from arc_env.sim.scene import SceneConfig
from planners.random_planner import RandomPlanner
from solver.arrays import FloatArray
from solver.errors import ArcCalibError, InvalidInputError
from solver.frames import quaternion_xyzw_from_matrix
from solver.observations import CameraIntrinsics

#: Largest joint-log latency ``record`` simulates, s (real rigs are off by milliseconds to a few hundred).
MAX_JOINT_LATENCY_S = 1.0
#: What ``record`` writes: a recording directory (format 1), a ROS 2 bag with sqlite3 or with MCAP storage.
FORMATS = ("dir", "bag", "mcap")
#: rad/s: the fastest joint's speed along a transit in a bag (a transit takes at least ``MIN_TRANSIT_S``).
TRANSIT_SPEED = 1.0
MIN_TRANSIT_S = 0.3
#: s: the arm rests this long before and after each exploratory motion in a bag.
REST_S = 0.4
#: s: the camera clock's reading when a bag starts (any epoch; this one looks like ROS time in 2023).
BAG_EPOCH_S = 1_700_000_000.0


def robot_dir_path(bag: Path) -> Path:
    """Where ``record --format bag|mcap`` puts the robot model of a bag: ``<bag>.robot/`` beside it."""
    bag = Path(bag)
    return bag.with_name(bag.name + ".robot")


def ground_truth_path(recording: Path) -> Path:
    """Where ``record`` puts the ground truth of a recording: ``<recording>.ground_truth.json`` beside it."""
    recording = Path(recording)
    return recording.with_name(recording.name + ".ground_truth.json")


def joint_velocity(deltas: FloatArray, fps: float) -> float:
    """The sweeping joint's velocity, rad/s: deltas (F,) rad of its frames at ``fps`` Hz, evenly spaced."""
    return float(deltas[1] - deltas[0]) * fps if len(deltas) > 1 else 0.0


@dataclass(frozen=True)
class RecordSettings:
    """What ``record_episode`` records.

    Attributes:
        out: the recording directory to create.
        motions: executed motions.
        seed: seeds the camera pose, the planner and the env.
        width: image width, px.
        height: image height, px.
        fx: focal length, px (None: 1380 scaled with the width, a D415-like camera).
        dist: OpenCV distortion of the simulated camera ((0,): none).
        video: one MP4 per motion instead of PNG frames.
        fps: camera frame rate, Hz (the joint turns at 1 rad/s, so this sets the frames per motion).
        robot: the robot.
        realism: "clean" or "realistic" camera (``arc_env.sim.imaging.realism_settings``).
        appearance: the robot's surface (None: the realism's default).
        joint_latency_s: how late the joint log is stamped relative to the camera, s (< 0: early); the
            logged positions of the sweeping joint lag the frames by this times its velocity. 0: exact.
        format: "dir" (a recording, format 1), "bag" (ROS 2, sqlite3) or "mcap" (ROS 2, MCAP).
        image_encoding: a bag's images: "rgb8" (sensor_msgs/Image) or "jpeg" (CompressedImage).
        joint_hz: a bag's joint_states rate, Hz.
        trajectory: a JointTrajectory YAML (``arc-calib plan``'s) to replay instead of planning motions
            (``record_trajectory``); ``motions`` is then ignored.
        camera_pose: (4, 4) float64 ``T_camera_base`` of the simulated camera; None samples one from ``seed``.
        background: what stands behind the robot (``SceneConfig.background``; the lab drawn from ``seed``).
    """

    out: Path
    motions: int = 12
    seed: int = 0
    width: int = 1920
    height: int = 1080
    fx: float | None = None
    dist: tuple[float, ...] = ()
    video: bool = False
    fps: float = 30.0
    robot: RobotSource = RobotSource()
    realism: str = "clean"
    appearance: str | None = None
    joint_latency_s: float = 0.0
    format: str = "dir"
    image_encoding: str = "jpeg"
    joint_hz: float = 200.0
    trajectory: Path | None = None
    camera_pose: FloatArray | None = None
    background: str = "floor"

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise InvalidInputError(f"--format must be one of {FORMATS}, got {self.format!r}")
        if self.image_encoding not in ("rgb8", "jpeg"):
            raise InvalidInputError(f"--image-encoding must be rgb8 or jpeg, got {self.image_encoding!r}")
        if not np.isfinite(self.joint_hz) or self.joint_hz <= 0:
            raise InvalidInputError(f"the joint rate must be > 0 Hz, got {self.joint_hz}")
        if not np.isfinite(self.joint_latency_s) or abs(self.joint_latency_s) > MAX_JOINT_LATENCY_S:
            raise InvalidInputError(f"the joint latency must be within +-{MAX_JOINT_LATENCY_S * 1e3:.0f} ms, "
                                    f"got {self.joint_latency_s * 1e3} ms")


#: The ground truth's note beside a recording directory.
_RECORDING_NOTE = "simulation ground truth of the recording beside this file; not part of the recording"


def _ground_truth(note: str, out: Path, T_camera_base: FloatArray, s: RecordSettings, **more: object) -> dict:
    """The ground-truth file's fields every format writes (the true pose (4, 4), three ways), then ``more``."""
    return {"note": note, "recording": out.name, "T_camera_base": T_camera_base.tolist(),
            "translation": T_camera_base[:3, 3].tolist(),
            "quaternion_xyzw": quaternion_xyzw_from_matrix(T_camera_base[:3, :3]).tolist(),
            "seed": s.seed, "robot": s.robot.path or "gymnasium-robotics Franka Panda",
            "joint_latency_s": s.joint_latency_s, **more}


def record_episode(settings: RecordSettings, on_motion: Callable[[str], None] | None = None) -> dict:
    """Run the episode and write the recording and its ground truth; returns the ground truth dict.

    ``on_motion`` is called with a one-line status after each recorded motion (a progress display).

    Raises:
        InvalidInputError: the output exists, or the robot / camera settings are invalid.
    """
    s = settings
    if s.motions < 1 and s.trajectory is None:
        raise InvalidInputError("--motions must be >= 1")
    out = Path(s.out)
    truth_path = ground_truth_path(out)
    beside = [out, truth_path] + ([robot_dir_path(out)] if s.format != "dir" else [])
    for path in beside:
        if path.exists():
            raise InvalidInputError(f"{path}: already exists; choose a new directory")
    if s.format != "dir" and (s.realism != "clean" or s.appearance is not None):
        raise InvalidInputError("--format bag/mcap renders the clean camera only (no --realism realistic or "
                                "--appearance yet)")
    fx = s.fx if s.fx is not None else 1380.0 * s.width / 1920.0
    target = CameraIntrinsics(K=CameraIntrinsics.from_fov(fx, s.width, s.height).K, dist=np.asarray(s.dist),
                              width=s.width, height=s.height)
    distorter = Distorter(target) if target.dist.size and np.any(target.dist != 0) else None
    render_fx = distorter.pinhole.K[0, 0] if distorter else fx
    scene = SceneConfig(robot=s.robot, width=s.width, height=s.height, fx=render_fx, background=s.background,
                        background_seed=s.seed, **realism_settings(s.realism, s.appearance))
    env = ArcCalibEnv(EnvConfig(scene=scene, max_motions=s.motions, oracle_keypoints=True,
                                terminate_on_convergence=False, fps=s.fps))
    writer: RecordingWriter | None = None
    try:
        obs, _ = env.reset(seed=s.seed, options={"camera_pose": s.camera_pose})
        if s.trajectory is not None:
            return record_trajectory(s, env, target, distorter, on_motion)
        planner = RandomPlanner(env.session, np.random.default_rng(s.seed))
        if s.format != "dir":
            return _record_bag(s, env, planner, obs, target, distorter, on_motion)
        writer = RecordingWriter(out, target, s.robot, video=s.video, fps=env.config.fps)
        names = env.scene.robot.joint_names
        for _ in range(s.motions):
            action = planner.plan(obs)
            obs, _, _, _, info = env.step(action)
            if info["refused"]:
                raise ArcCalibError(f"the env refused the planner's motion: {info['refused']}")
            q, joint, delta = np.asarray(action["Q"], float), int(action["J"]), float(action["delta"][0])
            deltas = env.sweep_deltas(delta)
            frames = env.scene.render_sweep(q, joint, deltas, env.config.joint_speed,
                                            np.random.default_rng([s.seed, writer.n_motions]))
            if distorter:
                frames = [distorter(image) for image in frames]
            positions = np.tile(q, (len(deltas), 1))
            positions[:, joint] += deltas
            if s.joint_latency_s:
                positions[:, joint] -= s.joint_latency_s * joint_velocity(deltas, env.config.fps)
            writer.add_motion(names, positions, frames)
            if on_motion is not None:
                on_motion(f"joint {names[joint]}, delta {delta:+.2f} rad, {len(deltas)} frames")
        T_camera_base = env.T_camera_base_true
        truth = _ground_truth(_RECORDING_NOTE, out, T_camera_base, s, motions=s.motions)
        writer.close()
        writer = None
        write_files_atomic({truth_path: json.dumps(truth, indent=2) + "\n"})
        return truth
    finally:
        if writer is not None:
            writer.abort()
        env.close()


def _bag_script(s: RecordSettings, env: ArcCalibEnv, planner: RandomPlanner, obs: dict,
                on_motion: Callable[[str], None] | None) -> tuple[FloatArray, FloatArray, list[dict]]:
    """Execute the motions in the env; the arm's piecewise-linear trajectory as knots (time s (K,), q (K, n) rad).

    Returns the knots and, per motion, its joint, Delta and the times its turn starts and stops (s).
    """
    names = env.scene.robot.joint_names
    times: list[float] = []
    qs: list[FloatArray] = []
    script: list[dict] = []
    for _ in range(s.motions):
        action = planner.plan(obs)
        obs, _, _, _, info = env.step(action)
        if info["refused"]:
            raise ArcCalibError(f"the env refused the planner's motion: {info['refused']}")
        q, joint, delta = np.asarray(action["Q"], float), int(action["J"]), float(action["delta"][0])
        transit = env.session.last_transit
        path = np.asarray(transit.waypoints, float) if transit is not None else np.array([q])
        if not times:  # the arm rests where it starts
            times += [0.0, REST_S]
            qs += [path[0], path[0]]
        for a, b in zip([qs[-1], *path[:-1]], path, strict=True):
            step = float(np.max(np.abs(b - a)))
            if step > 0:
                times.append(times[-1] + max(step / TRANSIT_SPEED, MIN_TRANSIT_S))
                qs.append(b)
        times.append(times[-1] + REST_S)
        qs.append(q)
        end = q.copy()
        end[joint] += delta
        start = times[-1]
        times.append(start + abs(delta) / env.config.joint_speed)
        qs.append(end)
        script.append({"joint": names[joint], "delta": delta, "t_start": start, "t_stop": times[-1]})
        times.append(times[-1] + REST_S)
        qs.append(end)
        if on_motion is not None:
            on_motion(f"planned: joint {names[joint]}, delta {delta:+.2f} rad")
    return np.asarray(times), np.asarray(qs), script


def _record_bag(s: RecordSettings, env: ArcCalibEnv, planner: RandomPlanner, obs: dict, target: CameraIntrinsics,
                distorter: Distorter | None, on_motion: Callable[[str], None] | None) -> dict:
    """``record_episode`` for ``format`` bag or mcap (the module doc); returns the ground truth dict."""
    knots_t, knots_q, script = _bag_script(s, env, planner, obs, on_motion)

    def q_at(t: FloatArray) -> FloatArray:
        return np.column_stack([np.interp(t, knots_t, knots_q[:, j]) for j in range(knots_q.shape[1])])

    return _write_bag(s, env, q_at, float(knots_t[-1]), target, distorter, {"script": script})


def replay_positions(s: RecordSettings, env: ArcCalibEnv) -> tuple[Callable[[FloatArray], FloatArray], float, str]:
    """The simulator's controller for ``s.trajectory``: q(t) (times (M,) s -> (M, n) rad), the duration (s), a label.

    The trajectory's joints are matched to the robot's by name (the same set, in any order) and its points
    must be within the joint limits; the arm holds the first point until its time, then follows the
    points as ``arc_env.robot.motion_script.trajectory_positions`` does (cubics through the points'
    positions and velocities, linear without velocities), and holds the last.

    Raises:
        InvalidInputError: an unreadable trajectory, other joints than the robot's, or a point outside the limits.
    """
    path = Path(s.trajectory or "")
    trajectory = read_trajectory(path)
    robot = env.scene.robot
    names = robot.joint_names
    if sorted(trajectory.joint_names) != sorted(names):
        raise InvalidInputError(f"{path}: joint_names {list(trajectory.joint_names)} are not the robot's arm joints "
                                f"{names}")
    order = [trajectory.joint_names.index(n) for n in names]
    positions = trajectory.positions[:, order]
    velocities = trajectory.velocities[:, order] if trajectory.velocities is not None else None
    bad = np.argwhere((positions < robot.lower - 1e-6) | (positions > robot.upper + 1e-6))
    if len(bad):
        k, j = (int(v) for v in bad[0])
        raise InvalidInputError(f"{path}: point {k}: {names[j]} = {positions[k, j]:.4f} rad is outside its limits "
                                f"[{robot.lower[j]:.4f}, {robot.upper[j]:.4f}]")

    def q_at(t: FloatArray) -> FloatArray:
        return trajectory_positions(trajectory.times, positions, velocities, t)

    return q_at, float(trajectory.times[-1]), path.name


def record_trajectory(s: RecordSettings, env: ArcCalibEnv, target: CameraIntrinsics, distorter: Distorter | None,
                      on_second: Callable[[str], None] | None = None) -> dict:
    """``record_episode`` with ``s.trajectory``: the arm replays it while the camera and joint log record.

    The camera renders at ``fps`` and the joints are logged at ``joint_hz`` from t = 0 to the last point's
    time, on the trajectory's clock (``replay_positions``). Bag formats are one continuous bag, as
    ``record --format bag|mcap`` writes. ``dir`` writes a recording directory in format 2: the exploratory
    motions found by segmenting the joint log (``arc_env.robot.segmentation``, as ``calibrate`` segments a
    bag), each with the frames exposed during it and the joint log over it, stamped ``joint_latency_s`` late.
    Returns the ground truth dict (also written beside the output).
    """
    q_at, duration, label = replay_positions(s, env)
    about = {"trajectory": label, "motions": None, "duration_s": duration}
    if s.format != "dir":
        return _write_bag(s, env, q_at, duration, target, distorter, about, on_second)
    out = Path(s.out)
    names = env.scene.robot.joint_names
    joint_t = np.arange(0.0, duration, 1.0 / s.joint_hz)
    joint_q = q_at(joint_t)
    segments, _ = segment_motions(joint_t, joint_q, names)
    frame_t = np.arange(0.0, duration, 1.0 / s.fps)
    writer: RecordingWriter | None = RecordingWriter(out, target, s.robot, video=s.video, fps=s.fps)
    seconds = _Seconds(duration, on_second)
    try:
        for k, seg in enumerate(segments):
            frames_in = frame_t[(frame_t >= seg.t_start) & (frame_t <= seg.t_stop)]
            logged = (joint_t >= seg.t_start - 0.1) & (joint_t <= seg.t_stop + 0.1)
            frames = []
            for q in q_at(frames_in):
                env.scene.robot.set_q(q)
                image = env.scene.render()
                frames.append(distorter(image) if distorter else image)
            writer.add_motion(names, joint_q[logged], frames, frame_times=frames_in,
                              joint_times=joint_t[logged] + s.joint_latency_s)
            seconds.until(seg.t_stop, f"motion {k}: {names[seg.joint or 0]} delta {seg.delta:+.3f} rad, "
                                      f"{len(frames)} frames")
        seconds.until(math.inf)
        T_camera_base = env.T_camera_base_true
        truth = _ground_truth(_RECORDING_NOTE, out, T_camera_base, s, format=s.format,
                              time_offset_s=s.joint_latency_s, **about,
                              segments=[{"joint": names[seg.joint or 0], "delta": seg.delta, "t_start": seg.t_start,
                                         "t_stop": seg.t_stop} for seg in segments])
        writer.close()
        writer = None
        write_files_atomic({ground_truth_path(out): json.dumps(truth, indent=2) + "\n"})
        return truth
    finally:
        if writer is not None:
            writer.abort()


class _Seconds:
    """Calls ``report`` once for every whole second of a recording passed (a progress display's steps)."""

    def __init__(self, duration: float, report: Callable[[str], None] | None):
        self.duration, self.report, self.done = duration, report, 0

    def until(self, t: float, status: str = "") -> None:
        """Report every whole second up to t s (the last one at the end of the recording)."""
        last = max(1, math.ceil(self.duration))
        whole = last if t >= self.duration else min(int(t), last)
        while self.report is not None and self.done < whole:
            self.done += 1
            self.report(status or f"{self.done} s of {self.duration:.0f} s")


def _ns(t: float) -> int:
    """Bag stamp (ns) of the time t s from the start of a simulated recording."""
    return int(round((BAG_EPOCH_S + t) * 1e9))


def _write_bag(s: RecordSettings, env: ArcCalibEnv, q_at: Callable[[FloatArray], FloatArray], duration: float,
               target: CameraIntrinsics, distorter: Distorter | None, about: dict,
               on_second: Callable[[str], None] | None = None) -> dict:
    """Write the arm's motion ``q_at`` (times (M,) s -> (M, n) rad) over [0, duration) s as a bag (module doc).

    ``about`` is added to the ground truth; ``on_second`` is called once per second of recording rendered.
    Returns the ground truth dict.
    """
    out = Path(s.out)
    names = env.scene.robot.joint_names
    ns = _ns
    frame_t = np.arange(0.0, duration, 1.0 / s.fps)
    joint_t = np.arange(0.0, duration, 1.0 / s.joint_hz)
    frame_q, joint_q = q_at(frame_t), q_at(joint_t)
    joint_v = np.gradient(joint_q, joint_t, axis=0)
    seconds = _Seconds(duration, on_second)
    events = sorted([(ns(t), 0, k) for k, t in enumerate(frame_t)]
                    + [(ns(t + s.joint_latency_s), 1, k) for k, t in enumerate(joint_t)])
    robot_dir = robot_dir_path(out)
    writer: BagWriter | None = None
    try:
        model_name, base = write_robot_model(s.robot, robot_dir)
        writer = BagWriter(out, "mcap" if s.format == "mcap" else "sqlite3", s.image_encoding)
        writer.camera_info(ns(0.0), target)
        for stamp, kind, k in events:
            if kind == 1:
                writer.joints(stamp, names, joint_q[k], joint_v[k])
                continue
            seconds.until(frame_t[k])
            env.scene.robot.set_q(frame_q[k])
            image = env.scene.render()
            writer.image(stamp, distorter(image) if distorter else image)
        writer.close()
        writer = None
        seconds.until(math.inf)
        T_camera_base = env.T_camera_base_true
        truth = _ground_truth("simulation ground truth of the bag beside this file; not part of the bag", out,
                              T_camera_base, s, **{"format": s.format, "motions": s.motions,
                                                   "robot_model": str(robot_dir / model_name), "base_body": base,
                                                   "time_offset_s": s.joint_latency_s,
                                                   "camera_epoch_s": BAG_EPOCH_S, **about})
        write_files_atomic({ground_truth_path(out): json.dumps(truth, indent=2) + "\n"})
        return truth
    except BaseException:
        if writer is not None:
            writer.abort()
        shutil.rmtree(out, ignore_errors=True)
        shutil.rmtree(robot_dir, ignore_errors=True)
        raise
