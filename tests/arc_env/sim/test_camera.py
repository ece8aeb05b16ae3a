"""The MuJoCo camera <-> OpenCV optical frame conversion, against rendered pixels."""

import numpy as np
import pytest

from arc_env.robot.model import RobotSource
from arc_env.sim.camera import fovy_from_intrinsics, mujoco_camera_from_optical, optical_from_mujoco_camera
from arc_env.sim.scene import Obstacle, Scene, SceneConfig
from solver import CameraIntrinsics, InvalidInputError, look_at, pixels_from_camera_points
from solver.frames import transform_from_rt

#: px: the centroid of a 1 cm cube seen from 1.2-1.8 m (about 8 px across) may differ from the
#: projection of its centre by perspective and rasterization, well under this.
CENTROID_TOL_PX = 0.6


def test_round_trip_through_mujoco_quaternion():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        R *= np.sign(np.linalg.det(R))
        T = transform_from_rt(R, rng.normal(size=3))
        pos, quat = mujoco_camera_from_optical(T)
        import mujoco

        xmat = np.empty(9)
        mujoco.mju_quat2Mat(xmat, quat)
        np.testing.assert_allclose(optical_from_mujoco_camera(pos, xmat), T, atol=1e-12)


def test_optical_z_is_mujoco_minus_z():
    T = look_at(np.array([2.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]))  # looking along world -x
    _, quat = mujoco_camera_from_optical(np.linalg.inv(T))
    import mujoco

    xmat = np.empty(9)
    mujoco.mju_quat2Mat(xmat, quat)
    R_world_mjcam = xmat.reshape(3, 3)
    np.testing.assert_allclose(-R_world_mjcam[:, 2], [-1, 0, 0], atol=1e-12)  # MuJoCo looks along -z
    np.testing.assert_allclose(R_world_mjcam[:, 1], [0, 0, 1], atol=1e-12)  # image up = world up


def test_fovy_rejects_what_mujoco_cannot_render():
    assert fovy_from_intrinsics(CameraIntrinsics.from_fov(1380, 1920, 1080)) == pytest.approx(
        np.degrees(2 * np.arctan(540 / 1380)))
    with pytest.raises(InvalidInputError, match="fx == fy"):
        fovy_from_intrinsics(CameraIntrinsics.from_fov(1380, 1920, 1080, fy=1300))
    K = np.array([[1380, 0, 900], [0, 1380, 539.5], [0, 0, 1.0]])
    with pytest.raises(InvalidInputError, match="principal point"):
        fovy_from_intrinsics(CameraIntrinsics(K=K))


@pytest.fixture(scope="module")
def marker_scene():
    """A scene whose only robot is a tiny arm, plus small cubes at known world points."""
    xml = """<mujoco><worldbody><body name="base"><geom type="box" size=".02 .02 .02" pos="0 0 -2"/>
      <body name="l1"><joint name="j1" type="hinge" axis="0 0 1" range="-1 1"/>
      <geom type="capsule" fromto="0 0 -2 0 0 -1.9" size=".01"/></body></body></worldbody></mujoco>"""
    import tempfile
    from pathlib import Path

    d = tempfile.mkdtemp()
    path = Path(d) / "tiny.xml"
    path.write_text(xml)
    cubes = [(0.0, 0.0, 0.5), (0.25, -0.2, 0.7), (-0.2, 0.3, 0.3), (0.1, 0.25, 0.9)]
    obstacles = tuple(Obstacle(f"cube{i}", c, (0.005, 0.005, 0.005)) for i, c in enumerate(cubes))
    config = SceneConfig(robot=RobotSource(str(path), "base", home=()), width=640, height=480, fx=600.0,
                         obstacles=obstacles, camera_mount=False)
    scene = Scene(config)
    yield scene, np.array(cubes)
    scene.close()


def test_rendered_cubes_land_where_opencv_projects_them(marker_scene):
    import mujoco

    scene, cubes = marker_scene
    rng = np.random.default_rng(1)
    for _ in range(3):
        eye = np.array([rng.uniform(1.0, 1.5), rng.uniform(-0.5, 0.5), rng.uniform(0.6, 1.2)])
        T = look_at(eye, np.array([0.05, 0.05, 0.6]), roll=rng.uniform(-0.3, 0.3))
        scene.set_camera(T)
        r = scene.renderer
        scene._update(None)
        r.enable_segmentation_rendering()
        seg = r.render()
        r.disable_segmentation_rendering()
        uv = pixels_from_camera_points(cubes @ T[:3, :3].T + T[:3, 3], scene.intrinsics)
        for i in range(len(cubes)):
            gid = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_GEOM, f"cube{i}")
            ys, xs = np.nonzero((seg[..., 0] == gid) & (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)))
            assert len(xs) > 10
            assert np.hypot(xs.mean() - uv[i, 0], ys.mean() - uv[i, 1]) < CENTROID_TOL_PX
