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
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from arc_env.robot.exports import write_files_atomic
from arc_env.robot.model import RobotSource
from arc_env.robot.recording import RecordingWriter
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

    def __post_init__(self) -> None:
        if not np.isfinite(self.joint_latency_s) or abs(self.joint_latency_s) > MAX_JOINT_LATENCY_S:
            raise InvalidInputError(f"the joint latency must be within +-{MAX_JOINT_LATENCY_S * 1e3:.0f} ms, "
                                    f"got {self.joint_latency_s * 1e3} ms")


def record_episode(settings: RecordSettings, on_motion: Callable[[str], None] | None = None) -> dict:
    """Run the episode and write the recording and its ground truth; returns the ground truth dict.

    ``on_motion`` is called with a one-line status after each recorded motion (a progress display).

    Raises:
        InvalidInputError: the output exists, or the robot / camera settings are invalid.
    """
    s = settings
    if s.motions < 1:
        raise InvalidInputError("--motions must be >= 1")
    out = Path(s.out)
    truth_path = ground_truth_path(out)
    if out.exists() or truth_path.exists():
        raise InvalidInputError(f"{out if out.exists() else truth_path}: already exists; choose a new directory")
    fx = s.fx if s.fx is not None else 1380.0 * s.width / 1920.0
    target = CameraIntrinsics(K=CameraIntrinsics.from_fov(fx, s.width, s.height).K, dist=np.asarray(s.dist),
                              width=s.width, height=s.height)
    distorter = Distorter(target) if target.dist.size and np.any(target.dist != 0) else None
    render_fx = distorter.pinhole.K[0, 0] if distorter else fx
    scene = SceneConfig(robot=s.robot, width=s.width, height=s.height, fx=render_fx,
                        **realism_settings(s.realism, s.appearance))
    env = ArcCalibEnv(EnvConfig(scene=scene, max_motions=s.motions, oracle_keypoints=True,
                                terminate_on_convergence=False, fps=s.fps))
    writer: RecordingWriter | None = None
    try:
        obs, _ = env.reset(seed=s.seed)
        planner = RandomPlanner(env.session, np.random.default_rng(s.seed))
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
        truth = {
            "note": "simulation ground truth of the recording beside this file; not part of the recording",
            "recording": out.name,
            "T_camera_base": T_camera_base.tolist(),
            "translation": T_camera_base[:3, 3].tolist(),
            "quaternion_xyzw": quaternion_xyzw_from_matrix(T_camera_base[:3, :3]).tolist(),
            "seed": s.seed,
            "motions": s.motions,
            "robot": s.robot.path or "gymnasium-robotics Franka Panda",
            "joint_latency_s": s.joint_latency_s,
        }
        writer.close()
        writer = None
        write_files_atomic({truth_path: json.dumps(truth, indent=2) + "\n"})
        return truth
    finally:
        if writer is not None:
            writer.abort()
        env.close()
