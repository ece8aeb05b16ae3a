"""The benchmarks' fixed camera poses, the same in every script, mode and method."""

from __future__ import annotations

import numpy as np

from solver.arrays import FloatArray
from solver.synthetic import sample_camera_pose

#: Where the benchmark cameras look, m, base frame (``arc_env.sim.env.EnvConfig.camera_target``'s default).
BENCHMARK_TARGET = (0.3, 0.0, 0.45)


def benchmark_camera_pose(index: int, target: tuple[float, float, float] = BENCHMARK_TARGET) -> FloatArray:
    """Camera pose number ``index`` of the benchmark scripts, the same in every script, mode and method.

    Returns:
        (4, 4) float64 T_camera_base, sampled like ``reset`` does (``sample_camera_pose``) from a
        generator seeded with 1000 + index, looking at ``target`` (m, base frame).
    """
    return sample_camera_pose(np.random.default_rng(1000 + index), target=np.asarray(target, dtype=np.float64))


