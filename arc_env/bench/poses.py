"""The benchmarks' fixed camera poses, the same in every script, mode and method, scaled to each robot.

The poses were chosen around the default Panda: ``BENCHMARK_TARGET`` and 1-2.5 m from it. Another robot
(``arc_env.robot.library``) gets the same poses moved and scaled to its size (``benchmark_view``): the
cameras look at the same place relative to the arm and stand as much farther or nearer as the arm is
larger or smaller, so every robot fills the image about as much as the Panda does.
"""

from __future__ import annotations

import functools

import numpy as np

from arc_env.robot.model import RobotModel, RobotSource
from solver.arrays import FloatArray
from solver.synthetic import sample_camera_pose

#: Where the benchmark cameras look, m, base frame (``arc_env.sim.env.EnvConfig.camera_target``'s default).
BENCHMARK_TARGET = (0.3, 0.0, 0.45)
#: (min, max) m from the target of the benchmark cameras for the Panda (``sample_camera_pose``'s default).
BENCHMARK_DISTANCE = (1.0, 2.5)


def benchmark_camera_pose(index: int, target: tuple[float, float, float] = BENCHMARK_TARGET,
                          scale: float = 1.0) -> FloatArray:
    """Camera pose number ``index`` of the benchmark scripts, the same in every script, mode and method.

    Args:
        index: the pose's number.
        target: (3,) m, base frame: where the camera looks.
        scale: the distance range ``BENCHMARK_DISTANCE`` is multiplied by this (``benchmark_view``).

    Returns:
        (4, 4) float64 T_camera_base, sampled like ``reset`` does (``sample_camera_pose``) from a
        generator seeded with 1000 + index, looking at ``target`` (m, base frame). The same random
        draws for every target and scale: only the camera's distance scales.
    """
    lo, hi = BENCHMARK_DISTANCE
    return sample_camera_pose(np.random.default_rng(1000 + index), target=np.asarray(target, dtype=np.float64),
                              distance=(lo * scale, hi * scale))


def arm_extent(robot: RobotModel) -> tuple[FloatArray, float]:
    """The centre (3,) m, base frame, and the diagonal (m) of the box around the arm at its home configuration.

    The box holds the vertices of the drawn geoms that the first arm joint moves (the arm without
    its fixed base). The robot's state is left as it was.
    """
    saved = robot.q
    robot.set_q(robot.home)
    body, local = robot.surface_points(0)
    points = robot.points_base(body, local)
    robot.set_q(saved)
    lo, hi = points.min(axis=0), points.max(axis=0)
    return (lo + hi) / 2.0, float(np.linalg.norm(hi - lo))


@functools.cache
def _panda_extent() -> tuple[FloatArray, float]:
    return arm_extent(RobotModel.load(RobotSource()))


def benchmark_view(robot: RobotModel) -> tuple[tuple[float, float, float], float]:
    """Where the benchmark cameras look at ``robot`` (m, base frame) and how their distances scale.

    The default Panda: ``BENCHMARK_TARGET`` and 1. Another robot: with the arm's home extent
    (``arm_extent``: centre c and diagonal d) against the Panda's (c_p, d_p), the scale s = d / d_p and
    the target c + s (``BENCHMARK_TARGET`` - c_p): the same place relative to the arm, scaled.
    """
    if robot.source == RobotSource():
        return BENCHMARK_TARGET, 1.0
    centre, size = arm_extent(robot)
    panda_centre, panda_size = _panda_extent()
    scale = size / panda_size
    target = centre + scale * (np.asarray(BENCHMARK_TARGET) - panda_centre)
    return (float(target[0]), float(target[1]), float(target[2])), scale


__all__ = ["BENCHMARK_DISTANCE", "BENCHMARK_TARGET", "arm_extent", "benchmark_camera_pose", "benchmark_view"]
