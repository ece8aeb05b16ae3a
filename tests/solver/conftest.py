"""Shared fixtures of the solver tests (the geometry helpers live in ``tests/solver/scene.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from solver.observations import CameraIntrinsics
from tests.solver.scene import HEIGHT, WIDTH, K


@pytest.fixture
def camera() -> CameraIntrinsics:
    """The house test camera without distortion."""
    return CameraIntrinsics(K=K.copy(), width=WIDTH, height=HEIGHT)


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed generator, fresh for every test."""
    return np.random.default_rng(20240611)
