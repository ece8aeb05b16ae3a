"""``SimulatedDriver``: the ``arc_env.robot.driver.RobotDriver`` protocol on a MuJoCo scene.

``arc-calib run --driver arc_env.sim.driver:SimulatedDriver`` calibrates it online exactly as a real
robot would be: the session sees frames and joint readings only; the true camera pose
(``T_camera_base_true``) is kept for the final report.
"""

from __future__ import annotations

import numpy as np

from arc_env.robot.driver import Sweep
from arc_env.robot.model import RobotSource
from arc_env.sim.env import EnvConfig
from arc_env.sim.scene import Scene, SceneConfig
from solver.arrays import FloatArray
from solver.synthetic import sample_camera_pose


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
        self.joint_names = tuple(self.scene.robot.joint_names)
        self.intrinsics = self.scene.intrinsics
        config = EnvConfig()
        self.T_camera_base_true = sample_camera_pose(np.random.default_rng(seed), np.asarray(config.camera_target),
                                                     config.camera_distance, config.camera_max_roll)
        self.scene.set_camera(self.T_camera_base_true)
        self.fps, self.joint_speed = fps, joint_speed
        self._rng = np.random.default_rng([seed, 1])  # camera effects, if the scene has any
        self.n_sweeps = 0

    @property
    def joint_limits(self) -> tuple[FloatArray, FloatArray]:
        """The model's limits, (lower, upper) rad."""
        return self.scene.robot.lower.copy(), self.scene.robot.upper.copy()

    def move_to(self, q: FloatArray) -> None:
        """Teleport (the simulation has no transit)."""
        self.scene.robot.set_q(self.scene.robot.check_q(q))

    def sweep(self, joint: int, delta: float) -> Sweep:
        """Render the sweep at ``fps`` while the joint turns at ``joint_speed``."""
        q = self.scene.robot.q
        n = max(3, int(np.ceil(abs(delta) / self.joint_speed * self.fps)) + 1)
        deltas = np.linspace(0.0, delta, n)
        frames = self.scene.render_sweep(q, joint, deltas, self.joint_speed, self._rng)
        positions = np.tile(q, (n, 1))
        positions[:, joint] += deltas
        self.n_sweeps += 1
        return Sweep(frames, positions)

    def close(self) -> None:
        """Free the renderer."""
        self.scene.close()
