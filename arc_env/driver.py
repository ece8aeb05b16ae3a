"""Online calibration: what ARC-Calib needs from a robot and its camera, and the simulator's version of it.

``RobotDriver`` is the whole interface (see ``docs/driver.md`` for what a real driver over ROS 2 or a
vendor SDK must do): the robot's model and joint order, its joint limits, a camera's intrinsics, a way to
move to a configuration, and an exploratory *sweep* -- turn one joint by delta while the camera records,
returning the frames and the joint positions read at each frame's exposure.

``DriverEnv`` adapts a driver to the planners, which take an ``ArcCalibEnv``: the env's scene becomes a
*digital twin* built from the driver's robot model (kinematics, collision checks of every start
configuration and sweep, the in-view test with the current estimate), while motions are executed by the
driver and its frames tracked. ``SimulatedDriver`` implements the protocol on a MuJoCo scene.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from arc_env.env import ArcCalibEnv, EnvConfig
from arc_env.scene import RobotSource, Scene, SceneConfig
from arc_env.tracking import track_keypoints
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics, MotionObservation
from solver.synthetic import sample_camera_pose

FloatArray = NDArray[np.float64]
ImageArray = NDArray[np.uint8]


@dataclass(frozen=True)
class Sweep:
    """What a driver returns for one exploratory motion.

    Attributes:
        frames: F >= 3 images (H, W, 3) uint8 RGB, in capture order.
        positions: (F, n_joints) float64, rad: every joint's position at each frame's exposure, in
            ``RobotDriver.joint_names`` order.
    """

    frames: list[ImageArray]
    positions: FloatArray


@runtime_checkable
class RobotDriver(Protocol):
    """A robot with a fixed camera, as ARC-Calib drives it (all angles rad, images RGB uint8).

    Attributes:
        robot: the robot's kinematic model (MJCF or URDF file and base body) -- the same robot, with
            joint names as in ``joint_names``.
        joint_names: the arm's revolute joints in the order of every q this interface uses.
        intrinsics: the camera's intrinsics (K, OpenCV distortion, image size).
    """

    robot: RobotSource
    joint_names: tuple[str, ...]
    intrinsics: CameraIntrinsics

    @property
    def joint_limits(self) -> tuple[FloatArray, FloatArray]:
        """(lower, upper), each (n_joints,) rad: where the planners may send the joints."""
        ...

    def move_to(self, q: FloatArray) -> None:
        """Bring the arm to q (n_joints,) rad and wait until it is there.

        The path is the driver's business (e.g. MoveIt or the vendor's collision-aware motion); ARC-Calib
        checks only q itself and the sweeps against its model.
        """
        ...

    def sweep(self, joint: int, delta: float) -> Sweep:
        """Turn joint ``joint`` (index into ``joint_names``) by ``delta`` rad from where it is, recording.

        The other joints are held. Frames cover the whole turn, from before it starts to after it ends;
        ``Sweep.positions`` holds every joint's reading at each frame's exposure.
        """
        ...


class SimulatedDriver:
    """The ``RobotDriver`` of the MuJoCo scene: a camera at a random pose (``T_camera_base_true``).

    Args:
        width: image width, px.
        height: image height, px.
        seed: seeds the camera pose.
        robot: the robot (default: the gymnasium-robotics Panda).
        fps: frames per second while sweeping at ``joint_speed``.
        joint_speed: rad/s.
    """

    def __init__(self, width: int = 1920, height: int = 1080, seed: int = 0, robot: RobotSource | None = None,
                 fps: float = 30.0, joint_speed: float = 1.0):
        self.robot = robot or RobotSource()
        self.scene = Scene(SceneConfig(robot=self.robot, width=width, height=height))
        self.joint_names = tuple(self.scene.joint_names)
        self.intrinsics = self.scene.intrinsics
        config = EnvConfig()
        self.T_camera_base_true = sample_camera_pose(np.random.default_rng(seed), np.asarray(config.camera_target),
                                                     config.camera_distance, config.camera_max_roll)
        self.scene.set_camera(self.T_camera_base_true)
        self.fps, self.joint_speed = fps, joint_speed
        self.n_sweeps = 0

    @property
    def joint_limits(self) -> tuple[FloatArray, FloatArray]:
        """The model's limits, (lower, upper) rad."""
        return self.scene.lower.copy(), self.scene.upper.copy()

    def move_to(self, q: FloatArray) -> None:
        """Teleport (the simulation has no transit)."""
        self.scene.set_q(self.scene.check_q(q))

    def sweep(self, joint: int, delta: float) -> Sweep:
        """Render the sweep at ``fps`` while the joint turns at ``joint_speed``."""
        q = self.scene.q
        n = max(3, int(np.ceil(abs(delta) / self.joint_speed * self.fps)) + 1)
        deltas = np.linspace(0.0, delta, n)
        frames = []
        for d in deltas:
            self.scene.set_swept(q, joint, d)
            frames.append(self.scene.render())
        positions = np.tile(q, (n, 1))
        positions[:, joint] += deltas
        self.n_sweeps += 1
        return Sweep(frames, positions)

    def close(self) -> None:
        """Free the renderer."""
        self.scene.close()


class DriverEnv(ArcCalibEnv):
    """``ArcCalibEnv`` whose motions a ``RobotDriver`` executes; its scene is the robot's digital twin.

    The twin has no camera mount (the real camera's place is unknown) and the driver's intrinsics; the
    joint limits are the model's intersected with the driver's. Ground-truth fields of ``info``
    (``rot_error_rad``, ``trans_error_m``) and the reward are meaningless here: there is no truth.

    Args:
        driver: the robot.
        config: episode settings; its ``scene`` is replaced by the twin's.
        on_sweep: called with (motion index, q_start, joint, Sweep) after every sweep (e.g. to record it).
    """

    def __init__(self, driver: RobotDriver, config: EnvConfig | None = None, on_sweep: Any = None):
        cam = driver.intrinsics
        robot = RobotSource(path=driver.robot.path, base_body=driver.robot.base_body,
                            joints=tuple(driver.joint_names), home=())
        twin = SceneConfig(robot=robot, width=cam.width, height=cam.height, fx=float(cam.K[0, 0]),
                           camera_mount=False, speckle=False)
        super().__init__(replace(config or EnvConfig(), scene=twin, oracle_keypoints=False))
        self.driver = driver
        self.intrinsics = cam  # the calibrator uses the real camera's K and distortion
        self.on_sweep = on_sweep
        lower, upper = (np.asarray(a, dtype=np.float64) for a in driver.joint_limits)
        n = self.scene.n_joints
        if lower.shape != (n,) or upper.shape != (n,) or np.any(lower >= upper):
            raise InvalidInputError(f"driver joint_limits must be two ({n},) arrays with lower < upper")
        self.scene.lower = np.maximum(self.scene.lower, lower)
        self.scene.upper = np.minimum(self.scene.upper, upper)
        self.action_space["Q"] = spaces.Box(self.scene.lower, self.scene.upper, (n,), np.float64)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start the episode; the twin's camera pose is a placeholder (the truth is unknown)."""
        return super().reset(seed=seed, options={**(options or {}), "camera_pose": np.eye(4)})

    def _execute(self, q: FloatArray, joint: int, delta: float) -> tuple[MotionObservation, int, dict[str, float]]:
        t0 = time.perf_counter()
        self.driver.move_to(q)
        sweep = self.driver.sweep(joint, delta)
        positions = np.asarray(sweep.positions, dtype=np.float64)
        n = self.scene.n_joints
        if len(sweep.frames) < 3 or positions.shape != (len(sweep.frames), n) or not np.all(np.isfinite(positions)):
            raise InvalidInputError(f"driver sweep must return >= 3 frames and finite positions "
                                    f"({len(sweep.frames)}, {n}); got {len(sweep.frames)} frames, "
                                    f"positions {positions.shape}")
        t1 = time.perf_counter()
        deltas = positions[:, joint] - positions[0, joint]
        result = track_keypoints(sweep.frames, deltas, self.config.tracker)
        self.scene.set_q(positions[-1])
        if self.on_sweep is not None:
            self.on_sweep(self.n_motions, positions[0], joint, sweep)
        seconds = {"render": t1 - t0, "tracking": time.perf_counter() - t1}
        obs = MotionObservation(q_start=positions[0], joint=joint, tracks=result.tracks)
        return obs, len(sweep.frames), seconds
