"""The marker baseline: the board in the scene, its detection, the hand-eye solve, a whole run."""

import cv2
import numpy as np
import pytest

from arc_env.bench.marker_baseline import (
    MarkerBaseline,
    detect_board,
    shah_robot_world_hand_eye,
    solve_eye_to_hand,
)
from arc_env.sim.env import ArcCalibEnv, EnvConfig
from arc_env.sim.marker_board import BOARD_BODY, BOARD_GEOM, MarkerBoard
from arc_env.sim.scene import Scene, SceneConfig
from planners.collision import CollisionChecker
from solver import sample_camera_pose
from solver.errors import InvalidInputError
from solver.frames import perturb, pose_errors, transform_from_rt
from solver.observations import CameraIntrinsics

#: 960x540 with the camera 1.2 m from the workspace (camera pose 4 of the benchmarks).
SCENE = SceneConfig(width=960, height=540, marker_board=MarkerBoard())
N_POSES = 8
#: PnP of a rendered board against the board body's true pose, at about 1 m and 960x540: measured
#: 0.3 mrad / 0.6 mm at 1080p; a wrong texture mapping (mirror, offset, scale) is off by degrees or
#: centimetres.
PNP_MAX_ROT_RAD = 0.005
PNP_MAX_TRANS_M = 0.005
#: Hand-eye from 8 board poses at 960x540 (measured about 1 mrad, 1 mm at 10 poses on this camera);
#: wrong frames or an inverted convention give errors of degrees and decimetres.
RUN_MAX_ROT_RAD = 0.005
RUN_MAX_TRANS_M = 0.005


def _random_transform(rng, scale):
    rot = rng.normal(size=3)
    return perturb(np.eye(4), np.concatenate([rot, rng.normal(size=3) * scale]))


@pytest.fixture(scope="module")
def env():
    e = ArcCalibEnv(EnvConfig(scene=SCENE))
    T = sample_camera_pose(np.random.default_rng(1004), target=np.asarray(e.config.camera_target))
    e.reset(seed=4, options={"camera_pose": T})
    yield e
    e.close()


@pytest.fixture(scope="module")
def run(env):
    baseline = MarkerBaseline(env, np.random.default_rng(4))
    return baseline, baseline.run(N_POSES)


def test_default_scene_has_no_board():
    scene = Scene(SceneConfig(width=64, height=48))
    assert BOARD_BODY not in [scene.model.body(b).name for b in range(scene.model.nbody)]


def test_board_keeps_its_texture_and_collides(env):
    m = env.scene.model
    assert m.mat(m.geom(BOARD_GEOM).matid[0]).name == "arc_marker_board"  # not the speckle paint
    # Some configuration is free without the board and in collision with it.
    plain = Scene(SceneConfig(width=64, height=48))
    plain_checker = CollisionChecker(plain.model, plain.robot.arm_joints, qpos_ref=plain.data.qpos.copy())
    rng = np.random.default_rng(0)
    for _ in range(3000):
        q = rng.uniform(plain.robot.lower, plain.robot.upper)
        if not plain_checker.in_collision(q)[0] and env.session.checker.in_collision(q)[0]:
            return
    pytest.fail("the board never changed a collision verdict in 3000 configurations")


def test_unknown_dictionary_lists_the_valid_ones():
    with pytest.raises(InvalidInputError, match="DICT_4X4_50"):
        MarkerBoard(dictionary="DICT_9X9")


def test_shah_recovers_an_exact_pose(rng):
    T_camera_base, T_flange_board = _random_transform(rng, 1.0), _random_transform(rng, 0.2)
    T_base_flange = np.array([_random_transform(rng, 0.5) for _ in range(6)])
    T_camera_board = np.array([T_camera_base @ T @ T_flange_board for T in T_base_flange])
    X, Z = solve_eye_to_hand(T_base_flange, T_camera_board, use_opencv=False)
    np.testing.assert_allclose(X, T_camera_base, atol=1e-9)
    np.testing.assert_allclose(Z, T_flange_board, atol=1e-9)


@pytest.mark.skipif(not hasattr(cv2, "calibrateRobotWorldHandEye"),
                    reason=f"OpenCV {cv2.__version__} does not bind calibrateRobotWorldHandEye")
def test_numpy_shah_matches_opencv(rng):
    """Poses that a pair (X, Z) explains, each then perturbed by 0.05 rad / 0.05 m: no exact solution.

    (On poses with no solution near at all, e.g. eight random A_i and B_i, OpenCV 5.1.0 returns another Z than
    OpenCV 4.10.0 and ``shah_robot_world_hand_eye``, with a larger residual in A_i X = Z B_i.)
    """
    X_true, Z_true = _random_transform(rng, 1.0), _random_transform(rng, 1.0)
    T_B = np.array([_random_transform(rng, 0.5) for _ in range(8)])
    T_A = np.array([perturb(Z_true @ B @ np.linalg.inv(X_true), rng.normal(size=6) * 0.05) for B in T_B])
    X, Z = shah_robot_world_hand_eye(T_A, T_B)
    assert np.abs(X - X_true).max() < 0.5 and np.abs(Z - Z_true).max() < 0.5  # near the pair, not exact
    R_x, t_x, R_z, t_z = cv2.calibrateRobotWorldHandEye(
        list(T_A[:, :3, :3]), list(T_A[:, :3, 3:]), list(T_B[:, :3, :3]), list(T_B[:, :3, 3:]),
        method=cv2.CALIB_ROBOT_WORLD_HAND_EYE_SHAH)
    np.testing.assert_allclose(X, transform_from_rt(R_x, np.ravel(t_x)), atol=1e-9)
    np.testing.assert_allclose(Z, transform_from_rt(R_z, np.ravel(t_z)), atol=1e-9)


def test_solver_needs_three_poses():
    with pytest.raises(InvalidInputError, match="at least 3"):
        solve_eye_to_hand(np.tile(np.eye(4), (2, 1, 1)), np.tile(np.eye(4), (2, 1, 1)))


def test_board_is_detected_where_it_is(env, run):
    baseline, result = run
    q = result.views[0].q
    env.scene.robot.set_q(q)
    det = detect_board(env.scene.render(), baseline.board, env.intrinsics)
    assert det is not None and len(det.corners_px) >= 6
    T_true = env.T_camera_base_true @ baseline.true_board_pose(q)
    rot, trans = pose_errors(det.T_camera_board, T_true)
    assert rot < PNP_MAX_ROT_RAD and trans < PNP_MAX_TRANS_M


def test_poses_are_collision_free_and_spread(env, run):
    _, result = run
    assert len(result.views) == N_POSES
    for view in result.views:
        assert not env.session.checker.in_collision(view.q)[0]
        assert np.all(view.q >= env.scene.robot.lower) and np.all(view.q <= env.scene.robot.upper)
    R = np.array([v.T_base_flange[:3, :3] for v in result.views])
    angles = [np.arccos(np.clip((np.trace(R[i].T @ R[j]) - 1) / 2, -1, 1))
              for i in range(len(R)) for j in range(i)]
    assert min(angles) > 0.1  # no two poses nearly alike


def test_run_recovers_the_camera_and_the_mount(env, run):
    baseline, result = run
    assert result.estimates[0] is None and result.estimates[1] is None  # fewer than 3 views
    rot, trans = pose_errors(result.T_camera_base, env.T_camera_base_true)
    assert rot < RUN_MAX_ROT_RAD and trans < RUN_MAX_TRANS_M
    # The hand-eye estimate of the board on the flange matches how the scene mounted it.
    rot, trans = pose_errors(result.T_flange_board, baseline.board.T_mount_board)
    assert rot < RUN_MAX_ROT_RAD and trans < RUN_MAX_TRANS_M


def test_baseline_needs_a_board_scene():
    e = ArcCalibEnv(EnvConfig(scene=SceneConfig(width=64, height=48)))
    try:
        e.reset(seed=0)
        with pytest.raises(InvalidInputError, match="marker_board"):
            MarkerBaseline(e)
    finally:
        e.close()


def test_a_fisheye_camera_is_refused():
    fisheye = CameraIntrinsics(K=np.array([[300.0, 0, 479.5], [0, 300.0, 269.5], [0, 0, 1]]), dist=np.zeros(4),
                               width=960, height=540, model="fisheye")
    with pytest.raises(InvalidInputError, match="marker baseline .* pinhole model .* fisheye camera is not supported"):
        detect_board(np.zeros((540, 960), np.uint8), MarkerBoard(), fisheye)
