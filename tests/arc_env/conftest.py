"""Shared fixtures of the arc_env tests (the synthetic sweeps live in the test modules)."""

from __future__ import annotations

import numpy as np
import pytest

from arc_env.sim.scene import Scene, SceneConfig
from solver import look_at


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed generator, fresh for every test."""
    return np.random.default_rng(20240611)


@pytest.fixture(scope="module")
def panda_scene():
    """The default Panda scene at 640x360, its camera looking at the arm from the front right (one per module)."""
    scene = Scene(SceneConfig(width=640, height=360))
    scene.set_camera(look_at(np.array([1.6, 0.7, 1.0]), np.array([0.3, 0.0, 0.45]), 0.2))
    yield scene
    scene.close()
