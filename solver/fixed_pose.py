"""Reprojection residuals at a fixed ``T_camera_base``: each track's point fitted alone (``arc-calib verify``).

With the pose fixed the bundle adjustment (``solver.refinement``) falls apart into one small problem per
track: its point p0 (base frame, start configuration) is the only unknown. ``fit_points`` starts from the
closed-form triangulation (``solver.refinement.triangulate_tracks``) and minimizes each track's pixel
error with a few damped Gauss-Newton steps (3 x 3 normal equations per track, all tracks at once). What
is left, ``track_rms_px``, says how well the pose explains the tracks: at the pose the tracks were
calibrated from (or the true one) a track on the moving link fits to its noise, while a pose that is off
bends every predicted arc away from the observed one by an amount the point cannot absorb.

Notation as in ``triangulate_tracks``: with y = p0 - d_b, M_k = R Rot_k and c = R d_b + t, the camera
point at frame k is M_k y + c.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import check_transform
from solver.refinement import TrackSet, track_camera_points, track_pixel_residuals, triangulate_tracks

#: Points nearer the camera than this (m) at any frame are not fitted (``FixedPoseFit.ok`` False).
MIN_DEPTH_M = 0.01


@dataclass(frozen=True)
class FixedPoseFit:
    """The tracks' points fitted at a fixed pose.

    Attributes:
        points: (T, 3) float64, m: each track's point p0 (base frame, start configuration); NaN where not ok.
        residuals: (P, 2) float64, px: every observation's reprojection error (NaN for tracks not ok).
        track_rms_px: (T,) float64, px: each track's RMS error per coordinate (NaN where not ok).
        ok: (T,) bool: the track was triangulated and stays in front of the camera.
    """

    points: FloatArray
    residuals: FloatArray
    track_rms_px: FloatArray
    ok: NDArray[np.bool_]


def _track_cost(tracks: TrackSet, r: FloatArray) -> FloatArray:
    """(T,) px^2: each track's summed squared residual of r (P, 2) px."""
    return np.bincount(tracks.track, weights=np.sum(r**2, axis=1), minlength=tracks.n_tracks)


def fit_points(tracks: TrackSet, T_camera_base: FloatArray, iterations: int = 15) -> FixedPoseFit:
    """Fit every track's point with the pose held at ``T_camera_base``; the residuals that remain.

    Args:
        tracks: the observations (``solver.refinement.build_track_set``: normalized coordinates, the turn
            of every frame, each track's joint axis point), as the bundle adjustment takes them.
        T_camera_base: (4, 4) float64, metres: the pose to test.
        iterations: most Levenberg-Marquardt steps per track (each track stops when its step no longer
            lowers its cost by 1e-10 relative).

    Returns:
        The points, residuals and per-track RMS (px, per coordinate, as ``RefinementResult.rms_px``).

    Raises:
        InvalidInputError: T_camera_base is not a finite rigid transform, or iterations < 1.
    """
    T_camera_base = check_transform(np.asarray(T_camera_base, dtype=np.float64), "T_camera_base")
    if iterations < 1:
        raise InvalidInputError(f"iterations must be >= 1, got {iterations}")
    n = tracks.n_tracks
    points, ok = triangulate_tracks(tracks, T_camera_base)
    y = points - tracks.pivot
    pc, M = track_camera_points(tracks, T_camera_base, y)
    ok &= np.bincount(tracks.track, weights=(pc[:, 2] <= MIN_DEPTH_M).astype(float), minlength=n) == 0
    r = track_pixel_residuals(tracks, pc)
    cost = _track_cost(tracks, r)
    damping = np.full(n, 1e-3)
    active = ok.copy()
    counts = np.bincount(tracks.track, minlength=n)
    for _ in range(iterations):
        if not active.any():
            break
        z = pc[:, 2]
        D = np.zeros((len(z), 2, 3))  # d pixel / d camera point
        D[:, 0, 0] = tracks.focal[0] / z
        D[:, 1, 1] = tracks.focal[1] / z
        D[:, 0, 2] = -tracks.focal[0] * pc[:, 0] / z**2
        D[:, 1, 2] = -tracks.focal[1] * pc[:, 1] / z**2
        J = np.matmul(D, M)  # (P, 2, 3): d residual / d y
        JtJ = np.zeros((n, 3, 3))
        Jtr = np.zeros((n, 3))
        np.add.at(JtJ, tracks.track, np.einsum("pki,pkj->pij", J, J))
        np.add.at(Jtr, tracks.track, np.einsum("pki,pk->pi", J, r))
        diag = np.einsum("tii->ti", JtJ)
        A = JtJ + (damping[:, None] * np.maximum(diag, 1e-12))[:, :, None] * np.eye(3)
        A[~active] = np.eye(3)
        step = -np.linalg.solve(A, Jtr[..., None])[..., 0]
        step[~active] = 0.0
        y_try = y + step
        pc_try, _ = track_camera_points(tracks, T_camera_base, y_try)
        front = np.bincount(tracks.track, weights=(pc_try[:, 2] <= MIN_DEPTH_M).astype(float), minlength=n) == 0
        r_try = track_pixel_residuals(tracks, np.where(pc_try[:, 2:] > MIN_DEPTH_M, pc_try, pc))
        cost_try = _track_cost(tracks, r_try)
        better = active & front & (cost_try < cost)
        converged = better & (cost - cost_try <= 1e-10 * np.maximum(cost, 1e-300))
        y[better] = y_try[better]
        keep_obs = better[tracks.track]
        pc[keep_obs], r[keep_obs] = pc_try[keep_obs], r_try[keep_obs]
        cost[better] = cost_try[better]
        damping = np.where(better, damping / 10, damping * 10)
        active &= ~converged & (damping < 1e8)
    rms = np.sqrt(cost / np.maximum(counts, 1) / 2)
    rms[~ok] = np.nan
    r[~ok[tracks.track]] = np.nan
    points = y + tracks.pivot
    points[~ok] = np.nan
    return FixedPoseFit(points, r, rms, ok)


__all__ = ["MIN_DEPTH_M", "FixedPoseFit", "fit_points"]
