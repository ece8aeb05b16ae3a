"""Reference positions of a motion's rotation axis (paper §IV-D, Eq. 15-18).

For a candidate axis a (unit, camera frame) the trajectories are centrally projected onto the plane
sigma: a . X = 1. Circles in planes normal to a map to circles on sigma by a similarity, so each
trajectory becomes a circle traversed at the known joint angles delta. The axis itself projects
onto sigma as a line through the circle centres and through a's own vanishing point (the foot of
the perpendicular from the camera centre), so the plane through the camera centre that contains
the axis has a normal rho perpendicular to a and to every centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_array

from solver.arrays import FloatArray

IntArray = NDArray[np.int64]


def plane_basis(axis: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Orthonormal e1, e2 (each (3,)) spanning the plane normal to ``axis``, with e1 x e2 = axis."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = _cross(helper, axis)
    e1 /= np.linalg.norm(e1)
    return e1, _cross(axis, e1)


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """The cross product of two (3,) vectors: np.cross's arithmetic (the same bits) without its overhead."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def project_to_plane(rays: FloatArray, axis: FloatArray) -> FloatArray:
    """Central projection of rays onto sigma: a . X = 1, in sigma's (e1, e2) coordinates.

    Args:
        rays: (M, 3) float64: rays (u, v, 1) in the camera frame.
        axis: (3,) float64: unit normal a of sigma.

    Returns:
        (M, 2) float64: coordinates on sigma (unitless: metres per metre of plane distance).
    """
    e1, e2 = plane_basis(axis)
    X = rays / (rays @ axis)[:, None]
    return np.column_stack([X @ e1, X @ e2])


@dataclass(frozen=True)
class PhaseCircles:
    """Circles z = c + alpha exp(i (delta + beta)) fitted to L trajectories on one plane.

    Attributes:
        centres: (L, 2) float64: circle centres on the plane.
        radii: (L,) float64: alpha >= 0.
        phases: (L,) float64, radians: beta.
        costs: (L,) float64: the paper's J, sum of squared distances to the model points.
        counts: (L,) int: points per trajectory.
    """

    centres: FloatArray
    radii: FloatArray
    phases: FloatArray
    costs: FloatArray
    counts: IntArray


def phase_circle_solution(n: FloatArray, S: NDArray[np.complex128], Z1: NDArray[np.complex128],
                          Z2: NDArray[np.complex128]
                          ) -> tuple[NDArray[np.complex128], NDArray[np.complex128], NDArray[np.bool_]]:
    """The phase model's closed-form (c, gamma) per trajectory (``fit_phase_circles``) from its sums.

    Args:
        n: (L,) points per trajectory.
        S: (L,) each trajectory's sum of exp(i delta).
        Z1: (..., L) each trajectory's sum of z (any leading axes: several z at once).
        Z2: (..., L) each trajectory's sum of exp(-i delta) z, likewise.

    Returns:
        c, gamma (..., L) and good (L,): the fit is well posed (delta changes); where not, c is the mean of z
        and gamma 0.
    """
    det = n * n - np.abs(S) ** 2
    good = det > 1e-12 * np.maximum(n * n, 1.0)
    safe = np.where(good, det, 1.0)
    c = np.where(good, (n * Z1 - S * Z2) / safe, Z1 / np.maximum(n, 1))
    gamma = np.where(good, (n * Z2 - np.conj(S) * Z1) / safe, 0)
    return c, gamma, good


def fit_phase_circles(points: FloatArray, delta: FloatArray, track_ids: IntArray,
                      n_tracks: int) -> PhaseCircles:
    """Globally optimal phase-model circle fit (Eq. 16-17) for many trajectories at once.

    With z = u' + i v' and gamma = alpha exp(i beta), the model z_k = c + gamma exp(i delta_k) is
    linear in the complex unknowns (c, gamma), so the least-squares problem has one closed-form
    minimizer. It is the paper's global minimum: the first-order conditions (Eq. 17) have exactly
    two critical points in beta in [0, 2 pi), (alpha, beta) and (-alpha, beta + pi), which describe
    the same curve; the one with alpha >= 0 is |gamma|, arg(gamma). No iterative solver is involved.

    Args:
        points: (P, 2) float64: all trajectories' points on the plane.
        delta: (P,) float64, radians: joint turn at each point.
        track_ids: (P,) int: which trajectory (0..n_tracks-1) each point belongs to.
        n_tracks: L.

    Returns:
        The L circles; a trajectory whose delta never changes gets radius 0 and infinite cost.
    """
    z = points[:, 0] + 1j * points[:, 1]
    e = np.exp(1j * delta)

    def per_track(values: NDArray[np.complex128]) -> NDArray[np.complex128]:
        re = np.bincount(track_ids, weights=values.real, minlength=n_tracks)
        im = np.bincount(track_ids, weights=values.imag, minlength=n_tracks)
        return re + 1j * im

    n = np.bincount(track_ids, minlength=n_tracks).astype(np.float64)
    c, gamma, good = phase_circle_solution(n, per_track(e), per_track(z), per_track(np.conj(e) * z))
    residual = z - c[track_ids] - gamma[track_ids] * e
    costs = np.bincount(track_ids, weights=np.abs(residual) ** 2, minlength=n_tracks)
    costs = np.where(good, costs, np.inf)
    return PhaseCircles(
        centres=np.column_stack([c.real, c.imag]),
        radii=np.abs(gamma),
        phases=np.angle(gamma),
        costs=costs,
        counts=n.astype(np.int64),
    )


def candidate_score(circles: PhaseCircles, keep_fraction: float = 0.75) -> float:
    """Eq. 18's score J' of one candidate axis, scale-free and robust to bad trajectories.

    The paper sums J / alpha; J scales with the square of sigma's (arbitrary) scale and alpha with
    its first power, so we use J / (M alpha^2): each trajectory's mean squared misfit relative to its
    radius, comparable between candidates whose planes differ. Trajectories from tracker failures
    misfit every candidate alike and would drown the comparison, so the sum runs over the best
    ``keep_fraction`` of the trajectories (a trimmed sum).
    """
    rel = circles.costs / (np.maximum(circles.counts, 1) * np.maximum(circles.radii, 1e-300) ** 2)
    rel = np.sort(np.where(np.isfinite(rel), rel, 1e6))
    return float(np.sum(rel[: max(1, int(np.ceil(keep_fraction * rel.size)))]))


def candidate_scores(rays: FloatArray, delta: FloatArray, track_ids: IntArray, n_tracks: int, axes: FloatArray,
                     keep_fraction: float = 0.75) -> FloatArray:
    """Eq. 18's score of many candidate axes at once (C,): ``candidate_score`` of each one's phase circles.

    The same as ``candidate_score(fit_phase_circles(project_to_plane(rays, a), delta, track_ids, n_tracks))``
    for every row ``a`` of ``axes`` (to rounding), over blocks of candidates. Each trajectory's misfit comes
    from its moments, never from per-point residuals: with z = x + i y its plane coordinates, the
    least-squares circle's cost is sum |z|^2 - Re(c conj(Z1) + gamma conj(Z2)) (the residual is orthogonal
    to the model), and Z1, Z2, sum |z|^2 are sparse products of the (P, 2 C) coordinates with
    per-trajectory weights 1, cos delta and sin delta. The coordinates are taken from one point of each
    trajectory (a shift its circle absorbs), so the difference does not cancel |z|^2 ~ 1 against a misfit
    of ~1e-8 (relative error 4e-6 -> 4e-9 of the per-point residuals' scores on captured 1080p motions).
    So the per-point work is one projection, one shift and one square per candidate (0.59 s against 1.07 s
    for forming the residuals, on a captured 1080p episode's 25 motions).

    Args:
        rays: (P, 3) float64: rays (u, v, 1) of every trajectory's points, camera frame.
        delta: (P,) float64, radians: joint turn at each point.
        track_ids: (P,) int: which trajectory (0..n_tracks-1) each point belongs to.
        n_tracks: L.
        axes: (C, 3) float64: unit candidate axes.
        keep_fraction: see ``candidate_score``.
    """
    helpers = np.eye(3)[np.argmin(np.abs(axes), axis=1)]  # plane_basis, row by row
    e1 = np.cross(helpers, axes)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(axes, e1)
    L, P = n_tracks, track_ids.size
    cos, sin = np.cos(delta), np.sin(delta)
    points = np.arange(P)
    one_hot = csr_array((np.ones(P), (track_ids, points)), shape=(L, P))  # per-trajectory sums as products
    # rows (0..L), (L..2L), (2L..3L): per-trajectory sums weighted by 1, cos delta, sin delta
    weighted = csr_array((np.concatenate([np.ones(P), cos, sin]),
                          (np.concatenate([track_ids, track_ids + L, track_ids + 2 * L]), np.tile(points, 3))),
                         shape=(3 * L, P))
    n = np.bincount(track_ids, minlength=L).astype(np.float64)[:, None]  # (L, 1)
    first = np.zeros(L, dtype=np.int64)
    first[track_ids[::-1]] = points[::-1]  # a point of each trajectory (its first)
    anchor = first[track_ids]  # (P,)
    S = (one_hot @ (cos + 1j * sin))[:, None]
    det = n * n - np.abs(S) ** 2
    good = det > 1e-12 * np.maximum(n * n, 1.0)
    safe = np.where(good, det, 1.0)
    keep = max(1, int(np.ceil(keep_fraction * L)))
    scores = np.empty(axes.shape[0])
    for lo in range(0, axes.shape[0], _SCORE_CHUNK):
        block = slice(lo, lo + _SCORE_CHUNK)
        m = axes[block].shape[0]
        xy = rays @ np.concatenate([e1[block], e2[block]]).T  # (P, 2m): x then y; X = ray / depth lies on sigma
        xy /= np.tile(rays @ axes[block].T, 2)
        xy -= xy[anchor]  # each trajectory's coordinates from one of its points: a shift its circle absorbs
        sums = weighted @ xy  # (3L, 2m)
        squares = one_hot @ (xy * xy)  # (L, 2m)
        Z1 = sums[:L, :m] + 1j * sums[:L, m:]  # sum z
        Z2 = (sums[L:2 * L, :m] + sums[2 * L:, m:]) + 1j * (sums[L:2 * L, m:] - sums[2 * L:, :m])  # sum conj(e) z
        c = (n * Z1 - S * Z2) / safe
        gamma = (n * Z2 - np.conj(S) * Z1) / safe
        misfit = squares[:, :m] + squares[:, m:] - (c * np.conj(Z1) + gamma * np.conj(Z2)).real
        costs = np.where(good, np.maximum(misfit, 0.0), np.inf)
        rel = costs / (np.maximum(n, 1) * np.maximum(np.abs(gamma), 1e-300) ** 2)
        rel = np.sort(np.where(np.isfinite(rel), rel, 1e6), axis=0)
        scores[block] = np.sum(rel[:keep], axis=0)
    return scores


#: Candidates per block of ``candidate_scores`` (memory: about 60 * chunk * P bytes). On the 25 motions of a
#: captured 1080p episode (2 700-4 800 points, 648 candidates each), before the shift to a point of each
#: trajectory, 32 took 0.57 s, 64 0.63 s, 128 0.64 s.
_SCORE_CHUNK = 32


def centres_3d(centres: FloatArray, axis: FloatArray) -> FloatArray:
    """Points on sigma (a . X = 1) from their (e1, e2) coordinates: (L, 2) -> (L, 3)."""
    e1, e2 = plane_basis(axis)
    return axis[None, :] + centres[:, :1] * e1 + centres[:, 1:] * e2


def fit_reference_plane(centres: FloatArray, axis: FloatArray, weights: FloatArray,
                        rng: np.random.Generator, inlier_angle: float = 0.01,
                        iterations: int = 64) -> tuple[FloatArray, NDArray[np.bool_]]:
    """RANSAC line through the circle centres and the axis's vanishing point (Eq. 18's line).

    Each centre alone fixes a candidate line (it must also pass through the vanishing point a), so
    one centre is a minimal sample. Inliers lie within ``inlier_angle`` of the line as seen from the
    camera; the final line is the weighted least-squares fit over the inliers.

    Args:
        centres: (L, 2) float64: circle centres on sigma in (e1, e2) coordinates.
        axis: (3,) float64: unit axis a (sigma's normal).
        weights: (L,) float64: confidence of each centre (>= 0).
        rng: random generator for the RANSAC samples.
        inlier_angle: radians; distance from the line divided by the distance from a's foot. The
            final inliers lie within the larger of this and 3 robust sigma of the scatter.
        iterations: RANSAC samples at most.

    Returns:
        rho: (3,) float64, the unit normal of the plane through the camera centre that contains the
        axis (its sign is arbitrary: the constraint rho . p = 0 does not depend on it), and
        inliers: (L,) bool, the centres that support the line.
    """
    L = centres.shape[0]
    dist = np.linalg.norm(centres, axis=1)
    directions = centres / np.maximum(dist, 1e-300)[:, None]
    order = rng.permutation(L)[:iterations]
    best_inliers = np.zeros(L, dtype=bool)
    best_support = -1.0
    for j in order:
        normal2d = np.array([-directions[j, 1], directions[j, 0]])
        off = np.abs(centres @ normal2d) / np.maximum(dist, 1e-300)
        inliers = off < inlier_angle
        support = float(np.sum(weights[inliers]))
        if support > best_support:
            best_support, best_inliers = support, inliers
    # Adapt the threshold to the centres' own scatter about the consensus line (3 robust sigma).
    normal2d = _line_normal(centres[best_inliers], weights[best_inliers])
    off = np.abs(centres @ normal2d) / np.maximum(dist, 1e-300)
    scale = 1.4826 * float(np.median(off))
    best_inliers = off < max(inlier_angle, 3.0 * scale)
    normal2d = _line_normal(centres[best_inliers], weights[best_inliers])
    e1, e2 = plane_basis(axis)
    direction3d = -normal2d[1] * e1 + normal2d[0] * e2
    rho = np.cross(axis, direction3d)
    return rho / np.linalg.norm(rho), best_inliers


def _line_normal(centres: FloatArray, weights: FloatArray) -> FloatArray:
    """Unit normal (2,) of the weighted least-squares line through the origin and the centres."""
    pts = centres * np.sqrt(weights)[:, None]
    _, _, Vt = np.linalg.svd(pts, full_matrices=False)
    return np.array([-Vt[0, 1], Vt[0, 0]])
