"""InformedPlanner: the score's preferences, valid collision-free motions, determinism; RandomPlanner too."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from arc_env.sim.env import ArcCalibEnv, EnvConfig
from arc_env.sim.scene import SceneConfig
from planners.informed import InformedPlanner
from planners.informed.candidates import line_distance
from planners.random_planner import RandomPlanner
from solver import look_at

SMALL = SceneConfig(width=320, height=180)
#: The upper arm tilted 0.8 rad forward, the forearm folded back up: joint 1's axis is vertical,
#: joint 3's (the upper arm's roll) is tilted 0.8 rad from vertical.
Q_TILTED = np.array([0.0, 0.8, 0.0, -2.0, 0.0, 1.8, 0.8])
#: A camera 2 m above the shoulder looking straight down: joint 1's axis points at it.
T_ABOVE = look_at(np.array([0.05, 0.0, 2.3]), np.array([0.05, 0.0, 0.3]))


@pytest.fixture(scope="module")
def env_above():
    e = ArcCalibEnv(EnvConfig(scene=SMALL, oracle_keypoints=True))
    e.reset(seed=0, options={"camera_pose": T_ABOVE})
    yield e
    e.close()


def test_score_prefers_a_tilted_axis_to_one_pointing_at_the_camera(env_above):
    planner = InformedPlanner(env_above.session, np.random.default_rng(0))
    axis0 = env_above.scene.robot.axis_and_point(Q_TILTED, 0)[0]
    axis2 = env_above.scene.robot.axis_and_point(Q_TILTED, 2)[0]
    view = T_ABOVE[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # optical axis in the base frame
    assert abs(axis0 @ view) > 0.99 and 0.5 < abs(axis2 @ view) < 0.9
    so_far = planner.information.information_so_far(T_ABOVE)
    at_camera = planner.information.score(Q_TILTED, 0, 0.8, T_ABOVE, so_far)
    tilted = planner.information.score(Q_TILTED, 2, 0.8, T_ABOVE, so_far)
    assert at_camera.in_view >= 0.7 and tilted.in_view >= 0.7
    # joint 1 swings the whole arm (larger circles, more tracks) and still loses
    assert tilted.gain > at_camera.gain


def test_same_motion_scores_higher_seen_obliquely_than_along_its_axis(env_above):
    planner = InformedPlanner(env_above.session, np.random.default_rng(0))
    centre = np.array([0.05, 0.0, 0.3])
    T_side = look_at(centre + 2.0 * np.array([0.0, np.cos(np.pi / 6), np.sin(np.pi / 6)]), centre)
    gains, weakest = [], []
    for T in (T_ABOVE, T_side):  # the same 2 m from the shoulder; joint 1's axis at 0 and 60 degrees
        scored = planner.information.score(Q_TILTED, 0, 0.8, T, planner.information.information_so_far(T))
        assert scored.in_view >= 0.7
        gains.append(scored.gain)
        # one turn about a known axis informs 3 of the pose's 6 directions; the weakest of those
        weakest.append(np.linalg.eigvalsh(planner.information.predicted_information(Q_TILTED, 0, 0.8, T)[0])[3])
    assert gains[1] > gains[0] + 1.0  # e-fold more volume shrinkage, at least
    # seen along its axis the turn leaves the depth to the unknown points: near-null direction
    assert weakest[0] * 5 < weakest[1]


def test_motions_out_of_view_score_minus_infinity(env_above):
    planner = InformedPlanner(env_above.session, np.random.default_rng(0))
    away = T_ABOVE.copy()
    away[:3, 3] += np.array([5.0, 0.0, 0.0])  # the camera looks 5 m to the side of the robot
    scored = planner.information.score(Q_TILTED, 2, 0.8, away, planner.information.information_so_far(T_ABOVE))
    assert scored.gain == -np.inf and scored.in_view < 0.7


def test_occlusion_verdicts_match_the_full_resolution_depth(env_above):
    planner = InformedPlanner(env_above.session, np.random.default_rng(0))
    s = env_above.scene
    body, local = s.robot.surface_points(2)
    s.robot.set_swept(Q_TILTED, 2, 0.4)
    uv, ok = s.robot.project_points(body, local, T_ABOVE, s.intrinsics, min_depth=0.1, margin_px=2)
    verdict = planner.information.visible_points(planner.renderer, Q_TILTED, 2, 0.4, body, local, T_ABOVE, uv)[ok]
    depth = s.depth()  # full resolution, the true camera
    z = (s.robot.points_base(body, local) @ T_ABOVE[:3, :3].T + T_ABOVE[:3, 3])[ok, 2]
    col, row = np.round(uv[ok]).astype(int).T
    truth = z <= depth[row, col] + 0.01
    s.robot.set_q(s.robot.home)
    # surface points all round the links: the far sides are hidden, the near sides seen
    assert 0.2 < verdict.mean() < 0.8
    assert np.mean(verdict == truth) > 0.9


def test_occlusion_can_only_lower_the_gain(env_above):
    planner = InformedPlanner(env_above.session, np.random.default_rng(0))
    so_far = planner.information.information_so_far(T_ABOVE)
    bound = planner.information.score(Q_TILTED, 2, 0.8, T_ABOVE, so_far)
    exact = planner.information.score(Q_TILTED, 2, 0.8, T_ABOVE, so_far, occlusion=True)
    assert exact.occlusion and not bound.occlusion
    assert 0 < exact.gain < bound.gain


def test_line_distance_matches_a_brute_force_search():
    rng = np.random.default_rng(3)
    for _ in range(5):
        p1, p2 = rng.normal(size=3), rng.normal(size=3)
        a1, a2 = rng.normal(size=3), rng.normal(size=3)
        a1, a2 = a1 / np.linalg.norm(a1), a2 / np.linalg.norm(a2)
        s = np.linspace(-20, 20, 1601)
        pts1 = p1 + s[:, None] * a1
        # exact minimum over the second line for each point of the first, then a fine grid on the first
        rel = pts1 - p2
        d = np.linalg.norm(rel - np.outer(rel @ a2, a2), axis=1)
        assert line_distance(p1, a1, p2, a2) == pytest.approx(d.min(), abs=2e-3)
    a = np.array([0.0, 0.0, 1.0])
    assert line_distance(np.zeros(3), a, np.array([0.3, 0.4, 2.0]), a) == pytest.approx(0.5)


@pytest.mark.parametrize("planner_cls", [RandomPlanner, InformedPlanner], ids=["random", "informed"])
def test_planner_yields_only_valid_collision_free_motions(planner_cls):
    env = ArcCalibEnv(EnvConfig(scene=SMALL, max_motions=8, oracle_keypoints=True))
    try:
        obs, _ = env.reset(seed=4)
        planner = planner_cls(env.session, np.random.default_rng(4))
        for _ in range(8):
            obs, _, terminated, truncated, info = env.step(planner.plan(obs))
            assert info["refused"] == ""
            q, joint, delta = env.session.executed[-1]
            assert env.session.checker.sweep_free(q, joint, delta, 0.002)[0]  # finer than the env's 5 mm
            w = env.session.last_transit.waypoints
            assert all(env.session.checker.path_free(a, b, 0.002)[0] for a, b in zip(w[:-1], w[1:], strict=True))
            if terminated or truncated:
                break
        assert len(env.session.executed) == 8
    finally:
        env.close()


def test_informed_planner_is_deterministic_with_a_seed():
    actions = []
    for _ in range(2):
        env = ArcCalibEnv(EnvConfig(scene=SMALL, max_motions=5, oracle_keypoints=True))
        obs, _ = env.reset(seed=9)
        planner = InformedPlanner(env.session, np.random.default_rng(9))
        run = []
        for _ in range(5):
            action = planner.plan(obs)
            run.append(action)
            obs, *_ = env.step(action)
        actions.append(run)
        env.close()
    for a, b in zip(*actions, strict=True):
        np.testing.assert_array_equal(a["Q"], b["Q"])
        assert a["J"] == b["J"]
        np.testing.assert_array_equal(a["delta"], b["delta"])


def test_pose_hypotheses_share_the_true_rotation_and_span_the_free_depth():
    """Two motions with axes: the hypotheses have the true R and lie on the family through the true t."""
    centre = np.array([0.3, 0.0, 0.4])
    T_true = look_at(centre + np.array([1.2, -1.0, 0.6]), centre)
    env = ArcCalibEnv(EnvConfig(scene=SceneConfig(width=960, height=540), oracle_keypoints=True))
    try:
        env.reset(seed=1, options={"camera_pose": T_true})
        planner = InformedPlanner(env.session, np.random.default_rng(1))
        assert planner.pose_hypotheses() == []  # nothing executed
        q = np.array([0.2, 0.3, 0.0, -1.8, 0.9, 1.9, 0.8])
        for joint, delta in ((0, 0.8), (3, -0.9)):  # base and elbow: skew, perpendicular axes
            _, _, _, _, info = env.step({"Q": q, "J": joint, "delta": np.array([delta])})
            assert info["refused"] == ""
        assert all(env.session.calibrator.motion_geometry(i) is not None for i in range(2))
        hypotheses = planner.pose_hypotheses()
        assert len(hypotheses) == planner.config.n_hypotheses
        R_true, t_true = T_true[:3, :3], T_true[:3, 3]
        ts = np.array([T[:3, 3] for T in hypotheses])
        u = (ts[-1] - ts[0]) / np.linalg.norm(ts[-1] - ts[0])
        for T in hypotheses:
            angle = np.linalg.norm(Rotation.from_matrix(T[:3, :3] @ R_true.T).as_rotvec())
            assert angle < 0.02  # rad: two oracle axes at 0.5 px
        off = t_true - ts[0]
        assert np.linalg.norm(off - (off @ u) * u) < 0.03  # m: the true pose is (nearly) a member
        anchor = np.mean([env.scene.robot.axis_and_point(q, j)[1] for j in (0, 3)], axis=0)
        depths = [(T[:3, :3] @ anchor + T[:3, 3])[2] for T in hypotheses]
        lo, hi = planner.config.hypothesis_depths
        assert lo <= depths[0] < depths[1] < depths[2] <= hi
        action = planner.plan({"has_estimate": 0})  # plans with the hypotheses: a valid motion
        assert env.session.refusal_reason(action["Q"], action["J"], float(action["delta"][0])) == ""
        assert len(planner.last_candidates) > 0
    finally:
        env.close()
