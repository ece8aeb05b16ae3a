"""The first motions' observability: concurrent axes leave the pose free, one more axis off their point fixes it;
the draws without executing are the executed episode's first motions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from arc_env.bench.episodes import EpisodeSpec, make_env
from arc_env.bench.first_motions import axes_observability, draw_first_motions
from arc_env.bench.poses import benchmark_camera_pose
from planners.context import estimate_from_observation
from planners.random_planner import RandomPlanner
from solver.calibration import MIN_OBSERVABILITY


def _lines_through(point: np.ndarray, n: int, rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """n random unit axes through ``point``, each given by a different point along it."""
    axes = Rotation.random(n, random_state=rng).apply([0.0, 0.0, 1.0])
    return [(a, point + rng.uniform(-0.3, 0.3) * a) for a in axes]


def test_axes_through_one_point_leave_the_pose_free_and_one_more_fixes_it():
    rng = np.random.default_rng(5)
    T = benchmark_camera_pose(0)
    centre = np.array([0.1, -0.05, 0.4])
    concurrent = _lines_through(centre, 4, rng)
    assert axes_observability(concurrent, T) < 1e-8
    # the same directions, one line moved 0.2 m off the common point (perpendicular to itself)
    a, p = concurrent[0]
    off = np.cross(a, [1.0, 0.0, 0.0])
    moved = [(a, p + 0.2 * off / np.linalg.norm(off)), *concurrent[1:]]
    assert axes_observability(moved, T) > MIN_OBSERVABILITY


def test_one_axis_or_parallel_axes_give_zero():
    T = benchmark_camera_pose(1)
    a = np.array([0.0, 0.0, 1.0])
    assert axes_observability([(a, np.zeros(3))], T) == 0.0
    assert axes_observability([(a, np.zeros(3)), (a, np.array([0.3, 0.0, 0.0]))], T) == 0.0


def test_the_panda_shoulder_joints_leave_the_pose_free_the_elbow_fixes_it():
    spec = EpisodeSpec("random", 0, 0, motions=3, width=192, height=108, robot="panda")
    env, _ = make_env(spec)
    try:
        robot = env.session.robot
        T = np.asarray(env.scene.T_camera_base)
        rng = np.random.default_rng(2)
        for _ in range(5):
            q = rng.uniform(robot.lower, robot.upper)
            shoulder = [robot.axis_and_point(q, j) for j in range(3)]
            # independent check that the three axes meet in one point: the least-squares point is on all three
            A = sum(np.eye(3) - np.outer(a, a) for a, _ in shoulder)
            b = sum((np.eye(3) - np.outer(a, a)) @ p for a, p in shoulder)
            meet = np.linalg.solve(A, b)
            assert max(np.linalg.norm(np.cross(meet - p, a)) for a, p in shoulder) < 1e-9
            assert axes_observability(shoulder, T) < MIN_OBSERVABILITY
            assert axes_observability([*shoulder, robot.axis_and_point(q, 3)], T) > MIN_OBSERVABILITY
    finally:
        env.close()


@pytest.mark.parametrize("seed", [0, 1])
def test_the_draws_are_the_executed_episodes_first_motions(seed):
    spec = EpisodeSpec("random", 0, seed, motions=3, width=192, height=108, robot="panda")
    drawn = draw_first_motions(spec, 3)
    env, observation = make_env(spec)
    executed = []
    try:
        planner = RandomPlanner(env.session, np.random.default_rng(spec.rng_seed))
        while len(executed) < 3 and estimate_from_observation(observation) is None:
            action = planner.plan(observation)
            executed.append(int(action["J"]))
            observation, *_ = env.step(action)
    finally:
        env.close()
    assert len(executed) >= 2  # no estimate from fewer than two motions
    assert drawn.joints[:len(executed)] == tuple(executed)
    assert len(drawn.observability) == 3 and drawn.observability[0] == 0.0
