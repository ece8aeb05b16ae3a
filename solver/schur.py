"""Levenberg-Marquardt on the bundle adjustment's normal equations with the points eliminated (ours).

Each observation touches the pose block (omega, tau[, s]) and its own track's point only, so the
normal equations J^T W J have a block-arrow shape: U (n, n) for the pose, one (3, 3) block V_t per
track and the couplings W_t (n, 3). Each iteration eliminates the points (Schur complement
S = U - sum_t W_t V_t^-1 W_t^T, n x n), solves for the pose step and back-substitutes every point's
step, all as vectorized numpy over the observations: what Ceres's DENSE_SCHUR does, with no
sparse matrix and no iterative linear solver. A robust loss enters as iteratively reweighted least
squares (Cauchy: w = 1 / (1 + r^2 / c^2) per observation, on its squared pixel error), and a
quadratic prior on the pose (``PosePrior``: the information earlier motions carry, marginalized) is
added to U and to the pose gradient.

The problem is any object with ``n_pose``, ``tracks`` (a ``solver.refinement.TrackSet``: its
``track`` index per observation), ``residuals(x)`` (2P [+1] px), ``jacobian_blocks(x)`` (P, 2,
n_pose + 3) and ``prior_row()`` ((n_pose,) or None: the time offset's prior residual, last in
``residuals``), i.e. ``solver.refinement._Problem``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from solver.arrays import FloatArray
from solver.errors import InvalidInputError

Loss = Literal["linear", "cauchy"]


@dataclass(frozen=True)
class PosePrior:
    """A quadratic cost on the pose parameters p (the problem's first n_pose): 0.5 p^T H p + g^T p + c.

    Attributes:
        information: (n, n) float64, H: px^2 per (rad, m[, s])^2, symmetric positive semi-definite.
        gradient: (n,) float64, g: px^2 per (rad, m[, s]).
        constant: c, px^2: the cost at p = 0 (e.g. what the earlier motions' residuals cost there), so
            that the total, and the relative decrease that ends the iteration, mean what they do in a
            batch adjustment.
    """

    information: FloatArray
    gradient: FloatArray
    constant: float = 0.0

    def cost(self, p: FloatArray) -> float:
        """The prior's cost at pose parameters p (n,)."""
        return float(0.5 * p @ self.information @ p + self.gradient @ p + self.constant)


@dataclass(frozen=True)
class SchurSolution:
    """Where ``solve_schur`` ended.

    Attributes:
        x: (n_pose + 3T,) the parameters.
        fun: the problem's residuals at x (2P px, then the time offset's prior residual when it has one).
        cost: the robust cost there (with the pose prior's), px^2.
        iterations: Jacobian evaluations.
        converged: the relative cost decrease fell below ``ftol`` (else the iteration cap or no progress).
    """

    x: FloatArray
    fun: FloatArray
    cost: float
    iterations: int
    converged: bool


def track_starts(track: np.ndarray) -> np.ndarray:
    """Index of each track's first observation, for ``np.add.reduceat`` (observations grouped by track)."""
    if track.size and np.any(np.diff(track) < 0):
        raise InvalidInputError("observations must be grouped by track, in order (build_track_set's layout)")
    return np.flatnonzero(np.r_[True, np.diff(track) != 0])


def _robust_cost(r2: FloatArray, loss: Loss, c2: float) -> float:
    return float(0.5 * np.sum(r2 if loss == "linear" else c2 * np.log1p(r2 / c2)))


def _weights(r2: FloatArray, loss: Loss, c2: float) -> FloatArray:
    return np.ones_like(r2) if loss == "linear" else 1.0 / (1.0 + r2 / c2)


def normal_blocks(blocks: FloatArray, r: FloatArray, w: FloatArray, starts: np.ndarray, per_track_pose: bool = False
                  ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The weighted normal equations' blocks from the observations' Jacobian blocks.

    Args:
        blocks: (P, 2, n + 3): each observation's derivatives by the pose's n parameters and its point's 3.
        r: (P, 2) px: the residuals.
        w: (P,): each observation's weight.
        starts: (T,) the first observation of each track (observations grouped by track).
        per_track_pose: give the pose block and gradient per track (each track's share) instead of summed.

    Returns:
        The pose block U (n, n) (per track (T, n, n)), the couplings W_t (T, n, 3), the point blocks
        V_t (T, 3, 3), the pose gradient gp (n,) (per track (T, n)) and the points' gx_t (T, 3).
    """
    P, n = blocks.shape[0], blocks.shape[2] - 3
    Jw = blocks * w[:, None, None]
    JwT = Jw.transpose(0, 2, 1)  # (P, n + 3, 2); batched matmul is ~5x faster than einsum here
    Jx = blocks[:, :, n:]
    W = np.add.reduceat(np.matmul(JwT[:, :n], Jx), starts)
    V = np.add.reduceat(np.matmul(JwT[:, n:], Jx), starts)
    g = np.matmul(JwT, r[:, :, None])[:, :, 0]  # (P, n + 3)
    gx = np.add.reduceat(g[:, n:], starts)
    if per_track_pose:
        U = np.add.reduceat(np.matmul(JwT[:, :n], blocks[:, :, :n]), starts)
        return U, W, V, np.add.reduceat(g[:, :n], starts), gx
    U = Jw[:, :, :n].reshape(2 * P, n).T @ blocks[:, :, :n].reshape(2 * P, n)  # one BLAS product
    return U, W, V, g[:, :n].sum(axis=0), gx


def robust_sigma(res: FloatArray) -> float:
    """px: the noise per coordinate of residuals (P, 2) px, from their median absolute value (1.4826 MAD)."""
    return 1.4826 * float(np.median(np.abs(res)))


def pose_step_sigmas(dp: FloatArray, S: FloatArray, r: FloatArray) -> float:
    """How far a pose step dp (n,) goes in units of the pose's 1-sigma: sqrt(dp^T S dp) / sigma.

    ``S`` (n, n) is the (weighted) Schur information in px^2 per unit of the parameters, so that the
    pose's covariance is sigma^2 S^-1; sigma (px) is the residuals' ``r`` (P, 2) ``robust_sigma``. A step
    along a direction the data fix well counts for more than the same step along a weak one, as the
    robust pass's outlier points creep on while the pose stands still.
    """
    sigma = robust_sigma(r)
    quad = float(dp @ S @ dp)
    return float(np.sqrt(max(quad, 0.0))) / sigma if sigma > 0 else float("inf")


def solve_schur(problem: Any, x0: FloatArray, loss: Loss = "linear", f_scale: float = 1.0, max_iter: int = 50,
                ftol: float = 1e-9, prior: PosePrior | None = None, pose_tol: float | None = None) -> SchurSolution:
    """Minimize the problem's robust cost (plus the pose prior's) from x0 by Levenberg-Marquardt.

    Args:
        problem: the bundle adjustment (the module doc).
        x0: (n_pose + 3T,) the start.
        loss: "linear" (least squares) or "cauchy" (scale ``f_scale`` px, on each observation's squared error).
        f_scale: px, the Cauchy scale.
        max_iter: Jacobian evaluations at most.
        ftol: the relative cost decrease of an accepted step below which the iteration stops.
        prior: a quadratic cost on the pose parameters, or None.
        pose_tol: also stop once an accepted step moves the pose by less than this fraction of its
            1-sigma (``pose_step_sigmas`` with the step's damped S, which lam keeps close to the
            undamped one near the optimum), whatever the points do; None: the cost criterion alone.

    Returns:
        The solution (``SchurSolution``).
    """
    n = problem.n_pose
    starts = track_starts(problem.tracks.track)
    P = problem.tracks.track.size
    c2 = float(f_scale) ** 2
    row = problem.prior_row()

    def evaluate(x: FloatArray) -> tuple[FloatArray, float]:
        fun = problem.residuals(x)
        r2 = np.sum(fun[:2 * P].reshape(P, 2) ** 2, axis=1)
        cost = _robust_cost(r2, loss, c2) + 0.5 * float(np.sum(fun[2 * P:] ** 2))
        if prior is not None:
            cost += prior.cost(x[:n])
        return fun, cost

    x = np.array(x0, dtype=np.float64)
    fun, cost = evaluate(x)
    lam = 1e-4
    converged = False
    iterations = 0
    while iterations < max_iter:
        iterations += 1
        r = fun[:2 * P].reshape(P, 2)
        blocks = problem.jacobian_blocks(x)
        U, W, V, gp, gx = normal_blocks(blocks, r, _weights(np.sum(r**2, axis=1), loss, c2), starts)
        if row is not None:
            U = U + np.outer(row, row)
            gp = gp + row * fun[2 * P]
        if prior is not None:
            U = U + prior.information
            gp = gp + prior.information @ x[:n] + prior.gradient
        dU, dV = np.diag(U).copy(), np.einsum("tii->ti", V).copy()
        improved = False
        while lam < 1e12:
            Vd = V + lam * (dV[:, :, None] * np.eye(3) + 1e-12 * np.eye(3))
            Vinv = np.linalg.inv(Vd)
            WVinv = np.matmul(W, Vinv)  # (T, n, 3)
            S = U + lam * np.diag(dU) - np.einsum("tij,tkj->ik", WVinv, W)
            rhs = -(gp - np.einsum("tij,tj->i", WVinv, gx))
            try:
                dp = np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            dx = -np.einsum("tij,tj->ti", Vinv, gx + np.einsum("tji,j->ti", W, dp))
            step = np.concatenate([dp, dx.ravel()])
            x_new = x + step
            fun_new, cost_new = evaluate(x_new)
            if np.isfinite(cost_new) and cost_new < cost:
                decrease = (cost - cost_new) / max(cost, 1e-300)
                converged = decrease < ftol or (pose_tol is not None
                                                and pose_step_sigmas(dp, S, r) < pose_tol)
                x, fun, cost = x_new, fun_new, cost_new
                lam = max(lam / 10, 1e-12)
                improved = True
                break
            lam *= 10
        if not improved or converged:
            converged = converged or not improved  # no step lowers the cost: a minimum to working precision
            break
    return SchurSolution(x, fun, cost, iterations, converged)
