"""Maximum-likelihood refinement (ours): bundle adjustment of T_camera_base and the keypoints.

Each track is an unknown point p0 fixed on the moving link, given in the base frame at the start
configuration. At frame k the motion turns it about the joint axis (a_b, d_b) = Gamma(Q, J) by
delta_k, so p_base,k = Rot(a_b, delta_k) (p0 - d_b) + d_b; the camera sees
p_cam,k = R p_base,k + t, and the residual is the pixel error of its projection (fx, fy applied
to the normalized-coordinate error). The pose is perturbed as R = Exp(omega) R_hat, t = t_hat + tau
(``solver.frames``). Solved with scipy's ``least_squares`` (TRF, sparse analytic Jacobian, LSMR):
first a redescending Cauchy loss, then tracks whose RMS error stays far above the noise are dropped
and a plain least-squares pass yields the estimate and its covariance (Gauss-Newton, Schur
complement over the points, scaled by the residual variance, enlarged where a track-clustered
sandwich estimate is larger).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.linalg import eigh
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.frames import perturb, rotation_about_axis, skew

IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class RefinementConfig:
    """Settings of the bundle adjustment.

    Attributes:
        cauchy_scale_px: scale of the Cauchy loss in the robust pass, px.
        outlier_px: px; after the robust pass a track whose RMS error (per coordinate) exceeds the
            larger of this and ``outlier_sigmas`` robust sigmas of all residuals is dropped. A
            good track of 30 frames has RMS within ~15% of sigma, so 1.8 sigma is about five
            standard deviations out, while slowly drifting tracks that bias the pose by
            millimetres sit at 2-3 sigma.
        outlier_sigmas: see ``outlier_px``.
        max_nfev: function evaluations per pass at most.
        min_track_frames: tracks with fewer frames are not used.
        robust_ftol: relative cost change that ends the robust pass. In whitened coordinates
            (``_Whitened``) a warm-started pass reaches the optimum's cost to 1e-5 within ~15
            iterations and then creeps while outlier tracks' points drift; 1e-5 gives the same
            estimates as 1e-9 to 1e-6 rad / 1e-6 m on scripts/bench_solver.py at a third of the cost.
            The robust pass only classifies tracks; the final pass fixes the estimate.
    """

    cauchy_scale_px: float = 1.0
    outlier_px: float = 0.5
    outlier_sigmas: float = 1.8
    max_nfev: int = 50
    min_track_frames: int = 4
    robust_ftol: float = 1e-5


@dataclass(frozen=True)
class TrackSet:
    """All tracks of the motions to refine, flattened.

    Attributes:
        uv: (P, 2) float64: normalized image coordinates of every observation.
        track: (P,) int: track index of each observation.
        rot: (P, 3, 3) float64: Rot(a_b, delta) of each observation's frame.
        pivot: (T, 3) float64, m: d_b of each track's motion (base frame).
        motion: (T,) int: motion index of each track.
        focal: (2,) float64, px: (fx, fy).
    """

    uv: FloatArray
    track: IntArray
    rot: FloatArray
    pivot: FloatArray
    motion: IntArray
    focal: FloatArray

    @property
    def n_tracks(self) -> int:
        """Number of tracks T."""
        return int(self.pivot.shape[0])


def build_track_set(motions: Sequence[tuple[FloatArray, FloatArray, Sequence[tuple[FloatArray, FloatArray]]]],
                    focal: FloatArray, min_frames: int = 4) -> TrackSet:
    """Flatten motions into a TrackSet.

    Args:
        motions: per motion (axis_base (3,), point_base (3,) m, tracks), each track a pair
            (uv (M, 2) normalized coordinates, delta (M,) rad).
        focal: (2,) float64, px: (fx, fy), to express residuals in pixels.
        min_frames: shorter tracks are skipped.
    """
    uv, track, rot, pivot, motion = [], [], [], [], []
    for i, (axis, point, tracks) in enumerate(motions):
        kept = [(uv_j, delta_j) for uv_j, delta_j in tracks if uv_j.shape[0] >= min_frames]
        if not kept:
            continue
        for uv_j, _ in kept:
            uv.append(uv_j)
            track.append(np.full(uv_j.shape[0], len(pivot)))
            pivot.append(point)
            motion.append(i)
        rot.append(rotation_about_axis(axis, np.concatenate([d for _, d in kept])))  # one call per motion
    if not pivot:
        raise InsufficientMotionsError("no track long enough to refine")
    return TrackSet(np.concatenate(uv), np.concatenate(track).astype(np.int64), np.concatenate(rot),
                    np.array(pivot), np.array(motion, dtype=np.int64), np.asarray(focal, float))


def triangulate_tracks(tracks: TrackSet, T_camera_base: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Each track's point p0 (base frame, start configuration) given the pose: linear, closed form.

    With y = p0 - d_b and M_k = R Rot_k, the camera point is M_k y + (R d_b + t); requiring it on
    the observed ray (x - u z = 0, y - v z = 0) is linear in y. Solved per track by least squares.

    Returns:
        points (T, 3) float64, m, and ok (T,) bool: False where the system is singular or the point
        falls behind the camera.
    """
    R, t = T_camera_base[:3, :3], T_camera_base[:3, 3]
    M = np.einsum("ij,pjk->pik", R, tracks.rot)  # (P, 3, 3)
    c = tracks.pivot[tracks.track] @ R.T + t  # (P, 3)
    u, v = tracks.uv[:, 0], tracks.uv[:, 1]
    A = np.stack([M[:, 0] - u[:, None] * M[:, 2], M[:, 1] - v[:, None] * M[:, 2]], axis=1)  # (P,2,3)
    b = np.stack([u * c[:, 2] - c[:, 0], v * c[:, 2] - c[:, 1]], axis=1)  # (P, 2)
    AtA = np.zeros((tracks.n_tracks, 3, 3))
    Atb = np.zeros((tracks.n_tracks, 3))
    np.add.at(AtA, tracks.track, np.einsum("pki,pkj->pij", A, A))
    np.add.at(Atb, tracks.track, np.einsum("pki,pk->pi", A, b))
    det = np.linalg.det(AtA)
    scale = np.einsum("tii->t", AtA) ** 3
    ok = det > 1e-12 * np.maximum(scale, 1e-300)
    AtA[~ok] = np.eye(3)
    y = np.linalg.solve(AtA, Atb[..., None])[..., 0]
    points = y + tracks.pivot
    depth = np.einsum("pij,pj->pi", M, y[tracks.track]) [:, 2] + c[:, 2]
    front = np.bincount(tracks.track, weights=(depth > 0).astype(float), minlength=tracks.n_tracks)
    counts = np.bincount(tracks.track, minlength=tracks.n_tracks)
    ok &= front == counts
    return points, ok


def _left_jacobian(omega: FloatArray) -> FloatArray:
    theta = float(np.linalg.norm(omega))
    W = skew(omega)
    if theta < 1e-8:
        return np.eye(3) + 0.5 * W
    return (np.eye(3) + (1 - np.cos(theta)) / theta**2 * W
            + (theta - np.sin(theta)) / theta**3 * W @ W)


class _Problem:
    """Residuals and sparse Jacobian of the bundle adjustment over x = (omega, tau, q_1..q_T).

    Each track's unknown is q, its point in the camera frame at the start configuration (delta =
    0), not its base-frame point p0 = R^T (q - t): the frame-0 residual then does not depend on the
    pose, which decouples points from pose and makes the sparse normal equations far better
    conditioned for LSMR. The pose's marginal covariance is the same in either parameterization
    (the change of variables is block-triangular with an identity pose block).
    """

    def __init__(self, tracks: TrackSet, T0: FloatArray):
        self.tracks = tracks
        self.T0 = T0
        P = tracks.uv.shape[0]
        cols = np.empty((P, 2, 9), dtype=np.int64)
        cols[:, :, :6] = np.arange(6)
        cols[:, :, 6:] = (6 + 3 * tracks.track)[:, None, None] + np.arange(3)
        self.cols = cols.ravel()  # CSR column indices: every row has the 6 pose entries and its point's 3
        self.indptr = np.arange(0, 9 * 2 * P + 1, 9)
        self.shape = (2 * P, 6 + 3 * tracks.n_tracks)
        self.obs_pivot = tracks.pivot[tracks.track]  # (P, 3) m: each observation's d_b

    def pose(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """R (3, 3) and t (3,) at parameters x."""
        return Rotation.from_rotvec(x[:3]).as_matrix() @ self.T0[:3, :3], self.T0[:3, 3] + x[3:6]

    def _camera_points(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        tr = self.tracks
        R, t = self.pose(x)
        q = x[6:].reshape(-1, 3)[tr.track]
        y = (q - t) @ R  # R^T (q - t): the base-frame point at delta = 0
        p_base = np.matmul(tr.rot, (y - self.obs_pivot)[:, :, None])[:, :, 0] + self.obs_pivot
        return p_base @ R.T + t, R, t, q

    def residuals(self, x: FloatArray) -> FloatArray:
        """(2P,) float64, px: reprojection errors."""
        pc = self._camera_points(x)[0]
        return ((pc[:, :2] / pc[:, 2:] - self.tracks.uv) * self.tracks.focal).ravel()

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        """(2P, 6 + 3T) sparse Jacobian of ``residuals``."""
        return sp.csr_matrix((self.jacobian_blocks(x).ravel(), self.cols, self.indptr), shape=self.shape)

    def jacobian_blocks(self, x: FloatArray) -> FloatArray:
        """(P, 2, 9): each observation's derivatives by (omega, tau) and by its own track's point q.

        With D the (2, 3) derivative of the pixel by the camera point and M = R Rot_k R^T, the
        camera point's derivatives are -[pc - t]x + M [q - t]x by omega (times the left Jacobian of
        SO(3)), I - M by tau and M by q; a row v of D times [a]x is v x a.
        """
        tr = self.tracks
        pc, R, t, q = self._camera_points(x)
        P = pc.shape[0]
        inv_z = 1.0 / pc[:, 2]
        D = np.zeros((P, 2, 3))
        D[:, 0, 0] = tr.focal[0] * inv_z
        D[:, 1, 1] = tr.focal[1] * inv_z
        D[:, 0, 2] = -tr.focal[0] * pc[:, 0] * inv_z**2
        D[:, 1, 2] = -tr.focal[1] * pc[:, 1] * inv_z**2
        DM = np.matmul((D.reshape(2 * P, 3) @ R).reshape(P, 2, 3), tr.rot).reshape(2 * P, 3) @ R.T  # D M
        DM = DM.reshape(P, 2, 3)
        d_omega = np.cross(DM, (q - t)[:, None, :]) - np.cross(D, (pc - t)[:, None, :])
        d_omega = (d_omega.reshape(2 * P, 3) @ _left_jacobian(x[:3])).reshape(P, 2, 3)
        return np.concatenate([d_omega, D - DM, DM], axis=2)


@dataclass(frozen=True)
class RefinementResult:
    """Outcome of the bundle adjustment.

    Attributes:
        T_camera_base: (4, 4) float64: the refined pose.
        covariance: (6, 6) float64: covariance of (omega rad, tau m) about it (``solver.frames``):
            the model's (pixel noise independent, ``pose_covariance``), enlarged along the
            directions where the track-clustered sandwich (``clustered_pose_covariance``) is
            larger. On synthetic episodes with 10% drifting or jumping tracks the model's alone
            holds the truth in its 95% region in 29% / 50% of runs at 5 / 10 motions, this in
            86% / 90% (the drifts that survive outlier removal bias the pose; their residuals are
            correlated within the track).
        points_base: (T, 3) float64, m: each track's point at its motion's start configuration.
        track_inliers: (T,) bool: tracks kept after the robust pass.
        rms_px: RMS reprojection error of the kept tracks, px.
        sigma_px: estimated pixel noise (per coordinate) from the kept residuals.
    """

    T_camera_base: FloatArray
    covariance: FloatArray
    points_base: FloatArray
    track_inliers: NDArray[np.bool_]
    rms_px: float
    sigma_px: float


class _Whitened:
    """A ``_Problem`` in block-whitened coordinates z about x0: x = x0 + A z.

    A is block diagonal: the pose's (6, 6) block and each track's (3, 3) block are L^-T for the
    Cholesky factor L of that block of J^T J at x0. Then J^T J in z has identity diagonal blocks
    for the points, so J^T J - I has rank at most 12 (the pose's coupling) and LSMR converges in
    a few dozen iterations instead of hundreds; and z starts at 0, so TRF's first trust region is
    unit-sized in these units (x0 itself would make it the size of the points' coordinates).
    """

    def __init__(self, problem: _Problem, x0: FloatArray):
        self.problem = problem
        self.x0 = x0
        blocks = problem.jacobian_blocks(x0)
        U, V = _diagonal_blocks(blocks, problem.tracks)
        self.Ap = _inverse_cholesky_t(U)
        self.Aq = _inverse_cholesky_t(V)
        self.Aq_obs = self.Aq[problem.tracks.track]  # (P, 3, 3)
        self._blocks_x0: FloatArray | None = blocks  # TRF's first Jacobian is at z = 0: x0's blocks

    def native(self, z: FloatArray) -> FloatArray:
        """(6 + 3T,) the problem's parameters x at whitened z."""
        dq = np.matmul(self.Aq, z[6:].reshape(-1, 3, 1))[:, :, 0]
        return self.x0 + np.concatenate([self.Ap @ z[:6], dq.ravel()])

    def residuals(self, z: FloatArray) -> FloatArray:
        """(2P,) float64, px: the problem's residuals at x(z)."""
        return self.problem.residuals(self.native(z))

    def jacobian(self, z: FloatArray) -> sp.csr_matrix:
        """(2P, 6 + 3T) sparse Jacobian of ``residuals`` by z."""
        p = self.problem
        if self._blocks_x0 is not None and not np.any(z):
            blocks, self._blocks_x0 = self._blocks_x0, None
        else:
            blocks = p.jacobian_blocks(self.native(z))
        P = blocks.shape[0]
        blocks[:, :, :6] = (blocks[:, :, :6].reshape(2 * P, 6) @ self.Ap).reshape(P, 2, 6)
        blocks[:, :, 6:] = np.matmul(blocks[:, :, 6:], self.Aq_obs)
        return sp.csr_matrix((blocks.ravel(), p.cols, p.indptr), shape=p.shape)


def _inverse_cholesky_t(S: FloatArray) -> FloatArray:
    """L^-T for S = L L^T, for (n, n) or a stack (..., n, n) of symmetric PSD matrices.

    A ridge of 1e-9 of the trace keeps rank-deficient blocks (a track that barely moves) finite.
    """
    n = S.shape[-1]
    ridge = 1e-9 * np.trace(S, axis1=-2, axis2=-1)[..., None, None] + 1e-300
    L = np.linalg.cholesky(S + ridge * np.eye(n))
    return np.swapaxes(np.linalg.inv(L), -1, -2)


def _per_track_sum(values: FloatArray, tracks: TrackSet) -> FloatArray:
    """Sum per track of per-observation values (P, ...) -> (T, ...)."""
    out = np.zeros((tracks.n_tracks,) + values.shape[1:])
    np.add.at(out, tracks.track, values)
    return out


def _diagonal_blocks(blocks: FloatArray, tracks: TrackSet) -> tuple[FloatArray, FloatArray]:
    """The pose's block U (6, 6) and each track's point block V (T, 3, 3) of J^T J, from the blocks (P, 2, 9)."""
    Jp, Jx = blocks[:, :, :6], blocks[:, :, 6:]
    return np.einsum("pki,pkj->ij", Jp, Jp), _per_track_sum(np.einsum("pki,pkj->pij", Jx, Jx), tracks)


#: TRF's first trust region in whitened units (a unit step changes the residual vector by about
#: 1 px in norm): large enough for a warm start's step, so a pass does not spend its first
#: iterations doubling a unit region (20-40% fewer evaluations on scripts/bench_solver.py).
_TRUST_SCALE = 32.0


def _solve(tracks: TrackSet, T0: FloatArray, points: FloatArray, loss: str, f_scale: float,
           max_nfev: int, lsmr_tol: float = 1e-12, ftol: float = 1e-9
           ) -> tuple[FloatArray, FloatArray, _Problem, FloatArray, object]:
    """One least-squares pass from pose T0 and base-frame points (T, 3) (``_Whitened`` coordinates).

    ``lsmr_tol`` must be tight (1e-12) far from the optimum, where TRF otherwise stalls; the
    final pass starts at the robust optimum and converges with a looser one. ``ftol`` is the
    relative cost change that ends the pass.

    Returns:
        pose (4, 4), base points (T, 3), the problem, its parameters x at the solution, and
        scipy's result (whose ``fun`` is the residual vector there).
    """
    problem = _Problem(tracks, T0)
    q0 = points @ T0[:3, :3].T + T0[:3, 3]
    white = _Whitened(problem, np.concatenate([np.zeros(6), q0.ravel()]))
    sol = least_squares(white.residuals, np.zeros(6 + 3 * tracks.n_tracks), jac=white.jacobian,
                        method="trf", loss=loss, f_scale=f_scale, tr_solver="lsmr", max_nfev=max_nfev,
                        x_scale=_TRUST_SCALE,
                        tr_options={"atol": lsmr_tol, "btol": lsmr_tol}, xtol=1e-10, ftol=ftol)
    x = white.native(sol.x)
    R, t = problem.pose(x)
    return perturb(T0, x[:6]), (x[6:].reshape(-1, 3) - t) @ R, problem, x, sol


def _schur_parts(problem: _Problem, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The Jacobian's dense blocks (P, 2, 9), W (T, 6, 3), V^-1 (T, 3, 3) and S = U - W V^-1 W^T (6, 6) at x.

    Built track by track (each observation touches the pose and its own point only); S is the pose
    block of J^T J with every track's point marginalized out, px^2 per (rad or m)^2.
    """
    blocks = problem.jacobian_blocks(x)
    U, V = _diagonal_blocks(blocks, problem.tracks)
    W = _per_track_sum(np.einsum("pki,pkj->pij", blocks[:, :, :6], blocks[:, :, 6:]), problem.tracks)
    V_inv = np.linalg.inv(V + 1e-12 * np.eye(3))
    return blocks, W, V_inv, U - np.einsum("tij,tjk,tlk->il", W, V_inv, W)


def _schur_information(problem: _Problem, x: FloatArray) -> FloatArray:
    """U - W V^-1 W^T (6, 6): the pose block of J^T J at x with every track's point marginalized out."""
    return _schur_parts(problem, x)[3]


def pose_covariance(problem: _Problem, x: FloatArray, sigma2: float) -> FloatArray:
    """Covariance (6, 6) of the pose block at x: sigma^2 (U - W V^-1 W^T)^-1 (Schur complement).

    Args:
        problem: the bundle adjustment.
        x: (6 + 3T,) its parameters (pose perturbation, then the tracks' camera-frame points).
        sigma2: residual variance, px^2.
    """
    return sigma2 * np.linalg.inv(_schur_information(problem, x))


def clustered_pose_covariance(problem: _Problem, x: FloatArray) -> FloatArray:
    """Track-clustered sandwich covariance (6, 6) of the pose at the least-squares optimum x.

    S^-1 (sum_t g_t g_t^T) S^-1 with S the Schur information and g_t track t's score with its
    point marginalized, (J_p,t - J_x,t V_t^-1 W_t^T)^T r_t: errors may be correlated within a
    track (a tracker drifting off its feature) but not across tracks. Scaled by
    T / (T - 1) * m / (m - n) for the clusters and the fitted parameters (m residuals, n unknowns).
    """
    return _pose_covariances(problem, x, 1.0, problem.residuals(x))[1]


def _pose_covariances(problem: _Problem, x: FloatArray, sigma2: float,
                      residuals: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``pose_covariance`` and ``clustered_pose_covariance`` at x from one evaluation of the blocks.

    ``residuals``: (2P,) float64, px, the residuals at x (the solver's ``fun``: not evaluated again).
    """
    blocks, W, V_inv, S = _schur_parts(problem, x)
    Jp, Jx = blocks[:, :, :6], blocks[:, :, 6:]
    r = residuals.reshape(-1, 2)
    tracks = problem.tracks
    g = (_per_track_sum(np.einsum("pki,pk->pi", Jp, r), tracks)
         - np.einsum("tij,tjk,tk->ti", W, V_inv, _per_track_sum(np.einsum("pki,pk->pi", Jx, r), tracks)))
    S_inv = np.linalg.inv(S)
    T, m, n = tracks.n_tracks, r.size, x.size
    scale = T / max(T - 1, 1) * m / max(m - n, 1)
    C = scale * S_inv @ (g.T @ g) @ S_inv
    return sigma2 * S_inv, 0.5 * (C + C.T)


def conservative_covariance(model: FloatArray, clustered: FloatArray) -> FloatArray:
    """The smallest covariance (6, 6) at least as large as both, in the model's eigen-directions.

    With C v = l M v (generalized eigenvectors, V^T M V = I), returns M V diag(max(l, 1)) V^T M:
    ``model`` where the clustered estimate is smaller, the clustered one where it is larger.
    """
    lam, V = eigh(clustered, model)
    MV = model @ V
    out = MV @ np.diag(np.maximum(lam, 1.0)) @ MV.T
    return 0.5 * (out + out.T)


def pose_information(tracks: TrackSet, T_camera_base: FloatArray) -> FloatArray:
    """Fisher information (6, 6) about (omega, tau) that noise-free tracks carry, per px^-2 of noise.

    The bundle adjustment's own Jacobian at ``T_camera_base`` and the tracks' points (triangulated
    from it), with each point marginalized out (Schur complement): what these observations would
    add to the estimate if every pixel had unit variance. Divide by sigma^2 (px^2) for the Fisher
    information; its inverse is the Cramer-Rao bound of the pose from these tracks alone. Tracks
    that cannot be triangulated (a point that does not move, or behind the camera) add nothing.
    Used to predict what a planned motion would add (``planners.informed_planner``).

    Args:
        tracks: the observations (``build_track_set``); uv need only be their projections.
        T_camera_base: (4, 4) float64: the pose at which to evaluate.

    Returns:
        (6, 6) float64, symmetric positive semi-definite, in px^2 per (rad or m)^2.
    """
    points, ok = triangulate_tracks(tracks, T_camera_base)
    if not ok.any():
        return np.zeros((6, 6))
    q = points[ok] @ T_camera_base[:3, :3].T + T_camera_base[:3, 3]
    S = _schur_information(_Problem(_subset(tracks, ok), T_camera_base), np.concatenate([np.zeros(6), q.ravel()]))
    return 0.5 * (S + S.T)


def track_observability(tracks: TrackSet, T_camera_base: FloatArray,
                        keep: NDArray[np.bool_] | None = None) -> tuple[float, FloatArray]:
    """How well the tracks fix the pose near T_camera_base, whatever their noise.

    The square roots of the eigenvalues of ``pose_information`` are the singular values of the
    bundle adjustment's pose Jacobian with the points marginalized out; with the translation in units
    of the points' mean distance from the camera, their ratio is dimensionless. A direction the tracks
    leave free (e.g. the depth of joints whose axes all meet in one point, seen without noise) gives a
    ratio near zero, where the covariance (scaled by the fitted noise) can still look small.

    Args:
        tracks: the observations (``build_track_set``).
        T_camera_base: (4, 4) float64: the pose at which to evaluate.
        keep: (T,) bool: the tracks to use (e.g. ``RefinementResult.track_inliers``); all if None.

    Returns:
        The ratio of the smallest to the largest singular value (0 when no track can be triangulated),
        and the weakest direction (6,) of (omega, tau / depth).
    """
    if keep is not None:
        tracks = _subset(tracks, keep)
    points, ok = triangulate_tracks(tracks, T_camera_base)
    if not ok.any():
        return 0.0, np.zeros(6)
    depth = float(np.mean(np.linalg.norm(points[ok] @ T_camera_base[:3, :3].T + T_camera_base[:3, 3], axis=1)))
    scale = np.array([1.0, 1.0, 1.0, depth, depth, depth])
    lam, V = np.linalg.eigh(pose_information(tracks, T_camera_base) * np.outer(scale, scale))
    return float(np.sqrt(max(lam[0], 0.0) / lam[-1])) if lam[-1] > 0 else 0.0, V[:, 0]


def refine(tracks: TrackSet, T_init: FloatArray, config: RefinementConfig | None = None,
           points_init: FloatArray | None = None) -> RefinementResult:
    """Bundle-adjust T_camera_base and the track points, starting from ``T_init``.

    Args:
        tracks: the observations (``build_track_set``).
        T_init: (4, 4) float64: starting pose, e.g. the linear calibration.
        config: settings; defaults to ``RefinementConfig()``.
        points_init: (T, 3) float64, m: starting points; triangulated from ``T_init`` if None.

    Raises:
        InsufficientMotionsError: fewer than two tracks survive triangulation or outlier removal.
    """
    config = config or RefinementConfig()
    if not np.all(np.isfinite(T_init)):
        raise InvalidInputError("T_init contains NaN or infinite values")
    points, ok = triangulate_tracks(tracks, T_init)
    if points_init is not None:
        points = np.where(np.isfinite(points_init).all(axis=1)[:, None], points_init, points)
    keep = ok.copy()
    if keep.sum() < 2:
        raise InsufficientMotionsError("fewer than two tracks could be triangulated from the pose")
    sub = _subset(tracks, keep)
    T, pts, problem, _, sol = _solve(sub, T_init, points[keep], "cauchy", config.cauchy_scale_px,
                                  config.max_nfev, ftol=config.robust_ftol)
    res = sol.fun.reshape(-1, 2)
    track_rms = np.sqrt(np.bincount(sub.track, weights=np.sum(res**2, axis=1), minlength=sub.n_tracks)
                        / np.maximum(np.bincount(sub.track, minlength=sub.n_tracks), 1) / 2)
    sigma = 1.4826 * float(np.median(np.abs(res)))
    good = track_rms <= max(config.outlier_px, config.outlier_sigmas * sigma)
    if good.sum() < 2:
        raise InsufficientMotionsError("fewer than two tracks agree with the refined pose")
    sub2 = _subset(sub, good)
    T, pts2, problem, x, sol = _solve(sub2, T, pts[good], "linear", 1.0, config.max_nfev, 1e-8)
    m, n = sol.fun.size, sol.x.size
    sigma2 = float(np.sum(sol.fun**2) / max(m - n, 1))
    cov = conservative_covariance(*_pose_covariances(problem, x, sigma2, sol.fun))
    inliers = np.zeros(tracks.n_tracks, dtype=bool)
    kept_idx = np.flatnonzero(keep)[good]
    inliers[kept_idx] = True
    all_points = np.full((tracks.n_tracks, 3), np.nan)
    all_points[kept_idx] = pts2
    return RefinementResult(T, cov, all_points, inliers, float(np.sqrt(np.mean(sol.fun**2))),
                            float(np.sqrt(sigma2)))


def screen_start(tracks: TrackSet, T_init: FloatArray, config: RefinementConfig, max_nfev: int,
                 cap_px: float) -> tuple[FloatArray, float]:
    """A short robust pass of the bundle adjustment from ``T_init``, scored so that starts compare.

    The points are triangulated from ``T_init`` and the pose and points take at most ``max_nfev``
    evaluations of the Cauchy pass (``refine``'s first). The score is the mean over every
    observation of min(r^2, cap_px^2) per coordinate, r the residual where the pass ended, and
    cap_px^2 for every observation of a track that could not be triangulated (behind the camera):
    a start that leaves tracks out is not rewarded for it.

    Args:
        tracks: the observations (``build_track_set``).
        T_init: (4, 4) float64: the start.
        config: bundle-adjustment settings (Cauchy scale, ftol).
        max_nfev: evaluations at most.
        cap_px: px, the truncation of the score.

    Returns:
        The pose where the pass ended (4, 4), and the score, px^2 (inf when fewer than two tracks
        can be triangulated).
    """
    points, ok = triangulate_tracks(tracks, T_init)
    if ok.sum() < 2:
        return T_init, np.inf
    T, _, _, _, sol = _solve(_subset(tracks, ok), T_init, points[ok], "cauchy", config.cauchy_scale_px,
                             max_nfev, ftol=config.robust_ftol)
    n_left_out = int(np.sum(~ok[tracks.track]))
    total = float(np.sum(np.minimum(sol.fun**2, cap_px**2))) + 2 * n_left_out * cap_px**2
    return T, total / (2 * tracks.track.size)


def _subset(tracks: TrackSet, keep: NDArray[np.bool_]) -> TrackSet:
    new_index = np.cumsum(keep) - 1
    mask = keep[tracks.track]
    return TrackSet(tracks.uv[mask], new_index[tracks.track[mask]].astype(np.int64), tracks.rot[mask],
                    tracks.pivot[keep], tracks.motion[keep], tracks.focal)


