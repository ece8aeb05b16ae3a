"""A motion's axis from the rigid motion of its tracks (ours; the issue's "relative-pose front end").

One joint turns by a known delta, so every point on the moving links moves as
``X(delta) = R(a, delta) (X0 - p) + p`` in the camera frame: a rotation by the *known* angle about an
unknown line (direction ``a``, point ``p``). This module fits that model to all tracks of one motion at
once, starting from the relative pose of the two frames that most tracks share (OpenCV's essential
matrix with RANSAC and ``recoverPose``), then refining ``a``, ``p`` and every track's point by robust
least squares over all frames. Only the line's distance from the camera is unknown (the scene's scale),
so ``p`` is fixed to unit distance.

Two uses:

* the axis and reference plane without conics: a ``MotionGeometry`` like the paper's stage one gives,
  from whole tracks instead of per-track ellipses, so short flat arcs (camera near the plane of
  rotation) still give an axis;
* a per-track consistency check: a track that does not move rigidly with the others by the known angle
  (it slides along a silhouette, follows a highlight or a shadow, or drifted) has a large residual and
  is dropped, whatever the camera pose.

Coordinates are normalized camera coordinates (OpenCV optical frame, ``solver.frames``); residuals are
reported in pixels through the mean focal length.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.camera import normalized_from_pixels
from solver.errors import DegenerateMotionError, InvalidInputError
from solver.motion import MotionGeometry
from solver.observations import CameraIntrinsics, MotionObservation

BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class RigidAxisConfig:
    """Settings of ``fit_rigid_axis``.

    Attributes:
        min_tracks: fewest tracks, and fewest shared by the two frames of the relative pose; count.
        min_pair_angle: rad; the two frames of the relative pose differ by at least this joint turn.
        ransac_px: px; the essential matrix's RANSAC threshold.
        max_track_rms_px: px; a track whose RMS residual under the fitted rigid motion exceeds this
            is inconsistent (it slides or drifted) and is dropped, then the fit is repeated.
        loss_scale_px: px; scale of the Cauchy loss of the refinement.
        max_axis_std: rad; the fitted axis direction's 1-sigma must be below this, else the motion is
            degenerate for this front end.
        min_inlier_fraction: fewest tracks, as a fraction, that must move rigidly together.
        max_fit_tracks: the fit uses at most this many tracks (evenly spread over the list); every
            track is then checked against it; count.
        max_fit_frames: frames per track the fit uses (evenly spaced); count.
    """

    min_tracks: int = 6
    min_pair_angle: float = 0.15
    ransac_px: float = 1.0
    max_track_rms_px: float = 1.0
    loss_scale_px: float = 0.5
    max_axis_std: float = 0.02
    min_inlier_fraction: float = 0.3
    max_fit_tracks: int = 40
    max_fit_frames: int = 12

    def __post_init__(self) -> None:
        if self.min_tracks < 5:
            raise InvalidInputError("RigidAxisConfig: min_tracks must be >= 5 (the essential matrix needs 5)")
        if not (self.min_pair_angle > 0 and self.ransac_px > 0 and self.max_track_rms_px > 0
                and self.loss_scale_px > 0 and self.max_axis_std > 0 and 0 < self.min_inlier_fraction <= 1
                and self.max_fit_tracks >= self.min_tracks and self.max_fit_frames >= 3):
            raise InvalidInputError("RigidAxisConfig: angles, thresholds and scales must be > 0, "
                                    "min_inlier_fraction in (0, 1], max_fit_tracks >= min_tracks, max_fit_frames >= 3")


@dataclass(frozen=True)
class RigidAxisFit:
    """The rigid motion of one motion's tracks.

    Attributes:
        axis_cam: (3,) unit rotation axis, camera frame, right-handed for positive delta.
        point_cam: (3,) the axis point closest to the camera centre, scaled to unit distance.
        axis_std: rad, 1-sigma of the axis direction (largest of its two angles).
        track_rms_px: (L,) RMS residual of each track under the fit, px (inf: not fitted).
        track_inliers: (L,) bool: tracks that move rigidly with the others.
        rms_px: RMS residual of the inlier tracks, px.
    """

    axis_cam: FloatArray
    point_cam: FloatArray
    axis_std: float
    track_rms_px: FloatArray
    track_inliers: BoolArray
    rms_px: float


def _basis(a: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit vectors completing a right-handed frame with unit a: (3,), (3,)."""
    e = np.eye(3)[int(np.argmin(np.abs(a)))]
    u = np.cross(a, e)
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


def _frame_table(deltas: list[FloatArray]) -> tuple[FloatArray, list[NDArray[np.int64]]]:
    """The distinct joint angles of a motion (K,) and, per track, the index of each of its frames."""
    angles = np.unique(np.round(np.concatenate(deltas), 12))
    return angles, [np.searchsorted(angles, np.round(d, 12)) for d in deltas]


def _relative_pose(uv: list[FloatArray], frames: list[NDArray[np.int64]], angles: FloatArray,
                   focal: float, config: RigidAxisConfig
                   ) -> list[tuple[FloatArray, FloatArray]]:
    """Starting (a, p) pairs from essential matrices between well-separated frames (best first)."""
    K = angles.shape[0]
    covers = np.zeros((len(uv), K), dtype=bool)
    for i, f in enumerate(frames):
        covers[i, f] = True
    shared = covers.T.astype(np.int64) @ covers.astype(np.int64)  # (K, K) tracks seen in both frames
    turn = np.abs(angles[:, None] - angles[None, :])
    eligible = (turn >= config.min_pair_angle) & (shared >= max(config.min_tracks, 8))
    if not np.any(eligible):
        return []
    score = np.where(eligible, np.minimum(turn, 0.8) * np.sqrt(shared), -1.0)
    pairs = []
    for flat in np.argsort(score, axis=None)[::-1][:6]:
        i, j = np.unravel_index(flat, score.shape)
        if score[i, j] > 0 and i < j:
            pairs.append((int(i), int(j)))
    starts = []
    for i, j in pairs:
        both = np.flatnonzero(covers[:, i] & covers[:, j])
        xi = np.array([uv[t][np.flatnonzero(frames[t] == i)[0]] for t in both])
        xj = np.array([uv[t][np.flatnonzero(frames[t] == j)[0]] for t in both])
        Es, _ = cv2.findEssentialMat(xi, xj, np.eye(3), method=cv2.RANSAC, prob=0.999,
                                     threshold=config.ransac_px / focal)
        if Es is None or Es.shape[1:] != (3,) or Es.shape[0] % 3:
            continue
        turn_ij = abs(angles[j] - angles[i])
        best: tuple[float, FloatArray, FloatArray] | None = None
        for E in Es.reshape(-1, 3, 3):  # the five-point solver may return several solutions
            _, R, t, _ = cv2.recoverPose(E, xi, xj, np.eye(3))
            rotvec = Rotation.from_matrix(R).as_rotvec()
            mismatch = abs(np.linalg.norm(rotvec) - turn_ij)  # the joint's turn is known
            if best is None or mismatch < best[0]:
                best = (mismatch, R, t)
        if best is None:
            continue
        _, R, t = best
        rotvec = Rotation.from_matrix(R).as_rotvec()
        angle = np.linalg.norm(rotvec)
        if angle < 1e-6:
            continue
        a = rotvec / angle * np.sign(angles[j] - angles[i])
        p, *_ = np.linalg.lstsq(np.eye(3) - R, t.ravel(), rcond=None)
        p -= a * (a @ p)
        norm = np.linalg.norm(p)
        if norm < 1e-9:
            continue
        starts.append((a, p / norm))
    return starts


def _triangulate(uv: FloatArray, delta: FloatArray, a: FloatArray, p: FloatArray) -> FloatArray:
    """X0 (3,) of one track under the model, by linear least squares (cross-product form)."""
    Rs = Rotation.from_rotvec(delta[:, None] * a[None]).as_matrix()  # (n, 3, 3)
    rays = np.column_stack([uv, np.ones(len(uv))])
    # x_f cross (R_f X0 + (I - R_f) p) = 0, linear in X0.
    skew = np.zeros((len(uv), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -rays[:, 2], rays[:, 1], -rays[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = rays[:, 2], -rays[:, 1], rays[:, 0]
    A = np.einsum("fij,fjk->fik", skew, Rs).reshape(-1, 3)
    b = -np.einsum("fij,fj->fi", skew, p[None] - np.einsum("fij,j->fi", Rs, p)).reshape(-1)
    X0, *_ = np.linalg.lstsq(A, b, rcond=None)
    return X0


def _reprojection(Rs: FloatArray, X0: FloatArray, p: FloatArray, uv: FloatArray, focal: float) -> FloatArray:
    """Residuals (2 F,) px of points X0 (F, 3) or (3,) turned by Rs (F, 3, 3) about p, against uv (F, 2)."""
    X = np.einsum("fij,fj->fi", Rs, np.broadcast_to(X0 - p, (Rs.shape[0], 3))) + p
    z = np.where(np.abs(X[:, 2:3]) < 1e-6, 1e-6, X[:, 2:3])
    return ((X[:, :2] / z - uv) * focal).ravel()


def _track_rms(uv: FloatArray, delta: FloatArray, a: FloatArray, p: FloatArray, focal: float) -> float:
    """RMS residual, px, of one track's best point under a fixed rigid motion (a, p)."""
    Rs = Rotation.from_rotvec(delta[:, None] * a[None]).as_matrix()

    def residuals(X0: FloatArray) -> FloatArray:
        return _reprojection(Rs, X0, p, uv, focal)

    result = least_squares(residuals, _triangulate(uv, delta, a, p), method="lm", max_nfev=50)
    return float(np.sqrt(2.0 * np.mean(result.fun ** 2)))


def _refine(uv: list[FloatArray], deltas: list[FloatArray], a0: FloatArray, p0: FloatArray,
            X0: FloatArray, focal: float, config: RigidAxisConfig):
    """Robust least squares over (axis: 2, point angle: 1, X0: 3 per track).

    Returns a (3,), p (3,), X0 (T, 3), track RMS (T,) px and the axis 1-sigma, rad.
    """
    u0, v0 = _basis(a0)
    theta0 = np.arctan2(p0 @ v0, p0 @ u0)
    n_obs = np.array([len(d) for d in deltas])
    starts = np.concatenate([[0], np.cumsum(n_obs)])
    track_of = np.repeat(np.arange(len(uv)), n_obs)
    all_uv = np.concatenate(uv)
    all_delta = np.concatenate(deltas)

    def unpack(x):
        # a turned by a small rotation; theta measured in the basis turned with it (continuous)
        R_turn = Rotation.from_rotvec(x[0] * u0 + x[1] * v0)
        a, u, v = R_turn.apply(a0), R_turn.apply(u0), R_turn.apply(v0)
        p = np.cos(x[2]) * u + np.sin(x[2]) * v
        return a, p, x[3:].reshape(-1, 3)

    def residuals(x):
        a, p, X = unpack(x)
        Rs = Rotation.from_rotvec(all_delta[:, None] * a[None]).as_matrix()
        return _reprojection(Rs, X[track_of], p, all_uv, focal)

    n = len(uv)
    row_track = np.repeat(track_of, 2)  # residual rows: (u, v) per observation
    x0 = np.concatenate([[0.0, 0.0, theta0], X0.ravel()])
    # The exact trust-region solver on the small dense matrix converges in a few steps (lsmr, scipy's
    # choice for a sparse pattern, takes inexact steps that crawl along the axis-depth valley).
    result = least_squares(residuals, x0, jac=lambda x: _jacobian(residuals, x, row_track),
                           tr_solver="exact", loss="cauchy", f_scale=config.loss_scale_px, x_scale="jac",
                           max_nfev=100)
    a, p, X = unpack(result.x)
    r = result.fun.reshape(-1, 2)
    track_rms = np.array([np.sqrt(np.mean(np.sum(r[starts[t]:starts[t + 1]] ** 2, axis=1)))
                          for t in range(n)])
    # Covariance of the axis angles (x[0], x[1]) from the Schur complement of the Gauss-Newton normal
    # matrix, with the residuals' robust scale.
    axis_std = _axis_std(np.asarray(result.jac), n, result.fun)
    return a, p, X, track_rms, axis_std


def _jacobian(residuals, x: FloatArray, row_track: NDArray[np.int64]) -> FloatArray:
    """Forward-difference Jacobian (R, 3 + 3 T) of the residuals at x.

    The 3 shared columns one by one, then each of the 3 per-track columns of every track at once
    (tracks touch disjoint rows): 6 evaluations whatever the number of tracks.
    """
    f0 = residuals(x)
    J = np.zeros((f0.size, x.size))
    rows = np.arange(f0.size)
    n_tracks = (x.size - 3) // 3
    for c in range(3):
        step = 1e-7 * max(1.0, abs(x[c]))
        xp = x.copy()
        xp[c] += step
        J[:, c] = (residuals(xp) - f0) / step
    for c in range(3):
        cols = 3 + 3 * np.arange(n_tracks) + c
        steps = 1e-7 * np.maximum(1.0, np.abs(x[cols]))
        xp = x.copy()
        xp[cols] += steps
        J[rows, cols[row_track]] = (residuals(xp) - f0) / steps[row_track]
    return J


def _axis_std(J, n_tracks: int, fun: FloatArray) -> float:
    """Largest 1-sigma of the two axis angles: Schur complement over the per-track points."""
    G = J[:, :3]
    H_gg = G.T @ G
    S = H_gg.copy()
    for t in range(n_tracks):
        cols = slice(3 + 3 * t, 6 + 3 * t)
        B = J[:, cols]
        rows = np.flatnonzero(np.any(B != 0, axis=1))
        Bt, Gt = B[rows], G[rows]
        H_pp = Bt.T @ Bt
        H_gp = Gt.T @ Bt
        try:
            S -= H_gp @ np.linalg.solve(H_pp + 1e-12 * np.eye(3), H_gp.T)
        except np.linalg.LinAlgError:
            return float("inf")
    sigma2 = max(float(np.median(fun ** 2) / 0.455), 1e-4)  # robust per-coordinate variance, px^2
    try:
        cov = np.linalg.inv(S) * sigma2
    except np.linalg.LinAlgError:
        return float("inf")
    d = np.diag(cov)[:2]
    return float(np.sqrt(np.max(d))) if np.all(d > 0) else float("inf")


def fit_rigid_axis(uv: list[FloatArray], deltas: list[FloatArray], focal: float,
                   config: RigidAxisConfig | None = None,
                   starts: list[tuple[FloatArray, FloatArray]] | None = None) -> RigidAxisFit:
    """Fit one rotation by known angles about an unknown line to all tracks of a motion.

    Args:
        uv: L tracks, each (n_i, 2) float64 normalized camera coordinates (undistorted).
        deltas: L arrays (n_i,) float64, rad: the joint's turn from the motion's start in each frame.
        focal: mean focal length, px (residuals and thresholds are in px).
        config: thresholds; ``RigidAxisConfig()`` if None.
        starts: more starting guesses (axis (3,) unit, a point of the axis (3,)), e.g. the conic
            front end's; the fit keeps whichever start ends with the lowest truncated cost.

    Returns:
        The axis, the axis point at unit distance, per-track residuals and inliers.

    Raises:
        DegenerateMotionError: too few tracks, no frame pair shared by enough of them, too few tracks
            moving rigidly together, or an axis direction the tracks do not fix.
    """
    config = config or RigidAxisConfig()
    if len(uv) != len(deltas):
        raise InvalidInputError(f"{len(uv)} tracks but {len(deltas)} delta arrays")
    L = len(uv)
    if L < config.min_tracks:
        raise DegenerateMotionError(f"rigid front end: {L} tracks (need {config.min_tracks})")
    # The fit: tracks spread over the list (not the longest: silhouette points that slide live long),
    # each subsampled evenly; every track is checked against the fit after.
    fit_set = sorted(set(np.linspace(0, L - 1, min(L, config.max_fit_tracks)).round().astype(int).tolist()))
    picks = [np.unique(np.linspace(0, len(deltas[t]) - 1, min(len(deltas[t]), config.max_fit_frames)).round()
                       .astype(int)) for t in fit_set]
    all_uv, all_deltas = uv, deltas
    uv = [all_uv[t][k] for t, k in zip(fit_set, picks, strict=True)]
    deltas = [all_deltas[t][k] for t, k in zip(fit_set, picks, strict=True)]
    n_fit = len(fit_set)
    angles, frames = _frame_table(deltas)
    guesses = []
    for a, p in starts or []:
        a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
        p = np.asarray(p, dtype=np.float64) - a * (a @ p)
        if np.linalg.norm(p) > 1e-9:
            guesses.append((a, p / np.linalg.norm(p)))
    starts = guesses + _relative_pose(uv, frames, angles, focal, config)
    if not starts:
        raise DegenerateMotionError(
            f"rigid front end: no two frames {config.min_pair_angle} rad apart share "
            f"{max(config.min_tracks, 8)} tracks")
    best = None
    for a0, p0 in starts:
        keep = np.ones(n_fit, dtype=bool)
        for _ in range(3):  # fit, drop the inconsistent tracks, refit
            idx = np.flatnonzero(keep)
            X0 = np.array([_triangulate(uv[t], deltas[t], a0, p0) for t in idx])
            a, p, X, rms, axis_std = _refine([uv[t] for t in idx], [deltas[t] for t in idx], a0, p0, X0,
                                             focal, config)
            if np.median(X[:, 2]) < 0:  # negating p and every point projects the same: keep them in front
                p = -p
            track_rms = np.full(n_fit, np.inf)
            track_rms[idx] = rms
            new_keep = track_rms <= config.max_track_rms_px
            a0, p0 = a, p
            if new_keep.sum() < config.min_tracks or np.array_equal(new_keep, keep):
                keep = new_keep
                break
            keep = new_keep
        # Compare starts by a truncated cost over every track (a dropped track costs the threshold).
        cost = float(np.sum(np.minimum(track_rms, config.max_track_rms_px) ** 2))
        if best is None or cost < best[0]:
            best = (cost, a0, p0, axis_std, track_rms, keep)
    _, a, p, axis_std, _, _ = best
    track_rms = np.array([_track_rms(u, d, a, p, focal) for u, d in zip(all_uv, all_deltas, strict=True)])
    keep = track_rms <= config.max_track_rms_px
    n_in, n_need = int(keep.sum()), max(config.min_tracks, int(np.ceil(config.min_inlier_fraction * L)))
    if n_in < n_need:
        raise DegenerateMotionError(f"rigid front end: only {n_in} of {L} tracks move rigidly together within "
                                    f"{config.max_track_rms_px} px (need {n_need})")
    rms_in = float(np.sqrt(np.mean(track_rms[keep] ** 2)))
    if not axis_std <= config.max_axis_std:
        raise DegenerateMotionError(
            f"rigid front end: the tracks do not fix the axis (1-sigma {axis_std:.3f} rad > {config.max_axis_std})")
    return RigidAxisFit(a, p, axis_std, track_rms, keep, rms_in)


def rigid_axis_of_motion(obs: MotionObservation, intrinsics: CameraIntrinsics,
                         config: RigidAxisConfig | None = None,
                         starts: list[tuple[FloatArray, FloatArray]] | None = None) -> RigidAxisFit:
    """``fit_rigid_axis`` on a motion's tracks in pixels (undistorted through the intrinsics)."""
    uv = [normalized_from_pixels(t.pixels, intrinsics) for t in obs.tracks]
    return fit_rigid_axis(uv, [t.delta for t in obs.tracks], float(np.mean(intrinsics.focal)), config, starts)


def geometry_from_rigid_fit(fit: RigidAxisFit) -> MotionGeometry:
    """The fit as the stage-one geometry the linear calibration takes (axis, reference ray, plane)."""
    reference = fit.point_cam / np.linalg.norm(fit.point_cam)
    normal = np.cross(reference, fit.axis_cam)
    return MotionGeometry(axis_cam=fit.axis_cam, reference_cam=reference,
                          plane_normal=normal / np.linalg.norm(normal), track_inliers=fit.track_inliers,
                          score=fit.rms_px ** 2, ambiguity=float("inf"), rms_px=fit.rms_px)
