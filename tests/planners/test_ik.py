"""mink IK: a link placed at a target (checked with MuJoCo's own kinematics), limits, and view targets."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import arc_env  # noqa: F401  (GL backend before MuJoCo)
from arc_env.scene import Scene, SceneConfig
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
    ik = IKSolver(scene)
    tip = int(scene.model.jnt_bodyid[scene.arm_joints[-1]])
    seed = np.random.default_rng(1).uniform(scene.lower, scene.upper)
    result = ik.solve(tip, np.array(target), seed)
    assert result.reached
    assert np.all(result.q >= scene.lower) and np.all(result.q <= scene.upper)
    before = scene.q
    scene.set_q(result.q)
    reached = scene.points_base(np.array([tip]), np.zeros((1, 3)))[0]  # MuJoCo's forward kinematics
    scene.set_q(before)
    assert np.linalg.norm(reached - np.array(target)) <= IKConfig().tolerance_m
    assert result.error_m == pytest.approx(np.linalg.norm(reached - np.array(target)), abs=1e-6)


def test_unreachable_target_is_reported_not_reached(scene):
    ik = IKSolver(scene, IKConfig(max_iterations=40))
    tip = int(scene.model.jnt_bodyid[scene.arm_joints[-1]])
    result = ik.solve(tip, np.array([2.0, 0.0, 0.5]), scene.home)  # 2 m away: beyond the arm's reach
    assert not result.reached and result.error_m > 0.5
    assert np.all(result.q >= scene.lower) and np.all(result.q <= scene.upper)


def test_bad_body_and_target_are_refused(scene):
    ik = IKSolver(scene)
    with pytest.raises(InvalidInputError, match="not a moving body"):
        ik.solve(scene.base_body, np.zeros(3), scene.home)
    tip = int(scene.model.jnt_bodyid[scene.arm_joints[-1]])
    with pytest.raises(InvalidInputError, match="finite"):
        ik.solve(tip, np.array([np.nan, 0.0, 0.5]), scene.home)


def test_target_in_view_projects_back_to_its_pixel():
    intrinsics = d415_intrinsics()
    T = look_at(np.array([1.5, 0.8, 1.0]), np.array([0.3, 0.0, 0.4]))
    pixel = np.array([700.0, 400.0])
    p_base = target_in_view(T, intrinsics, pixel, 1.3)
    p_cam = T[:3, :3] @ p_base + T[:3, 3]
    assert p_cam[2] == pytest.approx(1.3)
    uv, _ = cv2.projectPoints(p_base.reshape(1, 3), cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], intrinsics.K, None)
    np.testing.assert_allclose(uv.reshape(2), pixel, atol=1e-9)
