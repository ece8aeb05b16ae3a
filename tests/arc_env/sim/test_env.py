"""ArcCalib-v0: the Gymnasium contract, refusals, determinism and a short calibration episode."""

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from arc_env.sim.env import ArcCalibEnv, EnvConfig
from arc_env.sim.scene import Obstacle, SceneConfig
from planners.random_planner import RandomPlanner
from solver.errors import InvalidInputError

SMALL = SceneConfig(width=320, height=180)
#: Reduced-resolution episode (960x540, 10 random motions, fixed seed; it reaches a few mm and a few
#: mrad): bounds well below a wrong pose (centimetres, degrees), with room for platform differences.
EPISODE_MAX_ROT_RAD = 0.01
EPISODE_MAX_TRANS_M = 0.01


@pytest.fixture(scope="module")
def env():
    e = ArcCalibEnv(EnvConfig(scene=SMALL, max_motions=5))
    yield e
    e.close()


def test_registered_and_passes_the_gymnasium_checker():
    e = gym.make("ArcCalib-v0", config=EnvConfig(scene=SMALL, max_motions=3))
    try:
        check_env(e.unwrapped, skip_render_check=True)
    finally:
        e.close()


def _valid_action(env, rng):
    planner = RandomPlanner(env.session, rng)
    return planner.plan(env._observation())


def test_step_executes_a_valid_motion(env):
    obs, info = env.reset(seed=3)
    assert obs["has_estimate"] == 0 and info["refused"] == ""
    action = _valid_action(env, np.random.default_rng(0))
    obs, reward, terminated, truncated, info = env.step(action)
    assert info["refused"] == ""
    assert info["n_frames"] >= 3 and info["motion"]["n_tracks"] > 0
    assert env.observation_space.contains(obs)
    np.testing.assert_allclose(env.scene.robot.q[action["J"]], action["Q"][action["J"]] + action["delta"][0])
    assert np.isfinite(reward)


def _refused(env, action, match):
    q_before = env.scene.robot.q
    n_before = env.session.n_refused
    obs, reward, terminated, truncated, info = env.step(action)
    assert match in info["refused"], info["refused"]
    assert env.session.n_refused == n_before + 1 and info["n_refused"] == n_before + 1
    np.testing.assert_array_equal(env.scene.robot.q, q_before)  # the robot did not move
    assert reward == -env.config.refusal_penalty
    assert not terminated


def test_invalid_actions_are_refused_with_a_reason(env):
    env.reset(seed=4)
    home = env.scene.robot.home.copy()
    _refused(env, {"Q": home, "J": 0, "delta": np.array([0.05])}, "below the minimum")
    _refused(env, {"Q": home, "J": 0, "delta": np.array([np.nan])}, "finite")
    _refused(env, {"Q": home[:3], "J": 0, "delta": np.array([0.5])}, "shape")
    _refused(env, {"Q": home, "J": 9, "delta": np.array([0.5])}, "joint 9")
    bad = home.copy()
    bad[1] = 3.0
    _refused(env, {"Q": bad, "J": 0, "delta": np.array([0.5])}, "outside the limits")
    edge = home.copy()
    edge[0] = env.scene.robot.upper[0] - 0.1
    _refused(env, {"Q": edge, "J": 0, "delta": np.array([0.5])}, "sweep ends at")
    _refused(env, {"J": 0}, "keys")


def test_colliding_motions_are_refused(env):
    env.reset(seed=4)
    q = env.scene.robot.home.copy()
    q[1], q[3] = 1.7, -1.0  # shoulder pitched forward, elbow bent: the forearm is in the floor
    _refused(env, {"Q": q, "J": 0, "delta": np.array([0.5])}, "start configuration in collision")
    q[1], q[3] = 1.0, -3.0  # folded onto itself: the forearm hits the base
    _refused(env, {"Q": q, "J": 0, "delta": np.array([0.5])}, "panda0_link0")
    # a sweep that starts free and ends in the floor
    q = env.scene.robot.home.copy()
    assert env.session.refusal_reason(q, 1, 0.3) == ""
    _refused(env, {"Q": q, "J": 1, "delta": np.array([1.5])}, "sweep in collision")


def test_an_obstacle_refuses_the_motions_through_it():
    e = ArcCalibEnv(EnvConfig(scene=SceneConfig(width=160, height=90, obstacles=(
        Obstacle("wall", (0.45, 0.0, 0.5), (0.02, 0.6, 0.5)),))))
    try:
        e.reset(seed=0)
        q = e.scene.robot.home.copy()
        q[0] = -1.2
        assert "wall" in e.session.refusal_reason(q, 0, 1.5)  # joint 1 swings the arm through the wall
    finally:
        e.close()


def test_same_seed_same_episode():
    runs = []
    for _ in range(2):
        e = ArcCalibEnv(EnvConfig(scene=SMALL, max_motions=4))
        obs, _ = e.reset(seed=11)
        planner = RandomPlanner(e.session, np.random.default_rng(5))
        trace = [obs]
        for _ in range(4):
            obs, reward, *_ = e.step(planner.plan(obs))
            trace.append(obs)
            trace.append(reward)
        runs.append((trace, e.T_camera_base_true.copy()))
        e.close()
    (a, Ta), (b, Tb) = runs
    np.testing.assert_array_equal(Ta, Tb)
    for x, y in zip(a, b, strict=True):
        if isinstance(x, dict):
            for k in x:
                np.testing.assert_array_equal(x[k], y[k])
        else:
            assert x == y


def test_oracle_keypoints_need_no_rendering_and_calibrate():
    e = ArcCalibEnv(EnvConfig(scene=SMALL, max_motions=8, oracle_keypoints=True, oracle_noise_px=0.2))
    try:
        obs, _ = e.reset(seed=2)
        planner = RandomPlanner(e.session, np.random.default_rng(2))
        for _ in range(8):
            obs, _, terminated, truncated, info = e.step(planner.plan(obs))
            assert e.last_seconds["render"] == 0.0
        assert info["rot_error_rad"] < EPISODE_MAX_ROT_RAD and info["trans_error_m"] < EPISODE_MAX_TRANS_M
    finally:
        e.close()


def test_short_tracked_episode_reaches_a_bounded_error():
    e = ArcCalibEnv(EnvConfig(scene=SceneConfig(width=960, height=540), max_motions=10))
    try:
        obs, _ = e.reset(seed=0)
        planner = RandomPlanner(e.session, np.random.default_rng(0))
        for _ in range(10):
            obs, reward, terminated, truncated, info = e.step(planner.plan(obs))
            assert info["refused"] == ""
            if terminated or truncated:
                break
        assert obs["has_estimate"] == 1
        assert info["rot_error_rad"] < EPISODE_MAX_ROT_RAD
        assert info["trans_error_m"] < EPISODE_MAX_TRANS_M
        assert np.all(obs["std"] > 0)
    finally:
        e.close()


def test_make_with_the_module_prefix_works_in_a_fresh_interpreter():
    """``gymnasium.make("arc_env:ArcCalib-v0")`` imports arc_env itself: Gymnasium 1.x's way for a plugin env.

    (Gymnasium 1.x loads no ``gymnasium.envs`` entry points, so a bare ``make("ArcCalib-v0")`` without any
    import of arc_env cannot find the env; the module prefix is the supported route.)
    """
    import os
    import subprocess
    import sys

    code = ("import sys, gymnasium\n"
            "assert 'arc_env' not in sys.modules\n"
            "from gymnasium.error import NameNotFound\n"
            "try:\n"
            "    gymnasium.make('ArcCalib-v0')\n"
            "    print('BARE ok')\n"
            "except NameNotFound:\n"
            "    print('BARE NameNotFound')\n"
            "env = gymnasium.make('arc_env:ArcCalib-v0', max_episode_steps=3)\n"
            "print('PREFIX', type(env.unwrapped).__name__, env.spec.id)\n"
            "env.close()\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
    assert out.returncode == 0, out.stdout + out.stderr
    assert "PREFIX ArcCalibEnv ArcCalib-v0" in out.stdout
    assert "BARE NameNotFound" in out.stdout  # documents Gymnasium 1.x: no plugin entry points


def test_make_vec_builds_independent_envs():
    envs = gym.make_vec("ArcCalib-v0", num_envs=2, vectorization_mode="sync",
                        config=EnvConfig(scene=SMALL, max_motions=3))
    try:
        obs, info = envs.reset(seed=[1, 2])
        assert obs["has_estimate"].shape == (2,) and np.all(obs["has_estimate"] == 0)
        single = envs.single_observation_space
        for i in range(2):
            assert single.contains({k: v[i] for k, v in obs.items()})
        poses = [e.unwrapped.T_camera_base_true for e in envs.envs]
        assert not np.allclose(poses[0], poses[1])  # different seeds, different camera poses
    finally:
        envs.close()


def test_a_late_joint_log_gives_the_logs_deltas_and_the_offset_is_estimated():
    config = EnvConfig(scene=SMALL, max_motions=8, oracle_keypoints=True, oracle_noise_px=0.2, joint_latency_s=0.02)
    e = ArcCalibEnv(config)
    try:
        for delta in (0.6, -0.45):
            true = e.sweep_deltas(delta)
            logged, velocity = e.logged_deltas(true)
            lag = config.joint_speed * config.joint_latency_s  # rad the log trails by while the joint turns
            expected = np.sign(delta) * np.clip(np.abs(true) - lag, 0.0, abs(delta))
            np.testing.assert_allclose(logged, expected, atol=1e-12)
            assert logged[0] == 0.0 and np.all(np.abs(logged) <= np.abs(true) + 1e-12)
            moving = (np.abs(true) > lag) & (np.abs(true) < abs(delta) + lag)
            np.testing.assert_array_equal(velocity, np.where(moving, np.sign(delta) * config.joint_speed, 0.0))
        obs, _ = e.reset(seed=2)
        planner = RandomPlanner(e.session, np.random.default_rng(2))
        for _ in range(8):
            obs, _, terminated, truncated, info = e.step(planner.plan(obs))
        state = e.session.calibrator.state
        assert state.time_offset_s is not None and state.time_offset_std_s is not None
        # first order in the offset: a few ms short at the sweeps' abrupt starts (bench_latency), never far
        assert abs(state.time_offset_s - 0.02) < 0.004
        assert info["rot_error_rad"] < EPISODE_MAX_ROT_RAD and info["trans_error_m"] < EPISODE_MAX_TRANS_M
    finally:
        e.close()
    with pytest.raises(InvalidInputError, match="joint_latency_s"):
        EnvConfig(joint_latency_s=0.2)
    exact = ArcCalibEnv(EnvConfig(scene=SMALL))
    try:
        assert exact.logged_deltas(np.linspace(0, 0.5, 5))[1] is None
    finally:
        exact.close()


# -- overlap: each step renders its motion while a worker tracks and calibrates the previous one -------------
def _planned_actions(config, seed, n):
    """n valid actions a random planner chooses in an episode without overlap (a fixed list to replay)."""
    e = ArcCalibEnv(replace(config, overlap=False))
    try:
        obs, _ = e.reset(seed=seed)
        planner = RandomPlanner(e.session, np.random.default_rng(seed))
        actions = []
        for _ in range(n):
            actions.append(planner.plan(obs))
            obs, _, _, _, info = e.step(actions[-1])
            assert info["refused"] == ""
        return actions
    finally:
        e.close()


def _replay_actions(config, seed, actions):
    """(obs, reward, terminated, truncated, info) of each step replaying ``actions`` from reset(seed)."""
    e = ArcCalibEnv(config)
    try:
        e.reset(seed=seed)
        return [e.step(a) for a in actions]
    finally:
        e.close()


def _assert_obs_equal(a, b):
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


@pytest.mark.parametrize("oracle", [True, False], ids=["oracle", "tracked"])
def test_overlap_observes_the_same_calibration_one_motion_later(oracle):
    """Same seed and actions: with overlap, step k+1 observes what step k observed without; the end is the same."""
    n = 4
    config = EnvConfig(scene=SMALL, max_motions=n, oracle_keypoints=oracle, terminate_on_convergence=False)
    actions = _planned_actions(config, 7, n)
    off = _replay_actions(config, 7, actions)
    on = _replay_actions(replace(config, overlap=True), 7, actions)
    assert on[0][4]["motion"] is None and on[0][4]["motion_index"] is None and "n_frames" not in on[0][4]
    assert on[0][1] == pytest.approx(-config.step_cost, abs=1e-12) and on[0][0]["n_accepted"] == 0
    for k in range(1, n):
        (obs_off, _, _, _, info_off), (obs_on, _, _, _, info_on) = off[k - 1], on[k]
        assert info_on["motion"] == info_off["motion"] and info_on["motion_index"] == k - 1
        assert info_on["n_frames"] == info_off["n_frames"] and info_on["transit_rad"] == info_off["transit_rad"]
        if k < n - 1:  # (the last step also flushed: below)
            _assert_obs_equal(obs_on, obs_off)
            assert (info_on["T_camera_base"] is None) == (info_off["T_camera_base"] is None)
            if info_on["T_camera_base"] is not None:
                np.testing.assert_array_equal(info_on["T_camera_base"], info_off["T_camera_base"])
    assert [s[3] for s in on] == [s[3] for s in off] == [False] * (n - 1) + [True]
    # the last step flushed: its observation and info hold every motion, like the episode without overlap
    (obs_off, _, _, _, info_off), (obs_on, _, _, _, info_on) = off[-1], on[-1]
    _assert_obs_equal(obs_on, obs_off)
    assert info_on["flushed_motion"] == {**info_off["motion"], "index": n - 1, "n_frames": info_off["n_frames"]}
    for key in ("rot_error_rad", "trans_error_m", "stage", "n_motions"):
        assert info_on[key] == info_off[key]
    assert sum(s[1] for s in on) == pytest.approx(sum(s[1] for s in off), abs=1e-12)
    if oracle:
        assert obs_on["has_estimate"] == 1  # the comparison compared estimates


def test_overlap_passes_the_gymnasium_checker_and_same_seed_same_episode():
    config = EnvConfig(scene=SMALL, max_motions=4, overlap=True)
    e = gym.make("ArcCalib-v0", config=replace(config, max_motions=3))
    try:
        check_env(e.unwrapped, skip_render_check=True)
    finally:
        e.close()
    runs = []
    for _ in range(2):
        e = ArcCalibEnv(config)
        obs, _ = e.reset(seed=11)
        planner = RandomPlanner(e.session, np.random.default_rng(5))
        trace = [obs]
        for _ in range(4):
            obs, reward, terminated, truncated, info = e.step(planner.plan(obs))
            info.pop("T_camera_base")
            trace += [obs, reward, terminated, truncated, info]
        runs.append(trace)
        e.close()
    assert runs[1][-1]["motion_index"] == 2 and runs[1][-1]["flushed_motion"]["index"] == 3
    for x, y in zip(*runs, strict=True):
        if isinstance(x, dict) and "translation" in x:
            _assert_obs_equal(x, y)
        else:
            assert x == y


def test_overlap_flushes_when_refusals_end_the_episode():
    config = EnvConfig(scene=SMALL, max_motions=5, max_refusals=1, oracle_keypoints=True, overlap=True)
    action = _planned_actions(config, 3, 1)[0]
    e = ArcCalibEnv(config)
    try:
        e.reset(seed=3)
        obs, reward, terminated, truncated, info = e.step(action)
        assert info["motion"] is None and e.session.pending and not truncated
        home = e.scene.robot.home.copy()
        obs, reward, terminated, truncated, info = e.step({"Q": home, "J": 0, "delta": np.array([0.05])})
        assert "below the minimum" in info["refused"] and truncated and not terminated
        assert info["flushed_motion"]["index"] == 0 and "motion" not in info and not e.session.pending
        assert len(e.session.calibrator.reports) == 1 and reward == -config.refusal_penalty  # no estimate from one
    finally:
        e.close()
