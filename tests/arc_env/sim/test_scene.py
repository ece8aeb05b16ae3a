"""The scene: robots from files, kinematics read from MuJoCo, rendering and masks."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from arc_env.robot.model import RobotSource
from arc_env.sim.scene import Scene, SceneConfig
from solver import PANDA, InvalidInputError, pixels_from_camera_points
from tests.support.arms import arm_mjcf, arm_urdf, forward_axes, random_arm

#: The gymnasium-robotics Panda writes some rotations as 1.57 instead of pi/2, so its kinematics
#: differ from the published DH parameters by up to about this (rad for axes, m for points).
PANDA_MODEL_TOL = 5e-3
#: Its joint 6 is zero where the DH model's is pi/2 (its limits are shifted by the same amount).
PANDA_JOINT6_OFFSET = np.pi / 2


@pytest.fixture(scope="module", params=["mjcf", "urdf"])
def arm(request, tmp_path_factory):
    spec = random_arm(5)
    path = tmp_path_factory.mktemp("arm") / ("arm.xml" if request.param == "mjcf" else "arm.urdf")
    path.write_text(arm_mjcf(spec) if request.param == "mjcf" else arm_urdf(spec))
    scene = Scene(SceneConfig(robot=RobotSource(str(path), "arm_base", home=()), width=480, height=270))
    yield spec, scene
    scene.close()


def test_panda_loads_with_seven_arm_joints(panda_scene):
    assert panda_scene.robot.n_joints == 7
    assert all(name.endswith(f"joint{i + 1}") for i, name in enumerate(panda_scene.robot.joint_names))
    np.testing.assert_allclose(panda_scene.robot.upper[[0, 1]], [2.8973, 1.7628])


def test_panda_kinematics_match_the_published_dh_parameters(panda_scene):
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(panda_scene.robot.lower, panda_scene.robot.upper)
        for j in range(7):
            axis, point = panda_scene.robot.axis_and_point(q, j)
            axis_dh, point_dh = PANDA.axis_and_point(q + np.eye(7)[5] * PANDA_JOINT6_OFFSET, j)
            assert np.linalg.norm(axis - axis_dh) < PANDA_MODEL_TOL
            # points differ along the axis (any point on it is valid): compare the lines
            off = point - point_dh
            assert np.linalg.norm(off - off.dot(axis_dh) * axis_dh) < PANDA_MODEL_TOL


def test_generated_arm_kinematics_match_independent_fk(arm):
    spec, scene = arm
    assert scene.robot.n_joints == spec.n_joints
    rng = np.random.default_rng(1)
    for _ in range(10):
        q = rng.uniform(scene.robot.lower, scene.robot.upper)
        axes, points = forward_axes(spec, q)
        for j in range(spec.n_joints):
            axis, point = scene.robot.axis_and_point(q, j)
            np.testing.assert_allclose(axis, axes[j], atol=1e-9)
            np.testing.assert_allclose(point, points[j], atol=1e-9)


def test_projected_surface_points_fall_on_the_rendered_robot(panda_scene):
    T = panda_scene.T_camera_base
    mask = panda_scene.robot_mask()
    body, local = panda_scene.robot.surface_points(3)
    pc = panda_scene.robot.points_base(body, local) @ T[:3, :3].T + T[:3, 3]
    uv = np.round(pixels_from_camera_points(pc, panda_scene.intrinsics)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < 640) & (uv[:, 1] >= 0) & (uv[:, 1] < 360)
    assert inside.mean() > 0.9
    on_robot = mask[uv[inside, 1], uv[inside, 0]]
    assert on_robot.mean() > 0.95  # misses only at the silhouette's rounded pixels


def test_a_wrong_pose_gives_a_different_mask(panda_scene):
    true = panda_scene.robot_mask()
    T = panda_scene.T_camera_base.copy()
    T[0, 3] += 0.05
    shifted = panda_scene.robot_mask(T)
    iou = np.logical_and(true, shifted).sum() / np.logical_or(true, shifted).sum()
    assert 0.2 < iou < 0.9
    np.testing.assert_array_equal(panda_scene.robot_mask(), true)  # the true camera was restored


def test_a_thumbnail_is_the_same_view_with_fewer_pixels(panda_scene):
    full = panda_scene.render()
    thumb = panda_scene.render(4)
    assert thumb.shape == (90, 160, 3)
    shrunk = cv2.resize(full, (160, 90), interpolation=cv2.INTER_AREA)
    robot = cv2.resize(panda_scene.robot_mask().astype(np.uint8), (160, 90), interpolation=cv2.INTER_NEAREST) > 0
    diff = np.abs(shrunk.astype(int) - thumb.astype(int)).max(axis=2)
    # on the robot, pixels differing strongly: 0.3% here; a view shifted by one thumbnail pixel gives 14%
    assert np.mean(diff[robot] > 60) < 0.05
    with pytest.raises(InvalidInputError, match="downscale"):
        panda_scene.render(0)


def test_depth_of_the_floor_matches_the_ray_plane_intersection(panda_scene):
    depth = panda_scene.depth()
    K = panda_scene.intrinsics.K
    T_base_camera = np.linalg.inv(panda_scene.T_camera_base)
    T_world_camera = panda_scene.robot.T_world_base @ T_base_camera
    robot = panda_scene.robot_mask()
    checked = 0
    for v in range(200, 360, 20):
        for u in range(0, 640, 40):
            ray = np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])  # OpenCV: centres at integers
            origin, direction = T_world_camera[:3, 3], T_world_camera[:3, :3] @ ray
            if robot[v, u] or direction[2] >= 0:
                continue
            expected = -origin[2] / direction[2]  # the floor is the world's z = 0 plane
            # float32 depth; half a pixel off would be 2e-3 relative here
            assert depth[v, u] == pytest.approx(expected, rel=1e-5), (u, v)
            checked += 1
    assert checked > 50
    assert panda_scene.depth(downscale=4).shape == (90, 160)


def test_speckle_gives_the_tracker_corners_on_the_robot(panda_scene):
    grey = cv2.cvtColor(panda_scene.render(), cv2.COLOR_RGB2GRAY)
    mask = panda_scene.robot_mask().astype(np.uint8)
    plain = Scene(SceneConfig(width=640, height=360, appearance="as_shipped"))
    plain.set_camera(panda_scene.T_camera_base)
    grey_plain = cv2.cvtColor(plain.render(), cv2.COLOR_RGB2GRAY)
    plain.close()
    n = len(cv2.goodFeaturesToTrack(grey, 2000, 0.01, 3, mask=mask))
    found_plain = cv2.goodFeaturesToTrack(grey_plain, 2000, 0.01, 3, mask=mask)
    n_plain = 0 if found_plain is None else len(found_plain)
    # 298 vs 163 here; at 1920x1080 the marks are larger in pixels: 2115 vs 482
    assert n > 150
    assert n > 1.5 * n_plain


def test_missing_robot_file_is_named(tmp_path):
    path = tmp_path / "nope.urdf"
    with pytest.raises(InvalidInputError, match="nope.urdf does not exist"):
        Scene(SceneConfig(robot=RobotSource(str(path), "base")))


def test_corrupt_robot_file_is_named(tmp_path):
    path = tmp_path / "broken.xml"
    path.write_text("<mujoco><worldbody><body name='b'><geom type='sphere'")
    with pytest.raises(InvalidInputError, match="broken.xml could not be loaded"):
        Scene(SceneConfig(robot=RobotSource(str(path), "b")))


def test_unknown_base_body_lists_the_bodies(tmp_path):
    path = tmp_path / "arm.xml"
    path.write_text(arm_mjcf(random_arm(0)))
    with pytest.raises(InvalidInputError, match="no body named 'base'.*arm_link1"):
        Scene(SceneConfig(robot=RobotSource(str(path), "base")))


def test_unknown_joint_lists_the_joints(tmp_path):
    path = tmp_path / "arm.xml"
    path.write_text(arm_mjcf(random_arm(0)))
    with pytest.raises(InvalidInputError, match="no joint named 'elbow'.*arm_joint1"):
        Scene(SceneConfig(robot=RobotSource(str(path), "arm_base", joints=("elbow",))))


def test_multisampling_changes_only_geometry_edges_and_the_blur_is_the_psf(panda_scene):
    assert panda_scene.model.vis.quality.offsamples == panda_scene.config.multisamples == 0
    scenes = [Scene(SceneConfig(width=640, height=360, multisamples=ms, blur_px=0.0)) for ms in (0, 4)]
    try:
        for scene in scenes:
            scene.set_camera(panda_scene.T_camera_base)
            scene.robot.set_q(panda_scene.robot.q)
        assert scenes[1].model.vis.quality.offsamples == 4
        sharp, smooth = (scene.render() for scene in scenes)
    finally:
        for scene in scenes:
            scene.close()
    np.testing.assert_array_equal(panda_scene.render(), cv2.GaussianBlur(sharp, (0, 0), panda_scene.config.blur_px))
    diff = np.abs(sharp.astype(int) - smooth.astype(int)).max(axis=2)
    mask = panda_scene.robot_mask().astype(np.uint8)
    edge = cv2.dilate(mask, np.ones((3, 3), np.uint8)) != cv2.erode(mask, np.ones((3, 3), np.uint8))
    strong = diff > 8
    assert 0 < np.mean(strong) < 0.02  # the setting takes effect, on few pixels (0.7% here)
    assert np.mean(diff) < 1.0  # grey levels (0.23 here)
    # geometry edges, not texture or shading: 25% of the silhouette band differs, 0.4% elsewhere
    # (the rest of the geometry edges: between links and the floor's horizon)
    assert np.mean(strong[edge]) > 20 * np.mean(strong[~edge])
    for bad in ({"multisamples": -1}, {"blur_px": -0.5}, {"blur_px": float("nan")}):
        with pytest.raises(InvalidInputError, match=next(iter(bad))):
            SceneConfig(**bad)


def test_bad_configurations_are_refused(panda_scene):
    with pytest.raises(InvalidInputError, match="shape"):
        panda_scene.robot.axis_and_point(np.zeros(6), 0)
    with pytest.raises(InvalidInputError, match="NaN"):
        panda_scene.robot.axis_and_point(np.full(7, np.nan), 0)
    with pytest.raises(InvalidInputError, match="joint must be"):
        panda_scene.robot.axis_and_point(np.zeros(7), 7)


def test_panda_assets_come_from_the_installed_package():
    from arc_env.robot.model import panda_mjcf_dir

    d = panda_mjcf_dir()
    assert (d / "chain.xml").is_file() and Path(d, "meshes").is_dir()
