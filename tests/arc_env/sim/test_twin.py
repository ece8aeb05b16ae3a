"""The twin renderer of a robot model: depth on demand, from the planner's pose, with the planner's arm."""

import numpy as np

from arc_env.robot.model import RobotModel, RobotSource
from arc_env.sim.twin import TwinRenderer
from solver import look_at
from solver.observations import CameraIntrinsics

#: MuJoCo's depth buffer against a point's depth along the optical axis, m (near/far quantization).
DEPTH_TOL_M = 0.01


def test_twin_depth_matches_the_models_own_points():
    robot = RobotModel.load(RobotSource())
    camera = CameraIntrinsics.from_fov(200.0, 320, 240)
    twin = TwinRenderer(robot, camera)
    try:
        twin.prepare(4)
        assert twin._twin is None  # nothing is built until a depth image is asked for
        T_camera_base = look_at(np.array([1.8, 0.0, 0.8]), np.array([0.3, 0.0, 0.4]))
        q = robot.home.copy()
        depth = twin.depth_at(q, T_camera_base)
        assert depth.shape == (240, 320)
        body = np.array([robot.joint_body(3)])
        uv, ok = robot.project_points(body, np.zeros((1, 3)), T_camera_base, camera, min_depth=0.1)
        z = (robot.points_base(body, np.zeros((1, 3))) @ T_camera_base[:3, :3].T + T_camera_base[:3, 3])[0, 2]
        col, row = np.round(uv[0]).astype(int)
        assert ok[0] and depth[row, col] <= z + DEPTH_TOL_M  # the joint's origin, or the link in front of it
        assert depth[row, col] > 0.5 * z
    finally:
        twin.close()
