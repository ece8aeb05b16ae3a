"""Inverse kinematics with mink: arm configurations that put a link where the camera sees it well.

``IKSolver.solve`` moves the origin of a body of the arm (e.g. the body a joint turns, whose
origin is the joint's anchor on the Panda) to a target point in the robot's base frame by mink's
differential IK: a position-only frame task, a light posture task that keeps the answer near the
seed configuration (so seeds explore different arm postures), the joint limits as constraints,
and every joint that is not an arm joint (fingers) frozen. ``target_in_view`` turns a pixel and a
depth into such a target with a camera pose estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import mink
import numpy as np

from planners.context import RobotKinematics
from solver.arrays import FloatArray
from solver.camera import normalized_from_pixels
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics


@dataclass(frozen=True)
class IKConfig:
    """Settings of ``IKSolver``.

    Attributes:
        tolerance_m: m; a solution is reached when the body origin is this close to the target.
        max_iterations: differential-IK steps.
        dt: s, integration step of each velocity solve.
        posture_cost: weight of staying near the seed (relative to the position task's 1).
        damping: Levenberg-Marquardt damping of the velocity solve.
        limit_margin: rad; the seed is moved this far inside the arm's joint limits.
        solver: the QP solver mink hands to qpsolvers.
    """

    tolerance_m: float = 0.005
    max_iterations: int = 150
    dt: float = 0.1
    posture_cost: float = 0.02
    damping: float = 1e-3
    limit_margin: float = 0.02
    solver: str = "daqp"

    def __post_init__(self) -> None:
        if self.tolerance_m <= 0 or self.max_iterations < 1 or self.dt <= 0 or self.posture_cost < 0:
            raise InvalidInputError("tolerance_m, max_iterations and dt must be > 0, posture_cost >= 0")


@dataclass(frozen=True)
class IKResult:
    """Outcome of ``IKSolver.solve``.

    Attributes:
        q: (n,) rad, the arm configuration reached (within the limits).
        error_m: distance of the body origin from the target at q, m.
        iterations: steps taken.
        reached: error_m <= the tolerance.
    """

    q: FloatArray
    error_m: float
    iterations: int
    reached: bool


class IKSolver:
    """Position IK for one body of a robot model's arm.

    Args:
        robot: the robot model (its MuJoCo model, arm joints and base frame; its own state is untouched).
        config: settings.
    """

    def __init__(self, robot: RobotKinematics, config: IKConfig | None = None):
        self.robot = robot
        self.config = config or IKConfig()
        m = robot.model
        self._configuration = mink.Configuration(m)
        self._posture = mink.PostureTask(m, cost=self.config.posture_cost)
        arm_dofs = {int(m.jnt_dofadr[j]) for j in robot.arm_joints}
        frozen = [d for d in range(m.nv) if d not in arm_dofs]
        self._constraints = [mink.DofFreezingTask(m, dof_indices=frozen)] if frozen else []
        # no margin inside mink: frozen joints resting on a limit (open fingers at 0) would be infeasible;
        # the seed is clipped ``limit_margin`` inside the arm's limits instead
        self._limits = [mink.ConfigurationLimit(m)]
        self._tasks: dict[int, mink.FrameTask] = {}

    def _task(self, body: int) -> mink.FrameTask:
        if body not in self._tasks:
            self._tasks[body] = mink.FrameTask(body, "body", position_cost=1.0, orientation_cost=0.0)
        return self._tasks[body]

    def solve(self, body: int, target_base: FloatArray, q_seed: FloatArray) -> IKResult:
        """Move body's origin to target_base (3,) m (base frame), starting from q_seed (n,) rad.

        Raises:
            InvalidInputError: the body is not a moving body of the arm, or the inputs are malformed.
        """
        s, c = self.robot, self.config
        if body not in s.robot_bodies or body == s.base_body:
            raise InvalidInputError(f"body {body} is not a moving body of the arm")
        target_base = np.asarray(target_base, dtype=np.float64).reshape(-1)
        if target_base.shape != (3,) or not np.all(np.isfinite(target_base)):
            raise InvalidInputError(f"target must be 3 finite numbers, got {target_base!r}")
        q_seed = s.check_q(q_seed)
        target_world = s.T_world_base[:3, :3] @ target_base + s.T_world_base[:3, 3]
        qpos = s.data.qpos.copy()
        qpos[s.qpos_adr] = np.clip(q_seed, s.lower + c.limit_margin, s.upper - c.limit_margin)
        conf = self._configuration
        conf.update(qpos)
        self._posture.set_target(qpos)
        task = self._task(body)
        task.set_target(mink.SE3.from_translation(target_world))
        error = float(np.linalg.norm(conf.data.xpos[body] - target_world))
        it = 0
        while it < c.max_iterations and error > c.tolerance_m:
            v = mink.solve_ik(conf, [task, self._posture], c.dt, c.solver, damping=c.damping,
                              limits=self._limits, constraints=self._constraints)
            conf.integrate_inplace(v, c.dt)
            it += 1
            error = float(np.linalg.norm(conf.data.xpos[body] - target_world))
        q = np.clip(conf.q[s.qpos_adr], s.lower, s.upper)
        return IKResult(q, error, it, error <= c.tolerance_m)


def target_in_view(T_camera_base: FloatArray, intrinsics: CameraIntrinsics, pixel: FloatArray,
                   depth_m: float) -> FloatArray:
    """The base-frame point (3,) m seen at pixel (2,) px (undistorted by the camera model) at depth_m along z."""
    uv = normalized_from_pixels(np.asarray(pixel, dtype=np.float64).reshape(1, 2), intrinsics)[0]
    p_cam = np.array([uv[0], uv[1], 1.0]) * depth_m
    R_camera_base, t_camera_base = T_camera_base[:3, :3], T_camera_base[:3, 3]
    return R_camera_base.T @ (p_cam - t_camera_base)
