"""mink IK: a link placed at a target (checked with MuJoCo's own kinematics), limits, and view targets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from arc_env.sim.scene import Scene, SceneConfig
from planners.ik import IKConfig, IKSolver, target_in_view
from solver import d415_intrinsics, look_at
from solver.errors import InvalidInputError

#: Reachable targets of the Panda's last link, base frame (m).
TARGETS = [(0.4, 0.2, 0.5), (0.5, -0.3, 0.3), (0.3, 0.0, 0.7), (0.6, 0.1, 0.2)]


@pytest.fixture(scope="module")
def scene():
    s = Scene(SceneConfig(width=64, height=64))
    yield s
    s.close()


@pytest.mark.parametrize("target", TARGETS)
def test_last_link_reaches_the_target(scene, target):
    ik = IKSolver(scene.robot)
    tip = int(scene.model.jnt_bodyid[scene.robot.arm_joints[-1]])
    seed = np.random.default_rng(1).uniform(scene.robot.lower, scene.robot.upper)
    result = ik.solve(tip, np.array(target), seed)
    assert result.reached
    assert np.all(result.q >= scene.robot.lower) and np.all(result.q <= scene.robot.upper)
    before = scene.robot.q
    scene.robot.set_q(result.q)
    reached = scene.robot.points_base(np.array([tip]), np.zeros((1, 3)))[0]  # MuJoCo's forward kinematics
    scene.robot.set_q(before)
    assert np.linalg.norm(reached - np.array(target)) <= IKConfig().tolerance_m
    assert result.error_m == pytest.approx(np.linalg.norm(reached - np.array(target)), abs=1e-6)


def test_unreachable_target_is_reported_not_reached(scene):
    ik = IKSolver(scene.robot, IKConfig(max_iterations=40))
    tip = int(scene.model.jnt_bodyid[scene.robot.arm_joints[-1]])
    result = ik.solve(tip, np.array([2.0, 0.0, 0.5]), scene.robot.home)  # 2 m away: beyond the arm's reach
    assert not result.reached and result.error_m > 0.5
    assert np.all(result.q >= scene.robot.lower) and np.all(result.q <= scene.robot.upper)


def test_bad_body_and_target_are_refused(scene):
    ik = IKSolver(scene.robot)
    with pytest.raises(InvalidInputError, match="not a moving body"):
        ik.solve(scene.robot.base_body, np.zeros(3), scene.robot.home)
    tip = int(scene.model.jnt_bodyid[scene.robot.arm_joints[-1]])
    with pytest.raises(InvalidInputError, match="finite"):
        ik.solve(tip, np.array([np.nan, 0.0, 0.5]), scene.robot.home)


def test_target_in_view_projects_back_to_its_pixel():
    intrinsics = d415_intrinsics()
    T = look_at(np.array([1.5, 0.8, 1.0]), np.array([0.3, 0.0, 0.4]))
    pixel = np.array([700.0, 400.0])
    p_base = target_in_view(T, intrinsics, pixel, 1.3)
    p_cam = T[:3, :3] @ p_base + T[:3, 3]
    assert p_cam[2] == pytest.approx(1.3)
    uv, _ = cv2.projectPoints(p_base.reshape(1, 3), cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], intrinsics.K, None)
    np.testing.assert_allclose(uv.reshape(2), pixel, atol=1e-9)
