"""OMPL transit: straight when free, planned around an obstacle that blocks the straight line, checked."""

from __future__ import annotations

import numpy as np
import pytest

from arc_env.sim.env import ArcCalibEnv, EnvConfig
from arc_env.sim.scene import Obstacle, Scene, SceneConfig
from planners.collision import CollisionChecker
from planners.transit import TransitConfig, TransitError, path_length, plan_transit

#: A post in front of the Panda: turning joint 1 from -1 to +1 rad with the arm reaching forward at
#: 0.4 m height sweeps link 5 through it, so the straight joint-space segment is blocked.
POST = Obstacle("post", (0.55, 0.0, 0.3), (0.06, 0.06, 0.3))
Q_FROM = np.array([-1.0, 0.4, 0.0, -2.0, 0.0, 1.5, 0.8])
Q_TO = np.array([1.0, 0.4, 0.0, -2.0, 0.0, 1.5, 0.8])


@pytest.fixture(scope="module")
def blocked():
    scene = Scene(SceneConfig(width=64, height=64, obstacles=(POST,)))
    checker = CollisionChecker(scene.model, scene.robot.arm_joints, qpos_ref=scene.data.qpos.copy())
    yield scene, checker
    scene.close()


def test_the_post_blocks_the_straight_segment(blocked):
    _, checker = blocked
    assert not checker.in_collision(Q_FROM)[0] and not checker.in_collision(Q_TO)[0]
    free, why = checker.path_free(Q_FROM, Q_TO)
    assert not free and "post" in why


def test_planned_transit_goes_around_the_post(blocked):
    scene, checker = blocked
    path = plan_transit(checker, scene.robot.lower, scene.robot.upper, Q_FROM, Q_TO, seed=3)
    assert path.planned
    np.testing.assert_array_equal(path.waypoints[0], Q_FROM)
    np.testing.assert_array_equal(path.waypoints[-1], Q_TO)
    assert len(path.waypoints) >= 3
    assert np.all(path.waypoints >= scene.robot.lower - 1e-9) and np.all(path.waypoints <= scene.robot.upper + 1e-9)
    for a, b in zip(path.waypoints[:-1], path.waypoints[1:], strict=True):
        assert checker.path_free(a, b, 0.002)[0]  # finer than the planner's own 5 mm check
    assert path.length_rad == pytest.approx(path_length(path.waypoints))
    assert path.length_rad > np.linalg.norm(Q_TO - Q_FROM)


def test_same_seed_same_path(blocked):
    scene, checker = blocked
    a = plan_transit(checker, scene.robot.lower, scene.robot.upper, Q_FROM, Q_TO, seed=7)
    b = plan_transit(checker, scene.robot.lower, scene.robot.upper, Q_FROM, Q_TO, seed=7)
    np.testing.assert_array_equal(a.waypoints, b.waypoints)


def test_free_straight_segment_is_not_planned(blocked):
    scene, checker = blocked
    q_to = Q_FROM.copy()
    q_to[3] = -1.5
    path = plan_transit(checker, scene.robot.lower, scene.robot.upper, Q_FROM, q_to)
    assert not path.planned
    np.testing.assert_array_equal(path.waypoints, np.stack([Q_FROM, q_to]))


def test_goal_in_collision_fails_with_a_reason(blocked):
    scene, checker = blocked
    inside = Q_FROM.copy()
    inside[0] = 0.0  # link 5 inside the post
    assert checker.in_collision(inside)[0]
    with pytest.raises(TransitError, match="target configuration is in collision"):
        plan_transit(checker, scene.robot.lower, scene.robot.upper, Q_FROM, inside, TransitConfig(time_limit=0.2))


def test_env_executes_a_planned_transit_around_the_post():
    env = ArcCalibEnv(EnvConfig(scene=SceneConfig(width=160, height=90, obstacles=(POST,)),
                                oracle_keypoints=True))
    try:
        env.reset(seed=0)
        env.scene.robot.set_q(Q_FROM)  # as if the last motion had ended here
        obs, _, _, _, info = env.step({"Q": Q_TO, "J": 3, "delta": np.array([0.3])})
        assert info["refused"] == ""
        assert info["transit_planned"] is True
        assert info["transit_rad"] == pytest.approx(env.session.last_transit.length_rad)
        assert info["transit_rad"] > np.linalg.norm(Q_TO - Q_FROM)
        expected_end = Q_TO.copy()
        expected_end[3] += 0.3
        np.testing.assert_allclose(env.scene.robot.q, expected_end)
    finally:
        env.close()
