"""Online calibration: what ARC-Calib needs from a robot and its camera.

``RobotDriver`` is the whole interface (see ``docs/driver.md`` for what a real driver over ROS 2 or a
vendor SDK must do): the robot's model and joint order, its joint limits, a camera's intrinsics, a way to
move to a configuration, and an exploratory *sweep* -- turn one joint by delta while the camera records,
returning the frames and the joint positions read at each frame's exposure.

A driver is used through ``arc_env.robot.session``: a ``CalibrationSession`` on the driver's robot model
(kinematics, collision checks of every start configuration and sweep, the in-view test with the current
estimate) whose ``DriverExecutor`` has the driver execute the motions. The simulator implements the
protocol too (``arc_env.sim.driver.SimulatedDriver``). ``load_driver`` instantiates one named
``module:Class`` on the command line.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from arc_env.robot.model import RobotSource
from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics


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


def load_driver(spec: str) -> RobotDriver:
    """Instantiate ``module:Name`` (a class or factory taking no arguments) and check it is a RobotDriver.

    Raises:
        InvalidInputError: the spec is malformed, does not import, fails to construct, or lacks a member.
    """
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise InvalidInputError(f"--driver must be 'module:Class', got {spec!r}")
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise InvalidInputError(f"--driver {spec}: cannot load it: {exc}") from exc
    try:
        driver = factory()
    except Exception as exc:  # the user's code: report it, do not crash
        raise InvalidInputError(f"--driver {spec}: constructing it failed: {type(exc).__name__}: {exc}") from exc
    missing = [name for name in ("robot", "joint_names", "intrinsics", "joint_limits", "move_to", "sweep")
               if not hasattr(driver, name)]
    if missing:
        raise InvalidInputError(f"--driver {spec}: not a RobotDriver, missing {missing} (see docs/driver.md)")
    return driver
