"""The robot model on its own: the same kinematics as the simulator's scene, no floor, quiet to build."""

import warnings
from pathlib import Path

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


def _write_obj(path: Path) -> None:
    """A closed tetrahedron, 5 cm, as a Wavefront OBJ."""
    v = ["v 0 0 0", "v 0.05 0 0", "v 0 0.05 0", "v 0 0 0.05"]
    path.write_text("\n".join([*v, "f 1 3 2", "f 1 2 4", "f 1 4 3", "f 2 3 4"]) + "\n")


def test_a_urdf_with_package_meshes_in_folders_loads_with_its_visuals(tmp_path):
    package = tmp_path / "demo_description"
    (package / "meshes" / "visual").mkdir(parents=True)
    _write_obj(package / "meshes" / "visual" / "link.obj")
    (tmp_path / "urdf").mkdir()
    urdf = tmp_path / "urdf" / "demo.urdf"
    mesh = '<geometry><mesh filename="package://demo_description/meshes/visual/link.obj"/></geometry>'
    urdf.write_text(f"""<robot name="demo">
  <material name="orange"><color rgba="1 0.4 0 1"/></material>
  <link name="base"><visual>{mesh}<material name="orange"/></visual><collision>{mesh}</collision></link>
  <link name="link1"><inertial><mass value="1"/><inertia ixx="1" iyy="1" izz="3" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual>{mesh}<material name="orange"/></visual><collision>{mesh}</collision></link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="link1"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>""")
    robot = RobotModel.load(RobotSource(path=str(urdf), base_body="base", home=()))
    assert robot.joint_names == ["j1"]
    drawn = robot.rendered_geoms()
    assert len(drawn) == 2  # the two visuals; the collision meshes are moved out of sight
    np.testing.assert_allclose(robot.model.geom_rgba[drawn], [[1, 0.4, 0, 1]] * 2)
    urdf.write_text(urdf.read_text().replace("demo_description", "missing_description"))
    with pytest.raises(InvalidInputError, match="no folder 'missing_description'"):
        RobotModel.load(RobotSource(path=str(urdf), base_body="base", home=()))
