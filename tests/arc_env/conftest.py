"""Shared fixtures of the arc_env tests (the synthetic sweeps live in the test modules)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed generator, fresh for every test."""
    return np.random.default_rng(20240611)
