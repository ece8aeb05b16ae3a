"""The robot model on its own: the same kinematics as the simulator's scene, no floor, quiet to build."""

import warnings

import numpy as np
import pytest

from arc_env.robot.model import GROUND_GEOM, RobotModel, RobotSource
from arc_env.sim.scene import Scene, SceneConfig
from solver.errors import InvalidInputError


@pytest.fixture(scope="module")
def panda():
    return RobotModel.load(RobotSource())


def test_kinematics_are_the_scenes_to_the_last_bit(panda):
    scene = Scene(SceneConfig(width=64, height=48))
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(panda.lower, panda.upper)
        for j in range(panda.n_joints):
            a1, p1 = panda.axis_and_point(q, j)
            a2, p2 = scene.robot.axis_and_point(q, j)
            np.testing.assert_array_equal(a1, a2)
            np.testing.assert_array_equal(p1, p2)
    assert panda.joint_names == scene.robot.joint_names
    np.testing.assert_array_equal(panda.home, scene.robot.home)


def test_only_a_collision_ground_is_added(panda):
    m = panda.model
    ground = m.geom(GROUND_GEOM)
    assert ground.group[0] >= 3 and m.ncam == 0  # never drawn; no camera
    assert all(m.geom_bodyid[g] in panda.robot_bodies for g in panda.rendered_geoms())


def test_building_it_warns_nothing():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        RobotModel.load(RobotSource())
    assert not [w for w in caught if "empty prefix" in str(w.message)]


def test_bad_sources_are_refused_with_the_valid_names():
    with pytest.raises(InvalidInputError, match="no body named 'nope'; bodies: .*panda0_link0"):
        RobotModel.load(RobotSource(base_body="nope"))
    with pytest.raises(InvalidInputError, match="no joint named 'nope'"):
        RobotModel.load(RobotSource(joints=("nope",), home=()))
    with pytest.raises(InvalidInputError, match="does not exist"):
        RobotModel.load(RobotSource(path="/no/such/robot.urdf", base_body="base"))
