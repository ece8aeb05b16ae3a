"""The robot library: every named arm loads as shipped, with kinematics that match its own file."""

import importlib.util
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from arc_env.bench.poses import benchmark_camera_pose, benchmark_view
from arc_env.robot import library
from arc_env.robot.library import ROBOT_NAMES, library_robot, parse_robot_names, robot_from_arguments
from arc_env.robot.model import RobotSource
from arc_env.sim.scene import Scene, SceneConfig
from planners.collision import CollisionChecker
from solver.errors import InvalidInputError

#: The URDF arms: their kinematics are checked against forward kinematics computed from the file here.
URDF_ARMS = ("iiwa", "xarm6")
#: MuJoCo compiles the URDF's xyz/rpy into float64 quaternions and positions: they agree to rounding.
URDF_TOL = 1e-9
#: Joints must start this far (rad) inside their limits at home (the library's promise is 0.4).
HOME_MARGIN_RAD = 0.4


@pytest.fixture(scope="module", params=ROBOT_NAMES)
def scene(request):
    scene = Scene(SceneConfig(robot=library_robot(request.param), width=192, height=108, appearance="as_shipped"))
    yield request.param, scene
    scene.close()


def test_each_arm_loads_with_at_least_six_hinges_and_a_safe_home(scene):
    name, s = scene
    robot = s.robot
    assert robot.n_joints >= 6
    margin = np.minimum(robot.home - robot.lower, robot.upper - robot.home)
    assert margin.min() >= HOME_MARGIN_RAD, (name, margin)
    checker = CollisionChecker(robot.model, robot.arm_joints)
    assert checker.in_collision(robot.home) == (False, "")
    assert len(robot.rendered_geoms()) >= robot.n_joints  # every link drawn, visuals kept


def _urdf_axes(path: str, joints: tuple[str, ...], q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axes (n, 3) and points (n, 3) of a serial URDF chain at q, in its root link's frame (own FK)."""
    root = ET.parse(path).getroot()
    by_name = {j.get("name"): j for j in root.findall("joint")}  # not <transmission>'s
    T = np.eye(4)
    axes, points = [], []
    for name, angle in zip(joints, q, strict=True):
        j = by_name[name]
        origin = j.find("origin")
        xyz = np.array((origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split(), float)
        rpy = np.array((origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split(), float)
        T_origin = np.eye(4)
        T_origin[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF: fixed axes x, y, z
        T_origin[:3, 3] = xyz
        T = T @ T_origin
        axis = np.array(j.find("axis").get("xyz").split(), float)
        axis /= np.linalg.norm(axis)
        axes.append(T[:3, :3] @ axis)
        points.append(T[:3, 3].copy())
        T_turn = np.eye(4)
        T_turn[:3, :3] = Rotation.from_rotvec(axis * angle).as_matrix()
        T = T @ T_turn
    return np.array(axes), np.array(points)


@pytest.mark.parametrize("name", URDF_ARMS)
def test_urdf_arm_kinematics_match_forward_kinematics_from_the_file(name):
    source = library_robot(name)
    scene = Scene(SceneConfig(robot=source, width=64, height=48))
    try:
        robot = scene.robot
        rng = np.random.default_rng(3)
        for _ in range(10):
            q = rng.uniform(robot.lower, robot.upper)
            axes, points = _urdf_axes(source.path, source.joints, q)
            for j in range(robot.n_joints):
                axis, point = robot.axis_and_point(q, j)
                np.testing.assert_allclose(axis, axes[j], atol=URDF_TOL)
                off = point - points[j]  # any point on the axis is valid: compare the lines
                assert np.linalg.norm(off - off.dot(axes[j]) * axes[j]) < URDF_TOL
    finally:
        scene.close()


def test_the_base_frame_is_the_base_bodys_frame(scene):
    _, s = scene
    robot = s.robot
    q = robot.home + 0.1
    robot.set_q(q)
    T = robot.T_world_base
    for j in range(robot.n_joints):
        axis, point = robot.axis_and_point(q, j)
        body = robot.joint_body(j)
        jnt = robot.arm_joints[j]
        R_world_body = s.data.xmat[body].reshape(3, 3)
        axis_world = R_world_body @ robot.model.jnt_axis[jnt]
        anchor_world = s.data.xpos[body] + R_world_body @ robot.model.jnt_pos[jnt]
        np.testing.assert_allclose(T[:3, :3] @ axis, axis_world, atol=1e-12)
        np.testing.assert_allclose(T[:3, :3] @ point + T[:3, 3], anchor_world, atol=1e-12)
    robot.set_q(robot.home)


def test_as_shipped_arm_renders_from_a_benchmark_pose_in_its_own_colours(scene):
    name, s = scene
    target, scale = benchmark_view(s.robot)
    s.set_camera(benchmark_camera_pose(0, target, scale))
    mask = s.robot_mask()
    assert mask.mean() > 0.01, name  # about 3-5 % of the image at this pose
    rgb = s.render().astype(float)[mask]
    saturation = rgb.max(axis=1) - rgb.min(axis=1)
    if name == "iiwa":  # the file's blue and orange links
        assert ((rgb[:, 2] > rgb[:, 0] + 30) & (saturation > 40)).mean() > 0.1
        assert ((rgb[:, 0] > rgb[:, 2] + 60) & (saturation > 60)).mean() > 0.05
    else:  # white (and dark grey) castings: nothing coloured, nothing speckled
        assert np.median(saturation) < 25 and np.median(rgb.mean(axis=1)) > 120


def test_benchmark_view_is_the_pandas_own_and_scales_the_others(scene):
    name, s = scene
    target, scale = benchmark_view(s.robot)
    if name == "panda":
        assert (target, scale) == ((0.3, 0.0, 0.45), 1.0)
    else:
        assert 0.5 < scale < 1.5
    np.testing.assert_array_equal(benchmark_camera_pose(4), benchmark_camera_pose(4, (0.3, 0.0, 0.45), 1.0))


def test_unknown_names_list_the_valid_ones():
    with pytest.raises(InvalidInputError, match="unknown robot 'ur5'; valid: panda, iiwa, xarm6"):
        library_robot("ur5")
    with pytest.raises(InvalidInputError, match="unknown robot 'ur5'; valid: panda, iiwa, xarm6"):
        parse_robot_names("panda,ur5")
    with pytest.raises(InvalidInputError, match="no robot named"):
        parse_robot_names(" , ")
    assert parse_robot_names("xarm6, panda,xarm6") == ("xarm6", "panda")
    assert library_robot("panda") == RobotSource()


def test_a_missing_package_is_named(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(library.importlib.util, "find_spec",
                        lambda name, *a: None if name == "pybullet_data" else real(name, *a))
    with pytest.raises(InvalidInputError, match=r"pip install pybullet"):
        library_robot("iiwa")


def test_a_command_line_names_a_library_robot_or_a_model_file(tmp_path):
    assert robot_from_arguments(None, None) == RobotSource()
    assert robot_from_arguments("iiwa", None) == library_robot("iiwa")
    model = tmp_path / "arm.xml"
    assert robot_from_arguments(str(model), "base") == RobotSource(path=str(model), base_body="base", home=())
    with pytest.raises(InvalidInputError, match="needs --base-body"):
        robot_from_arguments(str(model), None)
    with pytest.raises(InvalidInputError, match="knows its own base"):
        robot_from_arguments("xarm6", "link_base")
    with pytest.raises(InvalidInputError, match="needs --robot"):
        robot_from_arguments(None, "base")
