"""arc_env.robot.contours: the robot's contours from its own model, against the simulator and OpenCV's projection."""

import threading

import cv2
import numpy as np
import pytest

from arc_env.robot.contours import RobotContours
from arc_env.robot.model import RobotModel, RobotSource
from arc_env.robot.overlay import RobotProjector
from arc_env.sim.scene import Scene, SceneConfig
from solver.frames import transform_from_rt
from solver.mask_start import MovingSurface
from solver.observations import CameraIntrinsics
from solver.outline_fusion import CoarseContours
from solver.outlines import project_base_points

W, H = 640, 360
#: Depth agreement with the simulator's renderer (float32 depth buffers of one GL pipeline), metres.
DEPTH_TOL_M = 1e-4
#: Masks of a mesh filled by OpenCV and rendered by GL differ along the outline only: this share of the pixels of
#: either lies within a pixel of the other.
MIN_NEAR = 0.995


def _look_at(eye, target) -> np.ndarray:
    """T_camera_base of a camera at eye (3,) m looking at target (3,) m, the base's z up in the image."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, -1.0])
    x /= np.linalg.norm(x)
    R_base_camera = np.stack([x, np.cross(z, x), z], axis=1)
    return transform_from_rt(R_base_camera.T, -R_base_camera.T @ eye)


T_VIEW = _look_at(np.array([1.6, 0.5, 0.9]), np.array([0.0, 0.0, 0.45]))


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return RobotModel.load(RobotSource())


@pytest.fixture(scope="module")
def q(robot) -> np.ndarray:
    q = robot.home.copy()
    q[1] += 0.3
    return q


def test_depth_and_mask_are_the_simulators(robot, q):
    scene = Scene(SceneConfig(width=W, height=H, appearance="as_shipped", shadows=False))
    try:
        scene.robot.set_q(q)
        depth, mask = scene.depth(T_VIEW).astype(np.float64), scene.robot_mask(T_VIEW)
        ours, our_mask = RobotContours(robot, scene.intrinsics).depth_and_mask(T_VIEW, q)
    finally:
        scene.close()
    assert mask.sum() > 1000 and np.array_equal(mask, our_mask)
    assert np.max(np.abs(depth[mask] - ours[mask])) < DEPTH_TOL_M
    floor = ~mask & np.isfinite(ours)  # the support plane, filled in analytically
    assert floor.sum() > 0.3 * H * W
    assert np.median(np.abs(depth[floor] - ours[floor])) < DEPTH_TOL_M


def test_an_off_centre_camera_sees_what_opencv_projects(robot, q):
    camera = CameraIntrinsics(np.array([[520.0, 0, 360.0], [0, 520.0, 160.0], [0, 0, 1]]), np.zeros(5), W, H)
    _, mask = RobotContours(robot, camera).depth_and_mask(T_VIEW, q)
    projected = RobotProjector(robot, camera).mask(q, T_VIEW)
    grown = [cv2.dilate(m.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0 for m in (mask, projected)]
    assert mask.sum() > 5000
    assert (mask & grown[1]).sum() / mask.sum() > MIN_NEAR and (projected & grown[0]).sum() / projected.sum() > MIN_NEAR
    contour = RobotContours(robot, camera, stride=1)(T_VIEW, q)
    cam = contour.points_base @ T_VIEW[:3, :3].T + T_VIEW[:3, 3]
    px = cam[:, :2] / cam[:, 2:] * 520.0 + [360.0, 160.0]
    inside = px - 0.5 * contour.outward  # half a pixel in from the contour: the robot; half out: what it hides
    outside = px + 0.5 * contour.outward
    ii, oo = np.rint(inside).astype(int), np.rint(outside).astype(int)
    assert np.all(mask[ii[:, 1], ii[:, 0]])
    assert np.mean(~mask[oo[:, 1], oo[:, 0]]) > 0.5  # the rest lies on a farther link


def test_the_coarse_contour_is_the_half_resolution_render_of_the_same_outline(robot, q):
    """``coarse`` renders the same camera at half the size: its contour points, projected with the full camera, lie
    within a pixel or two of the full render's (every point of it); it is a ``CoarseContours``, made once, and a small
    image is not halved."""
    camera = CameraIntrinsics(np.array([[1040.0, 0, 719.5], [0, 1040.0, 359.5], [0, 0, 1]]), np.zeros(5), 2 * W, 2 * H)
    full = RobotContours(robot, camera)
    assert isinstance(full, CoarseContours)
    half = full.coarse()
    assert half is full.coarse() and half.coarse() is half
    assert (half.intrinsics.width, half.intrinsics.height) == (W, H)
    np.testing.assert_allclose(half.intrinsics.K[:2], [[520.0, 0, 359.5], [0, 520.0, 179.5]])
    coarse = half(T_VIEW, q)
    fine = RobotContours(robot, camera, stride=1)(T_VIEW, q)
    assert 0.35 * len(full(T_VIEW, q).points_base) < len(coarse.points_base) < 0.65 * len(full(T_VIEW, q).points_base)
    px, _ = project_base_points(T_VIEW, coarse.points_base, camera)
    ref, _ = project_base_points(T_VIEW, fine.points_base, camera)
    gap = np.min(np.linalg.norm(px[:, None, :] - ref[None, :, :], axis=2), axis=1)
    assert np.mean(gap < 1.5) > 0.9 and np.median(gap) < 1.0
    small = CameraIntrinsics(np.array([[300.0, 0, 199.5], [0, 300.0, 149.5], [0, 0, 1]]), np.zeros(5), 400, 300)
    tiny = RobotContours(robot, small)
    assert tiny.coarse() is tiny


def test_the_floor_under_the_base_makes_no_outline(robot, q):
    camera = CameraIntrinsics(np.array([[520.0, 0, 319.5], [0, 520.0, 179.5], [0, 0, 1]]), np.zeros(5), W, H)
    low = _look_at(np.array([1.2, 0.2, 0.4]), np.array([0.0, 0.0, 0.2]))  # the base's foot in view
    on_floor = RobotContours(robot, camera, stride=1)(low, q)
    in_air = RobotContours(robot, camera, stride=1, ground=False)(low, q)
    near_floor = [int(np.sum(c.points_base[:, 2] < 0.01)) for c in (on_floor, in_air)]
    assert near_floor[1] > 20 and near_floor[0] < 0.25 * near_floor[1]


def test_another_thread_renders_the_same(robot, q):
    camera = CameraIntrinsics(np.array([[520.0, 0, 319.5], [0, 520.0, 179.5], [0, 0, 1]]), np.zeros(5), W, H)
    contours = RobotContours(robot, camera)
    here = contours(T_VIEW, q)
    there = []
    worker = threading.Thread(target=lambda: there.append(contours(T_VIEW, q)))
    worker.start()
    worker.join()
    assert np.array_equal(here.points_base, there[0].points_base)


def test_one_render_reads_the_geoms_and_depth_that_two_renders_give(robot, q):
    """``render_geoms_and_depth`` against mujoco.Renderer's own segmentation and depth renders of the same scene."""
    import mujoco

    from arc_env.robot.rendering import _geoms_and_depth_two_renders, create_renderer, render_geoms_and_depth

    loaded = RobotModel.load(RobotSource())
    model = loaded.model
    renderer = create_renderer(model, H, W)
    try:
        data = mujoco.MjData(model)
        data.qpos[loaded.qpos_adr] = q
        mujoco.mj_kinematics(model, data)
        camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(model, camera)
        renderer.update_scene(data, camera)
        geoms, depth = render_geoms_and_depth(renderer)
        want_geoms, want_depth = _geoms_and_depth_two_renders(renderer)
    finally:
        renderer.close()
    assert geoms.shape == (H, W) and (geoms >= 0).sum() > 1000 and (geoms < 0).sum() > 1000
    assert len(np.unique(geoms[geoms >= 0])) > 5  # many geoms, each with its own id
    assert np.array_equal(geoms, want_geoms)
    assert np.array_equal(depth, want_depth)


@pytest.mark.parametrize("view", ["whole", "cut by the border", "close"])
def test_the_contour_read_in_the_robots_window_is_the_whole_images(robot, q, view):
    """``RobotContours`` reads out only the pixels around the robot's bounding spheres: the same contour as the
    whole image's depth and mask give (``contour_from_depth`` on a full readout of the same render)."""
    from arc_env.robot.rendering import render_geoms_and_depth
    from solver.outlines import contour_from_depth

    T = {"whole": T_VIEW,
         "cut by the border": _look_at(np.array([1.2, 0.9, 0.6]), np.array([0.3, 0.0, 0.9])),
         "close": _look_at(np.array([0.35, 0.15, 0.5]), np.array([0.0, 0.0, 0.4]))}[view]
    camera = CameraIntrinsics(np.array([[520.0, 0, 319.5], [0, 520.0, 179.5], [0, 0, 1]]), np.zeros(5), W, H)
    contours = RobotContours(robot, camera, stride=1)
    got = contours(T, q)
    renderer, data = contours._renderer()  # the same scene as the call above left it, read out whole
    geoms, depth = render_geoms_and_depth(renderer)
    T_camera_world = T @ np.linalg.inv(contours.robot.T_world_base)
    mask = contours._robot_geom[geoms]
    want = contour_from_depth(np.where(mask, depth, contours._plane_depth(T_camera_world, depth.shape)), mask, T,
                              contours.K_render, contours.min_step_m, 1)
    window = contours._window(data, T_camera_world)
    area = (window[2] - window[0]) * (window[3] - window[1])
    if view == "close":
        assert area == W * H  # a bounding sphere reaches the camera: the whole image
    else:
        assert area < 0.8 * W * H
    if view == "cut by the border":
        assert window[0] == 0 or window[1] == 0 or window[2] == W or window[3] == H
    assert len(got.points_base) > 200
    np.testing.assert_allclose(got.points_base, want.points_base, rtol=0, atol=1e-12)
    assert np.array_equal(got.outward, want.outward)
    depth_whole, mask_whole = contours.depth_and_mask(T, q)
    assert np.array_equal(mask_whole, mask)
    assert np.array_equal(depth_whole[mask], depth[mask])


def test_the_moving_points_are_the_models_and_lie_on_its_rendered_pixels(robot, q):
    """``moving_points`` (the mask rescue's ``MovingSurface``): the vertices of the links a joint moves, where the
    caller's model puts them at q, and seen on the robot's own rendered pixels."""
    contours = RobotContours(robot, CameraIntrinsics(np.array([[500.0, 0, W / 2], [0, 500.0, H / 2], [0, 0, 1]]),
                                                     np.zeros(5), W, H))
    assert isinstance(contours, MovingSurface)
    saved = robot.q.copy()
    points = contours.moving_points(q, 3)
    np.testing.assert_array_equal(robot.q, saved)  # the caller's model is not posed
    robot.set_q(q)
    expected = robot.points_base(*robot.surface_points(3))
    robot.set_q(saved)
    np.testing.assert_allclose(points, expected, atol=1e-9)
    assert len(contours.moving_points(q, 0)) > len(points)  # joint 1 moves every link joint 4 does, and more
    _, mask = contours.depth_and_mask(T_VIEW, q)
    cam = points @ T_VIEW[:3, :3].T + T_VIEW[:3, 3]
    px = np.rint(cam[:, :2] / cam[:, 2:] * 500.0 + [W / 2, H / 2]).astype(int)
    inside = (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
    near = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    assert inside.mean() > 0.9 and near[px[inside, 1], px[inside, 0]].mean() > 0.99
