"""Tests of solver/reference_lines.py: phase-model circles on sigma and the reference plane."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from solver.reference_lines import (
    PhaseCircles,
    candidate_score,
    candidate_scores,
    centres_3d,
    fit_phase_circles,
    fit_reference_plane,
    plane_basis,
    project_to_plane,
)
from tests.solver.scene import (
    angle_between,
    circle_points,
    homogeneous,
    perpendicular,
    project_normalized,
    tilted_unit,
    unit,
)

#: Closed-form least squares on exact data: float64 rounding of sums over ~30 points.
EXACT_TOL = 1e-10

#: Relative agreement of two minimizations of the same cost (closed form and 1-D search).
COST_REL_TOL = 1e-9

#: The reference plane's normal from noise-free centres: an SVD of a few 2-vectors.
RHO_RAD = 1e-9


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def _phase_tracks(rng: np.random.Generator, noise: float = 0.0):
    """Three 2-D phase-model circles with different sizes and lengths, points shuffled together."""
    centres = np.array([[0.3, -0.2], [-1.0, 0.5], [0.05, 0.07]])
    radii = np.array([0.1, 0.8, 0.02])
    phases = np.array([0.4, -2.9, 3.0])
    lengths = [25, 12, 40]
    z, deltas, ids = [], [], []
    for j, m in enumerate(lengths):
        delta = np.sort(rng.uniform(-0.3, 1.6, m))
        zj = centres[j, 0] + 1j * centres[j, 1] + radii[j] * np.exp(1j * (delta + phases[j]))
        z.append(zj + noise * radii[j] * (rng.normal(size=m) + 1j * rng.normal(size=m)))
        deltas.append(delta)
        ids.append(np.full(m, j))
    z, delta, ids = np.concatenate(z), np.concatenate(deltas), np.concatenate(ids)
    order = rng.permutation(z.size)
    points = np.column_stack([z.real, z.imag])[order]
    return points, delta[order], ids[order], centres, radii, phases, lengths


def _model_cost(points, delta, centre, radius, phase) -> float:
    z = points[:, 0] + 1j * points[:, 1]
    model = centre[0] + 1j * centre[1] + radius * np.exp(1j * (delta + phase))
    return float(np.sum(np.abs(z - model) ** 2))


def _best_cost_at_phase(points: np.ndarray, delta: np.ndarray, beta: float) -> float:
    """Least-squares cost with the phase fixed: linear in (centre, signed radius)."""
    w = np.exp(1j * (delta + beta))
    design = np.concatenate([np.column_stack([np.ones_like(delta), np.zeros_like(delta), w.real]),
                             np.column_stack([np.zeros_like(delta), np.ones_like(delta), w.imag])])
    target = np.concatenate([points[:, 0], points[:, 1]])
    solution = np.linalg.lstsq(design, target, rcond=None)[0]
    return float(np.sum((design @ solution - target) ** 2))


def test_phase_circles_recover_exact_circles(rng):
    points, delta, ids, centres, radii, phases, lengths = _phase_tracks(rng)
    fit = fit_phase_circles(points, delta, ids, 3)
    assert isinstance(fit, PhaseCircles)
    np.testing.assert_allclose(fit.centres, centres, atol=EXACT_TOL)
    np.testing.assert_allclose(fit.radii, radii, atol=EXACT_TOL)
    np.testing.assert_allclose(_wrap(fit.phases - phases), 0.0, atol=1e-8)
    np.testing.assert_array_equal(fit.counts, lengths)
    assert np.all(fit.costs < EXACT_TOL**2)


def test_phase_circle_costs_are_the_returned_models_costs(rng):
    points, delta, ids, *_ = _phase_tracks(rng, noise=0.05)
    fit = fit_phase_circles(points, delta, ids, 3)
    for j in range(3):
        mine = ids == j
        expected = _model_cost(points[mine], delta[mine], fit.centres[j], fit.radii[j],
                               fit.phases[j])
        assert fit.costs[j] == pytest.approx(expected, rel=COST_REL_TOL)


def test_phase_circles_are_the_global_minimum_over_the_phase(rng):
    points, delta, ids, *_ = _phase_tracks(rng, noise=0.1)
    fit = fit_phase_circles(points, delta, ids, 3)
    grid = np.linspace(-np.pi, np.pi, 3601)
    for j in range(3):
        p, d = points[ids == j], delta[ids == j]
        costs = np.array([_best_cost_at_phase(p, d, b) for b in grid])
        assert fit.costs[j] <= costs.min() * (1 + COST_REL_TOL)
        # Polish the best grid phase: the closed form must equal the true minimum, not undercut it.
        k = int(np.argmin(costs))
        polished = minimize_scalar(lambda b, p=p, d=d: _best_cost_at_phase(p, d, b),
                                   bounds=(grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]),
                                   method="bounded", options={"xatol": 1e-12})
        assert fit.costs[j] == pytest.approx(polished.fun, rel=1e-7)


def test_constant_delta_track_gets_infinite_cost(rng):
    points, delta, ids, centres, radii, phases, lengths = _phase_tracks(rng)
    static = np.tile([[0.2, 0.1]], (8, 1))
    all_points = np.concatenate([points, static])
    all_delta = np.concatenate([delta, np.full(8, 0.7)])
    all_ids = np.concatenate([ids, np.full(8, 3)])
    fit = fit_phase_circles(all_points, all_delta, all_ids, 5)  # track 4 has no points at all
    assert fit.costs[3] == np.inf
    assert fit.radii[3] == 0.0
    np.testing.assert_allclose(fit.centres[3], [0.2, 0.1], atol=EXACT_TOL)
    assert fit.costs[4] == np.inf
    assert fit.counts[4] == 0
    # The other tracks are unaffected.
    np.testing.assert_allclose(fit.centres[:3], centres, atol=EXACT_TOL)
    np.testing.assert_allclose(fit.radii[:3], radii, atol=EXACT_TOL)


def test_candidate_score_is_scale_free_and_trims(rng):
    points, delta, ids, *_ = _phase_tracks(rng, noise=0.01)
    fit = fit_phase_circles(points, delta, ids, 3)
    scaled = fit_phase_circles(7.0 * points, delta, ids, 3)  # sigma's scale is arbitrary
    assert candidate_score(scaled) == pytest.approx(candidate_score(fit), rel=1e-9)
    relative = fit.costs / (fit.counts * fit.radii**2)
    # Wreck track 0: keeping ceil(0.6 * 3) = 2 tracks scores only tracks 1 and 2.
    wrecked = PhaseCircles(fit.centres, fit.radii, fit.phases, fit.costs * [1e6, 1.0, 1.0],
                           fit.counts)
    assert candidate_score(wrecked, keep_fraction=0.6) == pytest.approx(relative[1] + relative[2])
    assert candidate_score(wrecked, keep_fraction=1.0) > 1e3 * candidate_score(fit, 1.0)


def test_candidate_scores_match_one_candidate_at_a_time(rng):
    """The batched Eq. 18 scores against ``candidate_score`` per axis: noisy circles about one axis, a track
    that never turns (infinite cost), an id without points, the points shuffled, more candidates than a block."""
    point = np.array([0.15, -0.1, 1.5])
    axis = tilted_unit(rng, -point, np.deg2rad(50.0))
    points, deltas, ids = [], [], []
    for k in range(7):
        delta = np.linspace(0.0, rng.uniform(0.5, 1.5), 15 + k)
        ring = circle_points(point + rng.uniform(-0.25, 0.25) * axis, axis, rng.uniform(0.05, 0.15),
                             rng.uniform(0, 2 * np.pi) + delta)
        points.append(ring), deltas.append(delta), ids.append(np.full(delta.size, k))
    points.append(np.tile(point, (6, 1))), deltas.append(np.full(6, 0.3)), ids.append(np.full(6, 8))  # 7: none
    rays = homogeneous(project_normalized(np.concatenate(points)))
    rays[:, :2] += rng.normal(0.0, 1e-4, (len(rays), 2))
    order = rng.permutation(len(rays))
    rays, delta, track_ids = rays[order], np.concatenate(deltas)[order], np.concatenate(ids)[order]
    axes = np.vstack([axis, -axis, [unit(rng.normal(size=3)) for _ in range(300)]])
    batched = candidate_scores(rays, delta, track_ids, 9, axes)
    single = [candidate_score(fit_phase_circles(project_to_plane(rays, a), delta, track_ids, 9)) for a in axes]
    np.testing.assert_allclose(batched, single, rtol=1e-9)
    assert np.argmin(batched) == 0 and batched[0] < 1e-3 * np.median(batched)  # the scores tell axes apart


def test_plane_basis_is_right_handed(rng):
    for _ in range(10):
        a = unit(rng.normal(size=3))
        e1, e2 = plane_basis(a)
        np.testing.assert_allclose([e1 @ e1, e2 @ e2, e1 @ e2, e1 @ a, e2 @ a], [1, 1, 0, 0, 0],
                                   atol=1e-12)
        np.testing.assert_allclose(np.cross(e1, e2), a, atol=1e-12)


def _circle_scene(seed: int, flip: bool):
    """A 3-D circle facing the camera; ``axis`` is its normal, possibly pointing away."""
    rng = np.random.default_rng(seed)
    centre = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(1.3, 1.7)])
    axis = tilted_unit(rng, -centre, np.deg2rad(60.0)) * (-1.0 if flip else 1.0)
    radius = rng.uniform(0.1, 0.3)
    delta = np.linspace(0.0, 2.0, 30)
    points = circle_points(centre, axis, radius, rng.uniform(0, 2 * np.pi) + delta)
    return centre, axis, radius, delta, points


@pytest.mark.parametrize("flip", [False, True], ids=["axis-towards-camera", "axis-away"])
@pytest.mark.parametrize("seed", range(4))
def test_project_to_plane_maps_a_circle_to_a_circle(seed, flip):
    centre, axis, radius, delta, points = _circle_scene(seed, flip)
    rays = homogeneous(project_normalized(points))
    on_plane = project_to_plane(rays, axis)
    h = abs(axis @ centre)  # the circle's plane is axis . X = +-h: sigma is a copy scaled by 1/h
    d2 = np.linalg.norm(on_plane[:, None] - on_plane[None], axis=2)
    d3 = np.linalg.norm(points[:, None] - points[None], axis=2)
    np.testing.assert_allclose(d2, d3 / h, atol=EXACT_TOL)
    # The turn is counter-clockwise in (e1, e2), so the phase model fits it with +delta.
    fit = fit_phase_circles(on_plane, delta, np.zeros(delta.size, dtype=np.int64), 1)
    assert fit.radii[0] == pytest.approx(radius / h, rel=1e-9)
    assert fit.costs[0] < (EXACT_TOL * fit.radii[0]) ** 2
    reversed_fit = fit_phase_circles(on_plane, -delta, np.zeros(delta.size, dtype=np.int64), 1)
    assert reversed_fit.costs[0] > 1e-3 * delta.size * fit.radii[0] ** 2  # observed ~0.08


def test_centres_3d_inverts_project_to_plane(rng):
    axis = tilted_unit(rng, np.array([0.0, 0.0, -1.0]), 1.0)
    rays = homogeneous(rng.uniform(-0.5, 0.5, size=(20, 2)))
    back = centres_3d(project_to_plane(rays, axis), axis)
    np.testing.assert_allclose(back @ axis, 1.0, atol=1e-12)
    np.testing.assert_allclose(np.cross(back, rays), 0.0, atol=1e-12)


def _axis_scene(rng: np.random.Generator, n_inliers: int = 8, n_outliers: int = 2):
    """Circles about one camera-frame axis (and a few about a parallel, offset axis)."""
    point = np.array([0.15, -0.1, 1.5])  # on the axis, camera frame, m
    axis = tilted_unit(rng, -point, np.deg2rad(50.0))
    offset = 0.12 * perpendicular(axis)  # outliers turn about a parallel axis 12 cm away
    points, deltas, ids = [], [], []
    for k in range(n_inliers + n_outliers):
        along = rng.uniform(-0.25, 0.25)
        centre = point + along * axis + (offset if k >= n_inliers else 0.0)
        delta = np.linspace(0.0, 1.5, 20)
        ring = circle_points(centre, axis, rng.uniform(0.05, 0.15),
                             rng.uniform(0, 2 * np.pi) + delta)
        points.append(ring)
        deltas.append(delta)
        ids.append(np.full(delta.size, k))
    rays = homogeneous(project_normalized(np.concatenate(points)))
    fit = fit_phase_circles(project_to_plane(rays, axis), np.concatenate(deltas),
                            np.concatenate(ids), n_inliers + n_outliers)
    expected_inliers = np.arange(n_inliers + n_outliers) < n_inliers
    return point, axis, fit, expected_inliers


def _assert_rho_is_the_axis_plane(rho: np.ndarray, point: np.ndarray, axis: np.ndarray) -> None:
    assert np.linalg.norm(rho) == pytest.approx(1.0)
    assert abs(rho @ axis) < RHO_RAD
    assert abs(rho @ unit(point)) < RHO_RAD
    expected = np.cross(point, axis)
    assert min(angle_between(rho, expected), angle_between(rho, -expected)) < RHO_RAD


def test_reference_plane_contains_axis_and_camera_centre(rng):
    point, axis, fit, _ = _axis_scene(rng, n_outliers=0)
    rho, inliers = fit_reference_plane(fit.centres, axis, np.ones(len(fit.radii)),
                                       np.random.default_rng(0))
    assert np.all(inliers)
    _assert_rho_is_the_axis_plane(rho, point, axis)


def test_reference_plane_ransac_rejects_outlier_centres(rng):
    point, axis, fit, expected_inliers = _axis_scene(rng, n_outliers=2)
    rho, inliers = fit_reference_plane(fit.centres, axis, np.ones(len(fit.radii)),
                                       np.random.default_rng(0))
    np.testing.assert_array_equal(inliers, expected_inliers)
    _assert_rho_is_the_axis_plane(rho, point, axis)


def test_reference_plane_without_ransac_would_be_wrong(rng):
    # Guards the test above: the outliers really pull a plain fit off the axis plane.
    point, axis, fit, _ = _axis_scene(rng, n_outliers=2)
    rho, _ = fit_reference_plane(fit.centres, axis, np.ones(len(fit.radii)),
                                 np.random.default_rng(0), inlier_angle=10.0)
    assert abs(rho @ unit(point)) > 1e3 * RHO_RAD
