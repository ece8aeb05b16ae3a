"""What a planner reads: the narrow ``PlanningContext`` (and its parts), never an environment's internals.

A planner chooses the next exploratory motion from the robot's model, its limits and collision checks,
the camera's intrinsics, the calibration so far and the motions already executed. Nothing here holds a
true camera pose: in simulation the truth stays in the simulator, on a real robot there is none.
``arc_env.robot.session.CalibrationSession`` implements the context (the env exposes its session), so
the same planner serves the simulator and a real robot. A renderer is optional: the simulator offers
one (image tests, depth for occlusion), a real robot may not; planners do without. The estimate reaches
a planner through ``plan(observation)`` (the env's observation; ``observation_from_estimate`` builds its
estimate keys, ``estimate_from_observation`` reads them back).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray, ImageArray, IndexArray, MaskArray
from solver.frames import transform_from_rt
from solver.motion import MotionGeometry
from solver.observations import CameraIntrinsics
from solver.pipeline import CalibrationState, CalibratorConfig, MotionReport


class RobotKinematics(Protocol):
    """The robot model a planner poses and projects (``arc_env.robot.model.RobotModel``); base frame, rad, m."""

    model: mujoco.MjModel
    data: mujoco.MjData
    arm_joints: list[int]
    n_joints: int
    qpos_adr: NDArray[np.int64]
    lower: FloatArray
    upper: FloatArray
    robot_bodies: list[int]
    base_body: int
    T_world_base: FloatArray

    @property
    def q(self) -> FloatArray:
        """(n,) rad, the model's current configuration."""
        ...

    def check_q(self, q: FloatArray) -> FloatArray:
        """Validate a configuration (n,) rad."""
        ...

    def set_q(self, q: FloatArray) -> None:
        """Pose the model at q (n,) rad."""
        ...

    def set_swept(self, q: FloatArray, joint: int, delta: float) -> None:
        """Pose the model at q (n,) rad with ``joint`` turned further by delta rad."""
        ...

    def axis_and_point(self, q: FloatArray, joint: int) -> tuple[FloatArray, FloatArray]:
        """Gamma(q, joint): unit axis (3,) and a point (3,) m on it, base frame."""
        ...

    def joint_body(self, joint: int) -> int:
        """The body arm joint ``joint`` turns."""
        ...

    def surface_points(self, joint: int) -> tuple[IndexArray, FloatArray]:
        """(P,) body ids and (P, 3) m body-frame points on the links ``joint`` moves."""
        ...

    def points_base(self, body: IndexArray, local: FloatArray) -> FloatArray:
        """(P, 3) m: body-fixed points at the current configuration, base frame."""
        ...

    def project_points(self, body: IndexArray, local: FloatArray, T_camera_base: FloatArray,
                       intrinsics: CameraIntrinsics, min_depth: float, margin_px: float = 0.0
                       ) -> tuple[FloatArray, MaskArray]:
        """(P, 2) px and (P,) visible: body-fixed points seen through a camera at ``T_camera_base``."""
        ...


class SceneRenderer(Protocol):
    """Images of the robot at a configuration (the simulator's; a real robot may have none)."""

    def render_at(self, q: FloatArray, downscale: int = 1) -> ImageArray:
        """The camera's RGB image (H // downscale, W // downscale, 3) with the arm at q (n,) rad."""
        ...

    def depth_at(self, q: FloatArray, T_camera_base: FloatArray, downscale: int = 1) -> NDArray[np.float32]:
        """Depth (m) along the optical axis per pixel with the arm at q, seen from ``T_camera_base``."""
        ...

    def prepare(self, downscale: int) -> None:
        """Set up the renderer for ``downscale`` ahead of time."""
        ...


class CalibrationView(Protocol):
    """What a planner reads of the calibrator (``solver.pipeline.Calibrator``)."""

    config: CalibratorConfig
    state: CalibrationState
    reports: list[MotionReport]

    def motion_geometry(self, index: int) -> MotionGeometry | None:
        """Stage one's axis and plane of motion ``index`` (None without an axis)."""
        ...


class CollisionQueries(Protocol):
    """Collision checks of the arm (``planners.collision.CollisionChecker``)."""

    def in_collision(self, q: FloatArray) -> tuple[bool, str]:
        """Whether q (n,) rad collides, and why."""
        ...

    def sweep_free(self, q: FloatArray, joint: int, delta: float, max_step_m: float = 0.005) -> tuple[bool, str]:
        """Whether turning ``joint`` by delta from q is free, and why not."""
        ...


class PlanningContext(Protocol):
    """Everything a planner may read; see the module docstring.

    Attributes:
        robot: the robot model (posed freely by the planner: it is a model, not the robot).
        intrinsics: the camera.
        checker: collision checks of the arm against itself and the known world.
        renderer: images for image tests and occlusion, or None.
        calibrator: the calibration so far (None before a session starts).
        executed: the executed motions, in order: (Q (n,) rad, J, delta rad).
        np_random: the session's generator (seeds a planner given no rng).
    """

    robot: RobotKinematics
    intrinsics: CameraIntrinsics
    renderer: SceneRenderer | None
    calibrator: CalibrationView | None
    executed: Sequence[tuple[FloatArray, int, float]]
    np_random: np.random.Generator

    @property
    def checker(self) -> CollisionQueries:
        """The arm's collision checker."""
        ...

    @property
    def min_delta(self) -> float:
        """rad; smallest |Delta| the session accepts."""
        ...

    @property
    def max_delta(self) -> float:
        """rad; largest |Delta| the session accepts."""
        ...

    def refusal_reason(self, q: FloatArray, joint: int, delta: float) -> str:
        """Why the session would refuse the motion (q (n,) rad, joint, delta rad), or "" if it is valid."""
        ...


def estimate_from_observation(observation: dict[str, Any]) -> FloatArray | None:
    """The estimate of ``T_camera_base`` (4, 4) an env observation holds, or None without one."""
    if not int(observation.get("has_estimate", 0)):
        return None
    R_camera_base = Rotation.from_rotvec(np.asarray(observation["rotation"], dtype=np.float64)).as_matrix()
    return transform_from_rt(R_camera_base, np.asarray(observation["translation"], dtype=np.float64))


def observation_from_estimate(T_camera_base: FloatArray | None) -> dict[str, Any]:
    """The estimate keys of an env observation: ``has_estimate``, ``rotation`` (3,) rotvec, ``translation`` (3,) m.

    The inverse of ``estimate_from_observation``; without an estimate only ``{"has_estimate": 0}``.
    """
    if T_camera_base is None:
        return {"has_estimate": 0}
    return {"has_estimate": 1, "rotation": Rotation.from_matrix(T_camera_base[:3, :3]).as_rotvec(),
            "translation": T_camera_base[:3, 3].astype(np.float64).copy()}


__all__ = ["CalibrationView", "CollisionQueries", "PlanningContext", "RobotKinematics", "SceneRenderer",
           "estimate_from_observation", "observation_from_estimate"]
