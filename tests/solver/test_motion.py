"""Tests of solver/motion.py's axis refinement: the image misfit of the phase circles and its Jacobian."""

from __future__ import annotations

import numpy as np
import pytest

from solver.motion import _gather, _image_fit, _image_jacobian, _image_residuals, _refine_axis
from solver.reference_lines import centres_3d, fit_phase_circles, plane_basis, project_to_plane
from tests.solver.scene import (
    angle_between,
    circle_points,
    homogeneous,
    perpendicular,
    project_normalized,
    tilted_unit,
    unit,
)

#: Noise-free circles: the misfit at the true axis is float64 rounding of ~1e-1 normalized coordinates.
EXACT_RESIDUAL = 1e-12
#: Two float64 routes to the same closed-form fit and projection, ~300 points.
SAME_TOL = 1e-12
#: Central differences with step H: truncation ~H^2 |r'''| ~ 1e-10 and rounding ~eps |r| / H ~ 1e-11,
#: relative to the largest derivative (~1e-1); a wrong term (the basis carried along, the fit's own
#: derivative) is off by O(1) of it.
H = 1e-5
JACOBIAN_REL_TOL = 1e-6
#: Levenberg-Marquardt from 3 degrees off on exact data: its tolerances (1e-8) on ~1e-2-scaled tilts.
REFINED_RAD = 1e-7


def _circles(rng: np.random.Generator, n_tracks: int = 8, n_frames: int = 25):
    """Rays (one (M, 3) array per track) and joint angles of points turning about one camera-frame line.

    Points are turned with scipy's Rotation about a known axis through a known point and projected with a
    plain pinhole (tests/solver/scene.py), not with the solver's geometry.
    """
    point = np.array([0.1, -0.05, 1.4])  # on the axis, camera frame, m
    axis = tilted_unit(rng, -point, np.deg2rad(50.0))
    rays, deltas = [], []
    for _ in range(n_tracks):
        centre = point + rng.uniform(-0.2, 0.2) * axis
        delta = np.sort(rng.uniform(0.0, 1.2, n_frames))
        ring = circle_points(centre, axis, rng.uniform(0.05, 0.2), rng.uniform(0, 2 * np.pi) + delta)
        rays.append(homogeneous(project_normalized(ring)))
        deltas.append(delta)
    return rays, deltas, axis


def _tilted(axis: np.ndarray, rng: np.random.Generator, angle: float) -> np.ndarray:
    return tilted_unit(rng, axis, angle) if angle else axis


def test_image_misfit_vanishes_at_the_true_axis(rng):
    rays, deltas, axis = _circles(rng)
    points = _gather(rays, deltas, list(range(len(rays))))
    assert np.max(np.abs(_image_residuals(points, axis))) < EXACT_RESIDUAL
    assert np.max(np.abs(_image_residuals(points, _tilted(axis, rng, 0.05)))) > 1e3 * EXACT_RESIDUAL


def test_image_misfit_is_the_phase_circles_seen_from_the_camera(rng):
    """The same misfit through the public fit: fit_phase_circles on sigma, model points c + r exp(i (delta + beta))
    lifted onto sigma and projected through the camera centre."""
    rays, deltas, axis = _circles(rng)
    points = _gather(rays, deltas, list(range(len(rays))))
    a = _tilted(axis, rng, 0.08)
    circles = fit_phase_circles(project_to_plane(points.rays, a), points.delta, points.ids, points.n)
    turn = points.delta + circles.phases[points.ids]
    model = circles.centres[points.ids] + circles.radii[points.ids, None] * np.column_stack([np.cos(turn),
                                                                                             np.sin(turn)])
    on_sigma = centres_3d(model, a)  # (P, 3): sigma may lie behind the camera (a . X = 1 with a away from it)
    expected = on_sigma[:, :2] / on_sigma[:, 2:] - points.rays[:, :2]
    np.testing.assert_allclose(_image_residuals(points, a), expected, rtol=0, atol=SAME_TOL)


@pytest.mark.parametrize("tilt_deg", [0.0, 2.0, 10.0], ids=["at-truth", "2deg", "10deg"])
def test_image_jacobian_matches_central_differences(rng, tilt_deg):
    rays, deltas, axis = _circles(rng)
    points = _gather(rays, deltas, list(range(len(rays))))
    a = _tilted(axis, rng, np.deg2rad(tilt_deg))
    u = perpendicular(a)
    directions = np.array([u, np.cross(a, u), unit(0.6 * u - 0.8 * np.cross(a, u))])  # perpendicular to a
    J = _image_jacobian(points, _image_fit(points, a), directions)  # (2, P, 3)
    for j, d in enumerate(directions):
        plus, minus = unit(a + H * d), unit(a - H * d)  # the unit sphere's curve through a along d
        fd = (_image_fit(points, plus).residuals - _image_fit(points, minus).residuals) / (2 * H)
        assert np.max(np.abs(J[..., j] - fd)) <= JACOBIAN_REL_TOL * np.max(np.abs(fd)), j


def test_image_jacobian_does_not_depend_on_sigmas_basis(rng):
    """The basis plane_basis picks jumps where the axis's smallest component changes; the misfit and its
    derivative do not see it: both sides of such a jump agree."""
    rays, deltas, axis = _circles(rng)
    points = _gather(rays, deltas, list(range(len(rays))))
    a = unit(np.array([0.3, 0.3 + 1e-9, -1.0]))  # |a_x| < |a_y|: helper x; nudged: helper y
    b = unit(np.array([0.3 + 1e-9, 0.3, -1.0]))
    assert not np.allclose(plane_basis(a)[0], plane_basis(b)[0], atol=0.1)
    d = unit(np.cross(a, [0.0, 0.0, 1.0]))
    Ja = _image_jacobian(points, _image_fit(points, a), d[None])
    Jb = _image_jacobian(points, _image_fit(points, b), (d - (d @ b) * b)[None])
    np.testing.assert_allclose(Ja, Jb, rtol=0, atol=1e-6 * np.max(np.abs(Ja)))


def test_refined_axis_recovers_the_true_axis(rng):
    rays, deltas, axis = _circles(rng)
    points = _gather(rays, deltas, list(range(len(rays))))
    start = _tilted(axis, rng, np.deg2rad(3.0))
    assert angle_between(_refine_axis(points, start), axis) < REFINED_RAD
