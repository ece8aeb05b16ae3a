"""Tests of solver/circle_normals.py: circle normals and signed axis candidates from a cone."""

from __future__ import annotations

import numpy as np
import pytest

from solver.circle_normals import axis_candidates, plane_orientations, rotation_sense, sensed
from solver.conics import fit_ellipse_direct
from solver.errors import DegenerateTrajectoryError
from tests.solver.scene import (
    angle_between,
    circle_cone,
    circle_points,
    homogeneous,
    project_normalized,
    tilted_unit,
)

#: The cone built exactly from the 3-D circle: the normal comes out up to eigen-solver rounding.
EXACT_CONE_RAD = 1e-9

#: The cone fitted to 30 noise-free projected points (tests the fit and the normals together).
FITTED_CONE_RAD = 1e-6

#: Largest tilt of the circle's plane from facing the camera: flatter views are "nearly a line".
MAX_TILT = np.deg2rad(60.0)


def _scene(seed: int):
    """A circle with a known normal and a trajectory turning right-handedly about +normal.

    Odd seeds point the normal away from the camera, even seeds towards it, so both signs of the
    normal's z component are exercised.
    """
    rng = np.random.default_rng(seed)
    centre = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(1.3, 1.7)])
    normal = tilted_unit(rng, -centre, MAX_TILT) * (-1.0 if seed % 2 else 1.0)
    radius = rng.uniform(0.1, 0.3)
    delta = np.cumsum(rng.uniform(0.02, 0.08, 30))  # increasing, unevenly spaced joint angles
    delta -= delta[0]
    points = circle_points(centre, normal, radius, rng.uniform(0, 2 * np.pi) + delta)
    return centre, normal, radius, delta, homogeneous(project_normalized(points))


def _angle_up_to_sign(normals: np.ndarray, n: np.ndarray) -> float:
    return min(min(angle_between(m, n), angle_between(m, -n)) for m in normals)


def _signed_angle(normals: np.ndarray, n: np.ndarray) -> float:
    return min(angle_between(m, n) for m in normals)


SEEDS = range(8)


@pytest.mark.parametrize("seed", SEEDS)
def test_plane_orientations_contain_true_normal_exact_cone(seed):
    centre, normal, radius, _, _ = _scene(seed)
    normals = plane_orientations(circle_cone(centre, normal, radius))
    assert normals.shape == (2, 3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert np.all(normals[:, 2] > 0)
    assert _angle_up_to_sign(normals, normal) < EXACT_CONE_RAD


@pytest.mark.parametrize("seed", SEEDS)
def test_plane_orientations_contain_true_normal_fitted_cone(seed):
    centre, normal, radius, _, rays = _scene(seed)
    fit = fit_ellipse_direct(rays[:, :2])
    assert fit.ok, fit.reason
    assert _angle_up_to_sign(plane_orientations(fit.matrix), normal) < FITTED_CONE_RAD


@pytest.mark.parametrize("scale", [1.0, -1.0, 1e-3, -250.0])
def test_plane_orientations_ignore_the_cone_scale(scale):
    centre, normal, radius, _, _ = _scene(0)
    Q = circle_cone(centre, normal, radius)
    np.testing.assert_allclose(plane_orientations(scale * Q), plane_orientations(Q), atol=1e-12)


@pytest.mark.parametrize(
    "Q",
    [
        pytest.param(np.eye(3), id="imaginary"),
        pytest.param(np.diag([1.0, 0.0, -1.0]), id="line-pair"),
        pytest.param(np.zeros((3, 3)), id="zero"),
    ],
)
def test_plane_orientations_reject_non_elliptic_cones(Q):
    with pytest.raises(DegenerateTrajectoryError, match="are not of an elliptic cone"):
        plane_orientations(Q)


@pytest.mark.parametrize("seed", SEEDS)
def test_axis_candidates_contain_signed_normal(seed):
    centre, normal, radius, delta, rays = _scene(seed)
    candidates = axis_candidates(circle_cone(centre, normal, radius), rays, delta)
    assert candidates.shape == (2, 3)
    assert _signed_angle(candidates, normal) < EXACT_CONE_RAD
    assert _signed_angle(candidates, -normal) > 1.0  # the wrong sign is not offered


@pytest.mark.parametrize("seed", SEEDS)
def test_axis_candidates_from_fitted_cone(seed):
    _, normal, _, delta, rays = _scene(seed)
    candidates = axis_candidates(fit_ellipse_direct(rays[:, :2]).matrix, rays, delta)
    assert _signed_angle(candidates, normal) < FITTED_CONE_RAD


@pytest.mark.parametrize("seed", SEEDS)
def test_negated_delta_flips_the_sign(seed):
    centre, normal, radius, delta, rays = _scene(seed)
    Q = circle_cone(centre, normal, radius)
    forward = axis_candidates(Q, rays, delta)
    backward = axis_candidates(Q, rays, -delta)
    np.testing.assert_allclose(backward, -forward, atol=1e-12)
    assert _signed_angle(backward, -normal) < EXACT_CONE_RAD


@pytest.mark.parametrize("seed", SEEDS)
def test_reversed_frame_order_keeps_the_sign(seed):
    # Playing the same frames backwards, with their deltas, is the same rotation.
    centre, normal, radius, delta, rays = _scene(seed)
    Q = circle_cone(centre, normal, radius)
    np.testing.assert_allclose(axis_candidates(Q, rays[::-1], delta[::-1]),
                               axis_candidates(Q, rays, delta), atol=1e-12)


@pytest.mark.parametrize("seed", SEEDS)
def test_rotation_about_minus_normal_gives_minus_normal(seed):
    rng = np.random.default_rng(100 + seed)
    centre, normal, radius, delta, _ = _scene(seed)
    points = circle_points(centre, -normal, radius, rng.uniform(0, 2 * np.pi) + delta)
    rays = homogeneous(project_normalized(points))
    candidates = axis_candidates(circle_cone(centre, normal, radius), rays, delta)
    assert _signed_angle(candidates, -normal) < EXACT_CONE_RAD


def test_rotation_sense_sign_and_area():
    # A quarter turn counter-clockwise (right-handed about +z) on the unit circle in z = 1.
    angles = np.linspace(0.0, np.pi / 2, 10)
    rays = np.column_stack([np.cos(angles), np.sin(angles), np.ones(10)])
    n = np.array([0.0, 0.0, 1.0])
    assert rotation_sense(n, rays, angles) > 0
    assert rotation_sense(n, rays, -angles) < 0
    assert rotation_sense(-n, rays, angles) < 0


@pytest.mark.parametrize("seed", SEEDS)
def test_sensed_signs_either_normal_as_the_turn(seed):
    """Both signs of the true normal come back as the right-handed one; a turn the other way flips it."""
    _, normal, _, delta, rays = _scene(seed)
    for n in (normal, -normal):
        np.testing.assert_allclose(sensed(n, rays, delta), normal, atol=1e-12)
        np.testing.assert_allclose(sensed(n, rays, -delta), -normal, atol=1e-12)
