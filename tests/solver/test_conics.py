"""Tests of solver/conics.py: ellipse fits of projected 3-D circles."""

from __future__ import annotations

import numpy as np
import pytest

from solver.conics import (
    MIN_POINTS_PER_TRAJECTORY,
    ConicFit,
    conic_matrix,
    ellipse_reason,
    fit_conics_independent,
    fit_conics_shared,
    fit_ellipse_direct,
)
from solver.errors import DegenerateTrajectoryError, InvalidInputError
from tests.solver.scene import (
    FX,
    circle_points,
    homogeneous,
    project_normalized,
    random_unit,
    tilted_unit,
    unit,
)

#: Noise-free points lie exactly on the fitted conic: |x^T Q x| / (|Q|_F |x|^2) is float64
#: rounding amplified by the conditioning of the 6x6 fit (observed ~1e-15); scaling the points
#: by 1 + 1e-6 (1e-3 px) already gives ~5e-8.
ALGEBRAIC_TOL = 1e-9

#: Coaxial circles at 20 m under the shared-orientation model: it is exact only in the weak-
#: perspective limit, and the perspective misfit (~(extent / depth)^2) is ~2.5e-3 px here.
SHARED_WEAK_PERSPECTIVE_PX = 1e-2

#: Largest tilt of a test circle's normal from the line of sight: flatter views are "nearly a line".
MAX_TILT = np.deg2rad(60.0)

FIT_FUNCTIONS = [
    pytest.param(fit_ellipse_direct, id="direct"),
    pytest.param(lambda uv: fit_conics_shared([uv])[0], id="shared"),
    pytest.param(lambda uv: fit_conics_independent([uv])[0], id="independent"),
]


def _relative_algebraic_residual(Q: np.ndarray, uv: np.ndarray) -> np.ndarray:
    x = homogeneous(uv)
    return np.abs(np.einsum("pi,ij,pj->p", x, Q, x)) / (np.linalg.norm(Q) * np.sum(x * x, axis=1))


def _geometric_residual_px(Q: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """First-order distance of points from the conic, in pixels (Sampson distance)."""
    x = homogeneous(uv)
    value = np.einsum("pi,ij,pj->p", x, Q, x)
    gradient = 2.0 * (x @ Q)[:, :2]
    return FX * np.abs(value) / np.linalg.norm(gradient, axis=1)


def _random_circle(rng: np.random.Generator):
    centre = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(1.3, 1.7)])
    normal = tilted_unit(rng, -centre, MAX_TILT)
    radius = rng.uniform(0.1, 0.3)
    return centre, normal, radius


def _arc(rng: np.random.Generator, n_points: int = 30, span: float = 2.0):
    """A projected partial arc and the projection of its whole circle (held out of the fit)."""
    centre, normal, radius = _random_circle(rng)
    start = rng.uniform(0, 2 * np.pi)
    arc = circle_points(centre, normal, radius, start + np.linspace(0.0, span, n_points))
    whole = circle_points(centre, normal, radius, np.linspace(0.0, 2 * np.pi, 90, endpoint=False))
    return project_normalized(arc), project_normalized(whole)


@pytest.mark.parametrize("fit", FIT_FUNCTIONS)
@pytest.mark.parametrize("seed", range(6))
def test_fit_recovers_projected_circle(fit, seed):
    uv, whole = _arc(np.random.default_rng(seed))
    result = fit(uv)
    assert result.ok, result.reason
    assert result.reason == ""
    Q = result.matrix
    assert np.linalg.norm(Q) == pytest.approx(1.0)
    assert Q[0, 0] + Q[1, 1] > 0
    np.testing.assert_allclose(Q, Q.T, atol=0)
    assert np.max(_relative_algebraic_residual(Q, uv)) < ALGEBRAIC_TOL
    # Five points fix a conic, so the rest of the circle, never seen by the fit, lies on it too.
    assert np.max(_relative_algebraic_residual(Q, whole)) < ALGEBRAIC_TOL


def test_direct_fit_is_invariant_to_point_order(rng):
    uv, _ = _arc(rng)
    Q1 = fit_ellipse_direct(uv).matrix
    Q2 = fit_ellipse_direct(uv[rng.permutation(uv.shape[0])]).matrix
    np.testing.assert_allclose(Q1, Q2, atol=1e-10)


def _ellipse_with_axes(a: float, b: float) -> np.ndarray:
    return conic_matrix(np.array([1 / a**2, 0.0, 1 / b**2, 0.0, 0.0, -1.0]))


@pytest.mark.parametrize(
    ("Q", "match"),
    [
        pytest.param(np.diag([1.0, -0.5, -0.01]), "hyperbola or parabola", id="hyperbola"),
        pytest.param(np.diag([1.0, 0.0, -0.01]), "hyperbola or parabola", id="line-pair"),
        pytest.param(conic_matrix(np.array([1.0, 0.0, 0.0, 0.0, -1.0, 0.0])),
                     "hyperbola or parabola", id="parabola"),
        pytest.param(_ellipse_with_axes(0.2, 0.01), "nearly a line", id="flat-ellipse"),
        pytest.param(np.diag([1.0, 1.0, 1.0]), "imaginary", id="imaginary"),
        pytest.param(np.full((3, 3), np.nan), "degenerate", id="nan"),
        pytest.param(np.zeros((3, 3)), "degenerate", id="zero"),
    ],
)
def test_ellipse_reason_rejects(Q, match):
    assert match in ellipse_reason(Q)


@pytest.mark.parametrize("ratio", [1.0, 0.5, 0.15])
def test_ellipse_reason_accepts_real_ellipses(ratio):
    Q = _ellipse_with_axes(0.2, 0.2 * ratio)
    assert ellipse_reason(Q) == ""
    assert ellipse_reason(-Q) == ""  # the overall sign of a conic is arbitrary


def test_ellipse_reason_threshold_is_axis_ratio_about_one_tenth():
    assert ellipse_reason(_ellipse_with_axes(1.0, 0.11)) == ""
    assert "nearly a line" in ellipse_reason(_ellipse_with_axes(1.0, 0.09))


def _edge_on_circle(rng: np.random.Generator) -> np.ndarray:
    """A circle whose plane contains the camera centre: its image is a straight segment."""
    centre = np.array([0.1, -0.05, 1.5])
    normal = unit(np.cross(centre, random_unit(rng)))
    return project_normalized(circle_points(centre, normal, 0.2, np.linspace(0.0, 2.0, 30)))


COLLINEAR_CASES = [
    pytest.param(lambda rng: _edge_on_circle(rng), id="edge-on-circle"),
    pytest.param(lambda rng: np.column_stack([0.1 + np.linspace(0, 0.3, 20),
                                              -0.05 + 0.5 * np.linspace(0, 0.3, 20)]),
                 id="slanted-line"),
    pytest.param(lambda rng: np.column_stack([np.linspace(-0.2, 0.2, 20), np.zeros(20)]),
                 id="axis-line"),
]


@pytest.mark.parametrize("fit", FIT_FUNCTIONS)
@pytest.mark.parametrize("make", COLLINEAR_CASES)
def test_collinear_points_are_rejected(fit, make, rng):
    uv = make(rng)
    result = fit(uv)
    assert not result.ok
    assert result.matrix is None
    assert result.reason != ""


@pytest.mark.parametrize("fit", [p for p in FIT_FUNCTIONS if p.id != "shared"])
def test_too_few_points(fit, rng):  # the shared fit's case: test_shared_fit_reports_short_...
    uv, _ = _arc(rng, n_points=MIN_POINTS_PER_TRAJECTORY - 1)
    result = fit(uv)
    assert not result.ok
    assert result.reason == f"only {MIN_POINTS_PER_TRAJECTORY - 1} points (need " \
                            f"{MIN_POINTS_PER_TRAJECTORY})"


def test_minimum_number_of_points_is_enough(rng):
    uv, whole = _arc(rng, n_points=MIN_POINTS_PER_TRAJECTORY)
    result = fit_ellipse_direct(uv)
    assert result.ok, result.reason
    assert np.max(_relative_algebraic_residual(result.matrix, whole)) < ALGEBRAIC_TOL


def test_static_trajectory_is_rejected():
    result = fit_ellipse_direct(np.tile([[0.1, 0.2]], (10, 1)))
    assert not result.ok
    assert result.reason == "trajectory does not move"


def _coaxial_circles(depth: float, n_circles: int = 4):
    """Circles about one axis, ~``depth`` m away; returns the fitted arcs and the whole circles."""
    axis = unit(np.array([0.3, 0.35, -1.0]))
    point = np.array([0.015 * depth, -0.01 * depth, depth])
    arcs, wholes = [], []
    for k in range(n_circles):
        centre = point + (0.2 * k - 0.3) * axis
        radius = 0.1 + 0.05 * k
        arcs.append(project_normalized(
            circle_points(centre, axis, radius, k + np.linspace(0.0, 2.5, 25))))
        wholes.append(project_normalized(
            circle_points(centre, axis, radius, np.linspace(0.0, 2 * np.pi, 90, endpoint=False))))
    return arcs, wholes


def _shared_fit_misfit_px(depth: float) -> float:
    arcs, wholes = _coaxial_circles(depth)
    fits = fit_conics_shared(arcs)
    assert all(f.ok for f in fits), [f.reason for f in fits]
    return max(float(np.max(_geometric_residual_px(f.matrix, w))) for f, w in zip(fits, wholes,
                                                                                strict=True))


def test_independent_fits_together_equal_fits_one_by_one(rng):
    """fit_conics_independent fits a stack at once: the same verdicts, reasons and matrices as each trajectory fitted
    alone, on a batch mixing noisy arcs, an exact arc, short and static ones, lines and an edge-on circle."""
    batch = [_arc(rng)[0] + rng.normal(0.0, 2e-4, (1, 2)) for _ in range(6)]
    batch += [_arc(rng, n_points=MIN_POINTS_PER_TRAJECTORY - 1)[0], np.tile([[0.1, 0.2]], (10, 1))]
    batch += [make.values[0](rng) for make in COLLINEAR_CASES] + [_arc(rng, n_points=40)[0]]
    order = rng.permutation(len(batch))
    batch = [batch[k] for k in order]
    together = fit_conics_independent(batch)
    assert len(together) == len(batch)
    for uv, fit in zip(batch, together, strict=True):
        alone = fit_ellipse_direct(uv)
        assert (fit.ok, fit.reason) == (alone.ok, alone.reason)
        if alone.ok:
            np.testing.assert_allclose(fit.matrix, alone.matrix, atol=1e-9)
    assert sum(fit.ok for fit in together) >= 7  # the arcs fit; the rest give their reasons


def test_shared_fit_of_coaxial_circles_far_away():
    assert _shared_fit_misfit_px(20.0) < SHARED_WEAK_PERSPECTIVE_PX


def test_shared_fit_approaches_exact_as_perspective_weakens():
    near, far = _shared_fit_misfit_px(5.0), _shared_fit_misfit_px(50.0)
    assert near > SHARED_WEAK_PERSPECTIVE_PX  # the shared model is not exact up close ...
    assert far < near / 25  # ... and its misfit falls at least as (depth ratio)^2 / 4


def test_independent_fit_of_coaxial_circles_is_exact_at_any_depth():
    arcs, wholes = _coaxial_circles(5.0)
    for fit, whole in zip(fit_conics_independent(arcs), wholes, strict=True):
        assert fit.ok, fit.reason
        assert np.max(_relative_algebraic_residual(fit.matrix, whole)) < ALGEBRAIC_TOL


def test_shared_fit_reports_short_trajectories_and_fits_the_rest(rng):
    arcs, wholes = _coaxial_circles(20.0, n_circles=3)
    fits = fit_conics_shared([arcs[0], arcs[1][:3], arcs[2]])
    assert [f.ok for f in fits] == [True, False, True]
    assert fits[1].reason == f"only 3 points (need {MIN_POINTS_PER_TRAJECTORY})"
    for k in (0, 2):
        assert np.max(_geometric_residual_px(fits[k].matrix, wholes[k])) < \
            SHARED_WEAK_PERSPECTIVE_PX


def test_shared_fit_without_usable_trajectories_raises(rng):
    uv, _ = _arc(rng)
    with pytest.raises(DegenerateTrajectoryError, match="no trajectory has enough moving points"):
        fit_conics_shared([uv[:4], np.tile(uv[:1], (10, 1))])


@pytest.mark.parametrize(
    "fit",
    [
        pytest.param(fit_ellipse_direct, id="direct"),
        pytest.param(lambda uv: fit_conics_shared([uv]), id="shared"),
        pytest.param(lambda uv: fit_conics_independent([uv]), id="independent"),
    ],
)
def test_nan_input_raises(fit, rng):
    uv, _ = _arc(rng)
    uv[3, 1] = np.nan
    with pytest.raises(InvalidInputError, match="trajectory 0 contains NaN"):
        fit(uv)


def test_nan_in_second_trajectory_is_named(rng):
    uv, _ = _arc(rng)
    bad = uv.copy()
    bad[0, 0] = np.inf
    with pytest.raises(InvalidInputError, match="trajectory 1 contains NaN or infinite"):
        fit_conics_shared([uv, bad])


@pytest.mark.parametrize(
    ("trajectories", "match"),
    [
        pytest.param([np.zeros((10, 3))], r"trajectory 0 must be \(M, 2\), got shape \(10, 3\)",
                     id="three-columns"),
        pytest.param([np.zeros(10)], r"trajectory 0 must be \(M, 2\)", id="flat"),
        pytest.param([], "no trajectories given", id="empty"),
    ],
)
def test_bad_shapes_raise(trajectories, match):
    with pytest.raises(InvalidInputError, match=match):
        fit_conics_shared(trajectories)
    with pytest.raises(InvalidInputError, match=match):
        fit_conics_independent(trajectories)


def test_conic_fit_ok_property():
    assert ConicFit(np.eye(3)).ok
    assert not ConicFit(None, "why").ok


def test_conic_matrix_layout():
    Q = conic_matrix(np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]))
    u, v = 0.3, -0.7
    x = np.array([u, v, 1.0])
    assert x @ Q @ x == pytest.approx(u * u + 2 * u * v + 3 * v * v + 4 * u + 5 * v + 6)
