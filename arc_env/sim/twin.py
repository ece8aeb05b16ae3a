"""A robot model's digital twin for planners: depth images rendered by the simulator, on demand.

``arc-calib run`` plans on the driver's robot model (``arc_env.robot.model.RobotModel``, no rendering).
The informed planner can use depth images rendered from its estimate to predict occlusion; a
``TwinRenderer`` provides them (``planners.context.SceneRenderer``) from a scene of the same robot with
no camera mount and no texture, built when first asked, so nothing renders unless a planner needs it.
Its "true" camera is a placeholder: on a real robot there is no truth, so only ``depth_at`` (from a
given pose) is meaningful, and ``prepare`` builds nothing (no image test runs on a real robot).
"""

from __future__ import annotations

from arc_env.robot.model import RobotModel
from arc_env.sim.scene import Scene, SceneConfig, SceneRenderer
from solver.observations import CameraIntrinsics


class TwinRenderer(SceneRenderer):
    """Renders a robot model's twin (see the module docstring).

    Args:
        robot: the robot model the planner poses.
        intrinsics: the real camera (its size and fx set the twin's symmetric pinhole camera).
    """

    def __init__(self, robot: RobotModel, intrinsics: CameraIntrinsics):
        self.robot = robot
        self.intrinsics = intrinsics
        self._twin: Scene | None = None

    def _rendered(self) -> Scene:
        if self._twin is None:
            cam = self.intrinsics
            self._twin = Scene(SceneConfig(robot=self.robot.source, width=cam.width, height=cam.height,
                                           fx=float(cam.K[0, 0]), camera_mount=False, appearance="as_shipped"))
        return self._twin

    def prepare(self, downscale: int) -> None:
        """Nothing: the twin renders only when asked."""

    def close(self) -> None:
        """Free the twin's renderers, if it was built."""
        if self._twin is not None:
            self._twin.close()
