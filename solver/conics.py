"""Conic fits of keypoint trajectories in normalized image coordinates (paper §IV-B, Eq. 5-11).

A conic A u^2 + B uv + C v^2 + D u + E v + F = 0 is held as its symmetric 3x3 matrix
``[[A, B/2, D/2], [B/2, C, E/2], [D/2, E/2, F]]`` acting on (u, v, 1); the same matrix is the
cone of rays through the camera centre (Eq. 12), so no conversion is needed downstream.

Two fits are offered:

* ``fit_conics_shared`` (the paper's Eq. 9-11): all trajectories of one motion are fitted together
  with a shared B and G = C - A (one design matrix, 4L + 2 unknowns). The shared orientation holds
  exactly only under weak perspective.
* ``fit_conics_independent``: each trajectory gets its own ellipse-specific direct fit
  (Halir & Flusser 1998), exact under full perspective.

``scripts/bench_conics.py`` measures both against the true circle normals: noise-free the shared model
is biased (4e-3 rad median on the synthetic Panda) and the independent one exact, and with 0.5 px noise
far fewer shared fits are valid ellipses, so ``MotionConfig.conic_fit`` defaults to "independent".
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from solver.arrays import FloatArray
from solver.errors import DegenerateTrajectoryError, InvalidInputError

#: Smallest ellipticity 4AC - B^2, relative to (A + C)^2, accepted as an ellipse. An ellipse with
#: axis ratio b/a has 4AC - B^2 = 4 (b/a)^2 / (1 + (b/a)^2)^2 (A + C)^2 = 0.04 at b/a ~ 0.1: flatter
#: conics are lines in practice (the camera nearly in the circle's plane) and their normals are noise.
MIN_RELATIVE_ELLIPTICITY = 0.04

#: Fewest points on one trajectory for a conic (five determine one; more are needed against noise).
MIN_POINTS_PER_TRAJECTORY = 6


@dataclass(frozen=True)
class ConicFit:
    """Result of fitting one trajectory.

    Attributes:
        matrix: (3, 3) float64: the conic/cone matrix in normalized coordinates, scaled to unit
            Frobenius norm and signed so that A + C > 0; None when the fit is not an ellipse.
        reason: why the trajectory was rejected, or "" when it is a valid ellipse.
    """

    matrix: FloatArray | None
    reason: str = ""

    @property
    def ok(self) -> bool:
        """True for a valid ellipse."""
        return self.matrix is not None


def conic_matrix(coeffs: FloatArray) -> FloatArray:
    """Symmetric 3x3 matrix of conic coefficients (A, B, C, D, E, F): (6,) -> (3, 3)."""
    A, B, C, D, E, F = coeffs
    return np.array([[A, B / 2, D / 2], [B / 2, C, E / 2], [D / 2, E / 2, F]])


def ellipse_reason(Q: FloatArray) -> str:
    """Why a conic matrix Q (3, 3) is not a real, non-degenerate ellipse; "" if it is one."""
    A, B, C = Q[0, 0], 2 * Q[0, 1], Q[1, 1]
    trace = A + C
    if not np.all(np.isfinite(Q)) or not np.any(Q):
        return "conic fit is degenerate"
    if 4 * A * C - B * B <= 0:
        return "trajectory is a hyperbola or parabola, not an ellipse (4AC - B^2 <= 0)"
    ellipticity = (4 * A * C - B * B) / trace**2
    if ellipticity < MIN_RELATIVE_ELLIPTICITY:
        return f"trajectory is nearly a line (relative 4AC - B^2 = {ellipticity:.3g})"
    if np.linalg.det(Q) * np.sign(trace) >= 0:
        return "conic is imaginary (no real points)"
    return ""


def _normalized(Q: FloatArray) -> FloatArray:
    Q = Q / np.linalg.norm(Q)
    return Q if Q[0, 0] + Q[1, 1] > 0 else -Q


def _similarity(scale: float, centre: FloatArray) -> FloatArray:
    """3x3 homogeneous map x' = scale * (x - centre)."""
    return np.array([[scale, 0, -scale * centre[0]], [0, scale, -scale * centre[1]], [0, 0, 1.0]])


def _check_trajectories(trajectories: Sequence[FloatArray]) -> list[FloatArray]:
    out = []
    for j, uv in enumerate(trajectories):
        uv = np.asarray(uv, dtype=np.float64)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InvalidInputError(f"trajectory {j} must be (M, 2), got shape {uv.shape}")
        if not np.all(np.isfinite(uv)):
            raise InvalidInputError(f"trajectory {j} contains NaN or infinite values")
        out.append(uv)
    if not out:
        raise InvalidInputError("no trajectories given")
    return out


def _too_short(uv: FloatArray) -> str:
    if uv.shape[0] < MIN_POINTS_PER_TRAJECTORY:
        return f"only {uv.shape[0]} points (need {MIN_POINTS_PER_TRAJECTORY})"
    if np.max(np.ptp(uv, axis=0)) < 1e-9:
        return "trajectory does not move"
    return ""


def fit_ellipse_direct(uv: FloatArray) -> ConicFit:
    """Ellipse-specific direct least-squares fit of one trajectory (Halir & Flusser 1998).

    Args:
        uv: (M, 2) float64: normalized image coordinates of one trajectory.

    Returns:
        The fit; ``reason`` says why it is not an ellipse when it is not one.
    """
    return fit_conics_independent([uv])[0]


def fit_conics_independent(trajectories: Sequence[FloatArray]) -> list[ConicFit]:
    """Fit each trajectory on its own (``fit_ellipse_direct``): L arrays (M_j, 2) -> L fits.

    Halir & Flusser's fit of every trajectory, computed together: the scatter matrices, the eliminations and
    the 3x3 eigenproblems as stacks (one call per step instead of a dozen small numpy calls per trajectory:
    5x faster on a 1080p motion's ~190 trajectories). Each fit depends on its own trajectory only.
    """
    trajectories = _check_trajectories(trajectories)
    fits: list[ConicFit | None] = [ConicFit(None, r) if (r := _too_short(uv)) else None for uv in trajectories]
    used = [j for j, fit in enumerate(fits) if fit is None]
    if used:
        for j, fit in zip(used, _direct_fits([trajectories[j] for j in used]), strict=True):
            fits[j] = fit
    return [fit for fit in fits if fit is not None]


def _direct_fits(trajectories: list[FloatArray]) -> list[ConicFit]:
    """``fit_conics_independent`` of trajectories long enough to fit: n arrays (M_j >= 6, 2) -> n fits."""
    counts = np.array([uv.shape[0] for uv in trajectories])
    first = np.concatenate([[0], np.cumsum(counts[:-1])])
    uv = np.concatenate(trajectories)
    centres = np.add.reduceat(uv, first, axis=0) / counts[:, None]  # (n, 2)
    centred = uv - np.repeat(centres, counts, axis=0)
    spread = np.add.reduceat(np.sum(centred**2, axis=1), first) / counts
    scales = np.sqrt(2) / np.maximum(np.sqrt(spread), 1e-300)  # (n,)
    x, y = (centred * np.repeat(scales, counts)[:, None]).T
    design = np.column_stack([x * x, x * y, y * y, x, y, np.ones_like(x)])  # (P, 6): D1 | D2
    scatter = np.add.reduceat(design[:, :, None] * design[:, None, :], first, axis=0)  # (n, 6, 6)
    S1, S2, S3 = scatter[:, :3, :3], scatter[:, :3, 3:], scatter[:, 3:, 3:]
    S2t = np.transpose(S2, (0, 2, 1))
    # T = -S3^-1 S2^T. S3 is the scatter of (x, y, 1): singular to working precision when the points are collinear
    # (where LAPACK's own verdict on an exactly singular matrix would hang on rounding).
    collinear = np.linalg.cond(S3) > 1.0 / np.finfo(float).eps
    T = np.zeros_like(S3)
    T[~collinear] = -np.linalg.solve(S3[~collinear], S2t[~collinear])
    M = S1 + S2 @ T
    M = np.stack([M[:, 2] / 2, -M[:, 1], M[:, 0] / 2], axis=1)  # C1^-1 @ M for the constraint 4AC - B^2 = 1
    finite = np.all(np.isfinite(M), axis=(1, 2))
    eigval, eigvec = np.linalg.eig(np.where(finite[:, None, None], M, np.eye(3)))
    eigval, eigvec = np.real(eigval), np.real(eigvec)
    positive = 4 * eigvec[:, 0] * eigvec[:, 2] - eigvec[:, 1] ** 2 > 0  # (n, 3): 4AC - B^2 of each eigenvector
    # per trajectory, the eigenvector with 4AC - B^2 > 0 of the smallest |eigenvalue|
    pick = np.argmin(np.where(positive, np.abs(eigval), np.inf), axis=1)
    a1 = np.take_along_axis(eigvec, pick[:, None, None], axis=2)[:, :, 0]  # (n, 3)
    A, B, C, D, E, F = np.concatenate([a1, np.einsum("nij,nj->ni", T, a1)], axis=1).T
    local = np.stack([np.stack([A, B / 2, D / 2], 1), np.stack([B / 2, C, E / 2], 1),
                      np.stack([D / 2, E / 2, F], 1)], 1)  # conic_matrix, (n, 3, 3)
    similarity = np.zeros((len(trajectories), 3, 3))  # _similarity, (n, 3, 3)
    similarity[:, 0, 0] = similarity[:, 1, 1] = scales
    similarity[:, :2, 2] = -scales[:, None] * centres
    similarity[:, 2, 2] = 1.0
    Q = np.transpose(similarity, (0, 2, 1)) @ local @ similarity
    Q /= np.linalg.norm(Q, axis=(1, 2), keepdims=True)
    Q *= np.where(Q[:, 0, 0] + Q[:, 1, 1] > 0, 1.0, -1.0)[:, None, None]  # _normalized
    fits = []
    for k in range(len(trajectories)):
        if collinear[k]:
            fits.append(ConicFit(None, "trajectory points are collinear"))
        elif not finite[k]:
            fits.append(ConicFit(None, "conic fit is degenerate"))
        elif not np.any(positive[k]):
            fits.append(ConicFit(None, "no ellipse fits the trajectory (4AC - B^2 <= 0 for every solution)"))
        else:
            fits.append(ConicFit(None, reason) if (reason := ellipse_reason(Q[k])) else ConicFit(Q[k]))
    return fits


def fit_conics_shared(trajectories: Sequence[FloatArray]) -> list[ConicFit]:
    """Joint fit with a shared orientation (paper Eq. 9-11): L arrays (M_j, 2) -> L fits.

    The model of trajectory j is A_j (u^2 + v^2) + B uv + G v^2 + D_j u + E_j v + F_j = 0 with B and
    G = C_j - A_j shared. Each trajectory is centred on its own centroid (a translation leaves the
    quadratic part, and so the shared B and G, unchanged) and all are scaled by one common factor
    (which scales every quadratic part alike). The per-trajectory linear parts (D_j, E_j, F_j) are
    eliminated in closed form and the quadratic parts (B, G, A_1..A_L) are the least singular vector
    of the reduced system, under ||(B, G, A_1..A_L)|| = 1. Trajectories that are too short are
    reported and left out of the joint fit.

    Raises:
        DegenerateTrajectoryError: when no trajectory is long enough to take part.
    """
    trajectories = _check_trajectories(trajectories)
    reasons = [_too_short(uv) for uv in trajectories]
    used = [j for j, r in enumerate(reasons) if not r]
    if not used:
        raise DegenerateTrajectoryError("no trajectory has enough moving points for a conic fit")
    centres = [trajectories[j].mean(axis=0) for j in used]
    spread = np.concatenate([trajectories[j] - c for j, c in zip(used, centres, strict=True)])
    scale = np.sqrt(2) / max(np.sqrt(np.mean(np.sum(spread**2, axis=1))), 1e-300)
    n_used = len(used)
    # Reduced normal matrix over q = (B, G, A_1..A_L) after eliminating each (D_j, E_j, F_j).
    reduced = np.zeros((n_used + 2, n_used + 2))
    eliminations = []
    for slot, (j, centre) in enumerate(zip(used, centres, strict=True)):
        x, y = ((trajectories[j] - centre) * scale).T
        quad = np.column_stack([x * y, y * y, x * x + y * y])  # columns for B, G, A_j
        lin = np.column_stack([x, y, np.ones_like(x)])
        gram = lin.T @ lin
        elim = -np.linalg.lstsq(gram, lin.T @ quad, rcond=None)[0]  # (3, 3): lin = elim @ quad
        residual_op = quad + lin @ elim
        idx = [0, 1, slot + 2]
        reduced[np.ix_(idx, idx)] += residual_op.T @ residual_op
        eliminations.append(elim)
    _, eigvec = np.linalg.eigh(reduced)
    q = eigvec[:, 0]
    fits: list[ConicFit] = [ConicFit(None, r) for r in reasons]
    for slot, (j, centre) in enumerate(zip(used, centres, strict=True)):
        B, G, A = q[0], q[1], q[slot + 2]
        D, E, F = eliminations[slot] @ np.array([B, G, A])
        local = conic_matrix(np.array([A, B, A + G, D, E, F]))
        S = _similarity(scale, centre)
        Q = _normalized(S.T @ local @ S)
        reason = ellipse_reason(Q)
        fits[j] = ConicFit(None if reason else Q, reason)
    return fits
