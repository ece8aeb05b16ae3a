"""A motion's axis from the rigid motion of its tracks (ours; the issue's "relative-pose front end").

One joint turns by a known delta, so every point on the moving links moves as
``X(delta) = R(a, delta) (X0 - p) + p`` in the camera frame: a rotation by the *known* angle about an
unknown line (direction ``a``, point ``p``). This module fits that model to all tracks of one motion at
once, starting from given lines, an exhaustive search over axis directions (``_grid_starts``) and the
relative pose of the two frames that most tracks share (OpenCV's essential matrix with RANSAC and
``recoverPose``), then refining ``a``, ``p`` and every track's point by robust least squares over all frames.
Only the line's distance from the camera is unknown (the scene's scale), so ``p`` is fixed to unit distance.

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

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray, evenly_spaced
from solver.camera import normalized_from_pixels
from solver.errors import DegenerateMotionError, InvalidInputError, NonRigidTracksError
from solver.frames import skew
from solver.motion import MotionGeometry
from solver.observations import CameraIntrinsics, MotionObservation

BoolArray = NDArray[np.bool_]
#: Starting lines of ``fit_rigid_axis``: (axis (3,) unit, a point of it (3,)) pairs, or a function giving them.
Starts = list[tuple[FloatArray, FloatArray]] | Callable[[], list[tuple[FloatArray, FloatArray]]]


@dataclass(frozen=True)
class RigidAxisConfig:
    """Settings of ``fit_rigid_axis``.

    Attributes:
        min_tracks: fewest tracks, and fewest shared by the two frames of the relative pose; count.
        min_pair_angle: rad; the two frames of the relative pose differ by at least this joint turn.
        ransac_px: px; the essential matrix's RANSAC threshold.
        max_track_rms_px: px; a track whose RMS residual under the fitted rigid motion exceeds this
            (or ``noise_factor`` times the tracks' typical RMS, if larger) is inconsistent (it slides or
            drifted) and is dropped, then the fit is repeated.
        noise_factor: the threshold follows the tracks' noise: this many times the ``noise_quantile``
            of the tracks' RMS residuals (a low quantile, which the consistent tracks set even when most
            slide), capped by the tracks' own jitter (``rms_threshold``, ``track_noise_px``); 0 (the
            default) = the fixed ``max_track_rms_px``. With 2, on synthetic Panda motions at 1 px noise
            the rigid front end gives an axis within 3 degrees on 20 of 30 motions instead of 0
            (``scripts/bench_front_ends.py``), but on realistic Panda episodes (3 poses, 1080p) one run
            in three declared convergence with its true error over 3 times its 1-sigma (none with the
            fixed threshold), so it is off until the tracks it admits are understood.
        noise_quantile: see ``noise_factor``; in (0, 1).
        loss_scale_px: px; scale of the Cauchy loss of the refinement.
        max_axis_std: rad; the fitted axis direction's 1-sigma must be below this, else the motion is
            degenerate for this front end.
        min_inlier_fraction: fewest tracks, as a fraction, that must move rigidly together.
        max_fit_tracks: the fit uses at most this many tracks (evenly spread over the list); every
            track is then checked against it; count.
        max_fit_frames: frames per track the fit uses (evenly spaced); count.
        enough_inlier_fraction: once a start's fit keeps at least this fraction of the fit tracks,
            the remaining starts are not tried (no other rigid motion can explain more of them).
        grid_directions: axis directions of the exhaustive start search (``_grid_starts``: evenly
            over the sphere, about 4.5 degrees apart at 2000); count, 0 = no grid search.
        grid_starts: most starts the grid search hands to the fit (best first, 15 degrees apart); count.
        relative_pose_if_needed: the relative-pose starts (``_relative_pose``: essential matrices, each costing
            a RANSAC) are tried only when no fit from the earlier starts (the given ones and the grid search's)
            keeps ``min_inlier_fraction`` (and ``min_tracks``) of the fit tracks; False (the default): whenever
            the search runs. On the 10 captured realistic episodes of issue 18 it cut the rigid front end's CPU
            from 2.23 to 1.57 s per episode (median; add_motion 3.60 -> 2.93 s) but changed 6 motions' fits:
            1280x720 Panda pose 1 ended at 1.6e-3 rad / 20.3 mm instead of 9.6e-4 / 17.5 mm at 10 motions
            and with a 1-sigma of 7.4 instead of 4.8 mm at 25, 1920x1080 pose 2 at 4.77e-4 instead of 4.60e-4
            rad at 25 (the same with seeds 0 and 1): a relative pose alone reached the chosen fit in 2 of 82
            searches. Off until such a start's value is judged on more episodes.
        predicted_angle: rad; a predicted start (``fit_rigid_axis``'s ``predicted``: the axis a known camera
            pose gives) is taken, and no other start tried, when its fit ends within this angle of the
            prediction and keeps at least ``min_inlier_fraction`` (and ``min_tracks``) of the fit tracks.
        polish: the chosen fit is fitted once more from where it ended with the variables unscaled
            (``_refine``'s ``unit_scale``) and that fit kept when its truncated cost is lower. The Jacobian
            scaling can hold the line where it starts when most tracks slide: on an as-shipped iiwa 720p
            sweep (pose 4 seed 1, motion 5) a start 4 degrees off the true axis ended exactly there, as
            scipy's ``least_squares`` with ``x_scale="jac"`` does, while unscaled it reached a lower cost
            1.6 degrees off. Off: replayed on 43 captured runs (``docs/realistic-imaging.md``, "Stop 62") it
            gave one more as-shipped iiwa 720p run a pose by motion 5 (23 of 30) but put a realistic iiwa
            720p run's poses at motions 3-5 32-55 mm off instead of 1.3-2.3 mm (a motion's axis 4.1 degrees
            off instead of 1.2, at a truncated cost 0.4 % lower); with a margin of half a track's cost, neither.
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
    enough_inlier_fraction: float = 0.9
    grid_directions: int = 2000
    grid_starts: int = 3
    noise_factor: float = 0.0
    noise_quantile: float = 0.25
    predicted_angle: float = 0.05
    relative_pose_if_needed: bool = False
    polish: bool = False

    def __post_init__(self) -> None:
        if self.min_tracks < 5:
            raise InvalidInputError("RigidAxisConfig: min_tracks must be >= 5 (the essential matrix needs 5)")
        if not (self.min_pair_angle > 0 and self.ransac_px > 0 and self.max_track_rms_px > 0
                and self.loss_scale_px > 0 and self.max_axis_std > 0 and 0 < self.min_inlier_fraction <= 1
                and self.max_fit_tracks >= self.min_tracks and self.max_fit_frames >= 3
                and 0 < self.enough_inlier_fraction <= 1 and self.grid_directions >= 0 and self.grid_starts >= 1
                and self.noise_factor >= 0 and 0 < self.noise_quantile < 1 and self.predicted_angle > 0):
            raise InvalidInputError("RigidAxisConfig: angles, thresholds and scales must be > 0, min_inlier_fraction "
                                    "and enough_inlier_fraction in (0, 1], max_fit_tracks >= min_tracks, "
                                    "max_fit_frames >= 3, grid_directions >= 0, grid_starts >= 1, noise_factor >= 0, "
                                    "noise_quantile in (0, 1), predicted_angle > 0")


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
        from_prediction: True when the fit came from the predicted start alone (no search ran).
    """

    axis_cam: FloatArray
    point_cam: FloatArray
    axis_std: float
    track_rms_px: FloatArray
    track_inliers: BoolArray
    rms_px: float
    from_prediction: bool = False


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


def sphere_directions(n: int) -> FloatArray:
    """Unit vectors (n, 3), n of them, spread evenly over the sphere (the golden-angle spiral)."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + np.sqrt(5.0)) * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _grid_costs(x: FloatArray, y: FloatArray, theta: FloatArray, directions: FloatArray,
                focal: float, config: RigidAxisConfig) -> tuple[FloatArray, FloatArray]:
    """Each trial axis's best truncated Sampson cost (D,) (normalized units^2) and its proposal p (D, 3).

    Args:
        x: (L, 3) first rays (u, v, 1) of the tracks, normalized camera coordinates.
        y: (L, 3) last rays likewise.
        theta: (L,) rad, each track's joint turn from its first to its last frame.
        directions: (D, 3) unit trial axes.
        focal: mean focal length, px.
        config: ``ransac_px``, the truncation of each track's Sampson distance, px.

    For axis ``a`` and track ``l`` (rotation R_l by theta_l about a, M_l = I - R_l) the epipolar
    constraint of a proposal p is ``t . v_l = p . g_l`` with t = M_l p, v_l = R_l x_l x y_l,
    g_l = M_l^T v_l, and the Sampson denominator ``|(t x R_l x_l)_xy|^2 + |(R_l^T (t x y_l))_xy|^2``
    is the quadratic form p^T G_l p, G_l = E_l^T E_l + F_l^T F_l with E_l = ([R_l x_l]x M_l)_xy and
    F_l = (R_l^T [y_l]x M_l)_xy: every (proposal, track) pair costs two 3- and 6-term dot products.
    """
    threshold = (config.ransac_px / focal) ** 2
    costs = np.empty(directions.shape[0])
    points = np.empty_like(directions)
    c, s = np.cos(theta)[None, :, None, None], np.sin(theta)[None, :, None, None]
    iu, ju = np.triu_indices(3)
    for lo in range(0, directions.shape[0], _GRID_CHUNK):
        a = directions[lo:lo + _GRID_CHUNK]  # (A, 3)
        R = c * np.eye(3) + s * skew(a)[:, None] + (1.0 - c) * np.einsum("ai,aj->aij", a, a)[:, None]  # (A, L, 3, 3)
        M = np.eye(3) - R
        Rx = np.einsum("alij,lj->ali", R, x)
        v = np.cross(Rx, y)  # the constraint t . v = 0 of each track, t = (I - R) p
        g = np.einsum("alji,alj->ali", M, v)  # (I - R)^T v: p . g = 0
        p = np.cross(a[:, None, :], g)  # (A, L, 3) each track's proposal, perpendicular to a and g
        p /= np.maximum(np.linalg.norm(p, axis=2, keepdims=True), 1e-300)
        EF = np.concatenate([skew(Rx)[..., :2, :] @ M,  # E (A, L, 2, 3) over F
                             np.swapaxes(R[..., :2], -1, -2) @ (skew(y) @ M)], axis=-2)
        # p^T G p as 6 products: G's diagonal once, its off-diagonal pairs twice (one column pair per product:
        # a third of the CPU of gathering the pairs' columns first)
        G6 = np.stack([np.einsum("...k,...k->...", EF[..., i], EF[..., j]) * (1.0 if i == j else 2.0)
                       for i, j in zip(iu, ju, strict=True)], axis=-1)
        pp = p[..., iu] * p[..., ju]  # (A, L proposals, 6)
        num = p @ np.swapaxes(g, 1, 2)  # (A, L proposals, L tracks)
        den = pp @ np.swapaxes(G6, 1, 2)
        sampson = np.square(num, out=num)  # (in place: the chunk's largest arrays)
        sampson /= np.maximum(den, 1e-300, out=den)
        cost = np.sum(np.minimum(sampson, threshold, out=sampson), axis=2)  # (A, L proposals)
        best = np.argmin(cost, axis=1)
        pick = np.arange(a.shape[0])
        costs[lo:lo + _GRID_CHUNK] = cost[pick, best]
        points[lo:lo + _GRID_CHUNK] = p[pick, best]
    return costs, points


#: Trial axes per batch of ``_grid_costs`` (memory: about 100 * chunk * L^2 bytes). At 128 (40 tracks: 1.6 MB
#: per (A, L, L) array, within a 4 MB L2 cache) the search took 17 % less CPU than at 256 on 30 captured
#: realistic motions (64: the same, 32: 10 % less); every trial axis's arithmetic is the same at any chunk.
_GRID_CHUNK = 128


def _grid_starts(uv: list[FloatArray], deltas: list[FloatArray], focal: float,
                 config: RigidAxisConfig) -> list[tuple[FloatArray, FloatArray]]:
    """Starting (a, p) pairs from an exhaustive search over axis directions (best first).

    The relative pose of two frames needs tracks that both frames share; on realistic images the tracks
    are short and half of them slide, so often no frame pair has enough good ones. This search uses each
    track's own first and last frame instead. For a trial axis ``a`` the rotation of every track between
    them is known (the joint's turn), and the rigid motion's translation ``(I - R) p`` with ``p``
    perpendicular to ``a`` leaves one unknown, ``p``'s direction in that plane, which one track's
    epipolar constraint fixes. So every track proposes a ``p``; each proposal is scored by the Sampson
    distances (px, truncated at ``config.ransac_px``) of all tracks (``_grid_costs``), and the trial
    axis keeps its best. The axes with the lowest truncated cost, at least 15 degrees apart, are the starts.
    """
    turn = np.array([d[-1] - d[0] for d in deltas])
    use = np.flatnonzero(np.abs(turn) >= config.min_pair_angle)
    if config.grid_directions == 0 or use.shape[0] < config.min_tracks:
        return []
    x = np.column_stack([np.array([uv[t][0] for t in use]), np.ones(use.shape[0])])  # (L, 3) first rays
    y = np.column_stack([np.array([uv[t][-1] for t in use]), np.ones(use.shape[0])])  # (L, 3) last rays
    directions = sphere_directions(config.grid_directions)
    costs, points = _grid_costs(x, y, turn[use], directions, focal, config)
    starts: list[tuple[FloatArray, FloatArray]] = []
    for k in np.argsort(costs):
        if not any(directions[k] @ a > np.cos(np.radians(15.0)) for a, _ in starts):
            starts.append((directions[k], points[k]))
        if len(starts) == config.grid_starts:
            break
    return starts


@dataclass(frozen=True)
class _Tracks:
    """The frames of several tracks, concatenated track after track.

    Attributes:
        uv: (N, 2) normalized camera coordinates of every frame.
        delta: (N,) rad, the joint's turn in every frame.
        track: (N,) the track of every frame (0..T-1, non-decreasing).
        first: (T,) index of every track's first frame in the arrays above.
        turns: (N, 3) cos(delta), sin(delta), 1 of every frame (``_rotations_of``'s coefficients).
    """

    uv: FloatArray
    delta: FloatArray
    track: NDArray[np.int64]
    first: NDArray[np.int64]
    turns: FloatArray

    @staticmethod
    def of(uv: list[FloatArray], deltas: list[FloatArray]) -> _Tracks:
        n_obs = np.array([len(d) for d in deltas], dtype=np.int64)
        delta = np.concatenate(deltas)
        return _Tracks(np.concatenate(uv), delta, np.repeat(np.arange(len(uv)), n_obs),
                       np.concatenate([[0], np.cumsum(n_obs)[:-1]]).astype(np.int64),
                       np.column_stack([np.cos(delta), np.sin(delta), np.ones_like(delta)]))

    def rotations(self, a: FloatArray) -> FloatArray:
        """Every frame's rotation (N, 3, 3) by its delta about the unit axis a (3,)."""
        return _rotations_of(self.turns, a)

    def per_track(self, values: FloatArray) -> FloatArray:
        """Sums of per-frame values (N, ...) over each track's frames: (T, ...)."""
        return np.add.reduceat(values, self.first, axis=0)


#: The identity (3, 3), read-only.
_EYE3 = np.eye(3)
_EYE3.flags.writeable = False


def _rotations_of(turns: FloatArray, a: FloatArray) -> FloatArray:
    """Rotations (N, 3, 3) about the unit axis a (3,) from (cos, sin, 1) of their angles, turns (N, 3).

    Rodrigues as one product: R = cos (I - a a^T) + sin [a]x + a a^T (its three (3, 3) terms written
    out on Python floats: one call per trial step).
    """
    x, y, z = a.tolist()
    xx, xy, xz, yy, yz, zz = x * x, x * y, x * z, y * y, y * z, z * z
    terms = np.array([[1.0 - xx, -xy, -xz, -xy, 1.0 - yy, -yz, -xz, -yz, 1.0 - zz],
                      [0.0, -z, y, z, 0.0, -x, -y, x, 0.0],
                      [xx, xy, xz, xy, yy, yz, xz, yz, zz]])
    return (turns @ terms).reshape(-1, 3, 3)


def _triangulate(tracks: _Tracks, Rs: FloatArray, p: FloatArray) -> FloatArray:
    """X0 (T, 3) of every track under the rotations Rs (N, 3, 3) about p, by linear least squares.

    Each frame's ray x gives x cross (R X0 + (I - R) p) = 0, linear in X0; the normal equations of
    each track are solved on their own.
    """
    cross = skew(np.column_stack([tracks.uv, np.ones(len(tracks.uv))]))
    A = cross @ Rs  # (N, 3, 3)
    b = -np.einsum("nij,nj->ni", cross, p - np.einsum("nij,j->ni", Rs, p))
    AtA = tracks.per_track(np.einsum("nki,nkj->nij", A, A))
    Atb = tracks.per_track(np.einsum("nki,nk->ni", A, b))
    return np.linalg.solve(AtA + 1e-12 * np.eye(3), Atb[..., None])[..., 0]


def _residuals(tracks: _Tracks, Rs: FloatArray, p: FloatArray, X0: FloatArray, focal: float,
               jacobian: bool = False):
    """Reprojection residuals (N, 2) px of the track points X0 (T, 3) turned by Rs (N, 3, 3) about p (3,).

    With ``jacobian``, also their derivatives (N, 2, 3) with respect to a small rotation w of the
    line's frame (a <- exp(w) a, p <- exp(w) p) and (N, 2, 3) with respect to the frame's track point.
    """
    projection = _project(tracks, Rs, p, X0, focal)
    if not jacobian:
        return projection.r
    return projection.r, *_jacobians(projection, focal)


@dataclass(frozen=True)
class _Projection:
    """The track points turned into every frame and projected (``_project``).

    Attributes:
        Rs: (N, 3, 3) the frames' rotations; Xt: (N, 3) each frame's track point before its turn;
        X: (N, 3) after it, camera frame; z: (N,) its depth (kept off zero); r: (N, 2) px residuals.
    """

    Rs: FloatArray
    Xt: FloatArray
    X: FloatArray
    z: FloatArray
    r: FloatArray


def _project(tracks: _Tracks, Rs: FloatArray, p: FloatArray, X0: FloatArray, focal: float) -> _Projection:
    """``_residuals`` without derivatives, keeping what they need."""
    Xt = X0[tracks.track]
    X = np.einsum("nij,nj->ni", Rs, Xt - p) + p
    z = np.where(np.abs(X[:, 2]) < 1e-6, 1e-6, X[:, 2])
    return _Projection(Rs, Xt, X, z, (X[:, :2] / z[:, None] - tracks.uv) * focal)


def _jacobians(projection: _Projection, focal: float) -> tuple[FloatArray, FloatArray]:
    """``_residuals``'s derivatives (N, 2, 3) and (N, 2, 3) at a projection."""
    Rs, Xt, X, z = projection.Rs, projection.Xt, projection.X, projection.z
    # d(pixel)/dX, then dX/dX0 = R and dX/dw = R [X0]x - [X]x (R conjugated by exp(w), p turned by it).
    P = np.zeros((len(z), 2, 3))
    P[:, 0, 0] = P[:, 1, 1] = focal / z
    P[:, :, 2] = -focal * X[:, :2] / z[:, None] ** 2
    J_point = P @ Rs
    J_frame = J_point @ skew(Xt) - P @ skew(X)
    return J_frame, J_point


def _normal_blocks(tracks: _Tracks, w: FloatArray, wr: FloatArray, J_frame: FloatArray, J_point: FloatArray):
    """Blocks of the weighted normal matrix J^T W J (weights w (N, 2)) and the gradient J^T wr (wr (N, 2)).

    Returns H_gg (3, 3), H_gp (T, 3, 3), H_pp (T, 3, 3), g_g (3,), g_p (T, 3): g for the frame's
    rotation, p for each track's point.
    """
    WJ = w[..., None] * np.concatenate([J_frame, J_point], axis=2)  # (N, 2, 6)
    H_gg = WJ[..., :3].reshape(-1, 3).T @ J_frame.reshape(-1, 3)
    H_xp = tracks.per_track(np.swapaxes(WJ, 1, 2) @ J_point)  # (T, 6, 3): H_gp over H_pp, one product and sum
    g_g = J_frame.reshape(-1, 3).T @ wr.ravel()
    g_p = tracks.per_track((np.swapaxes(J_point, 1, 2) @ wr[..., None])[..., 0])
    return H_gg, H_xp[:, :3], H_xp[:, 3:], g_g, g_p


def _hessian_weights(z: FloatArray) -> FloatArray:
    """Gauss-Newton weights of the Cauchy loss rho(z) = log(1 + z) at squared scaled residuals z (N, 2).

    rho' + 2 z rho'' (Triggs' correction, as scipy's least_squares uses): residuals beyond the
    loss's scale (z > 1) weigh (almost) nothing in the normal matrix, though they pull the gradient.
    """
    return np.maximum((1.0 - z) / (1.0 + z) ** 2, np.finfo(float).eps)


def _damping_scale(H: FloatArray) -> FloatArray:
    """Marquardt's damping scale of normal matrices H (..., 3, 3): their diagonals (..., 3), floored.

    The floor (a 1e-12 fraction of the largest) keeps the damped matrices positive definite when a
    direction is unobserved (a point drifting to infinity along its ray).
    """
    d = np.diagonal(H, axis1=-2, axis2=-1)
    return np.maximum(d, 1e-12 * np.max(d, axis=-1, keepdims=True) + 1e-300)


def _turn(w: FloatArray, a: FloatArray, p: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The line's frame (a, p) turned by the small rotation vector w (3,), kept orthonormal.

    On Python floats: three-vectors, one at every trial step of ``_refine``, cost less so than as arrays.
    """
    wx, wy, wz = w.tolist()
    (ax, ay, az), (px, py, pz) = a.tolist(), p.tolist()
    angle = math.sqrt(wx * wx + wy * wy + wz * wz)
    if angle > 0:  # Rodrigues: x c + (k x x) s + k (k . x)(1 - c)
        kx, ky, kz = wx / angle, wy / angle, wz / angle
        c, s = math.cos(angle), math.sin(angle)
        ka, kp = (kx * ax + ky * ay + kz * az) * (1.0 - c), (kx * px + ky * py + kz * pz) * (1.0 - c)
        ax, ay, az = (ax * c + (ky * az - kz * ay) * s + kx * ka, ay * c + (kz * ax - kx * az) * s + ky * ka,
                      az * c + (kx * ay - ky * ax) * s + kz * ka)
        px, py, pz = (px * c + (ky * pz - kz * py) * s + kx * kp, py * c + (kz * px - kx * pz) * s + ky * kp,
                      pz * c + (kx * py - ky * px) * s + kz * kp)
    n = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / n, ay / n, az / n
    ap = ax * px + ay * py + az * pz
    px, py, pz = px - ax * ap, py - ay * ap, pz - az * ap
    n = math.sqrt(px * px + py * py + pz * pz)
    return np.array([ax, ay, az]), np.array([px / n, py / n, pz / n])


def _inverse_3x3(S: FloatArray) -> FloatArray:
    """The inverse (3, 3) of a 3 x 3 matrix S by its adjugate, on Python floats (no LAPACK call's overhead)."""
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * A + b * B + c * C
    if det == 0.0 or not math.isfinite(det):
        return np.linalg.inv(S)  # LAPACK's verdict (raises when singular)
    return np.array([[A, c * h - b * i, b * f - c * e], [B, a * i - c * g, c * d - a * f],
                     [C, b * g - a * h, a * e - b * d]]) / det


class _ArrowSystem:
    """Normal equations (H + alpha I) x = b of the shared (g, 3) and per-track (p, 3 each) unknowns.

    H is arrow-shaped: H_gg (3, 3), H_gp (T, 3, 3), H_pp (T, 3, 3) with the tracks' blocks independent.
    Each track's block is diagonalized once (H_pp = Q diag(lam) Q^T), and the per-track unknowns are
    handled in those eigenbases, all 3T at once (``y = Q^T x_p``, flattened): there the points' block is
    diagonal, so any alpha costs one 3 x 3 inverse (the Schur complement over the points), and lengths are
    the same as in the original coordinates (``to_eigen``, ``from_eigen`` convert).
    """

    def __init__(self, H_gg: FloatArray, H_gp: FloatArray, H_pp: FloatArray, n_residuals: int):
        self.H_gg = H_gg
        lam, self.Q = np.linalg.eigh(H_pp)  # (T, 3), (T, 3, 3)
        lam = np.maximum(lam, 0.0)
        self.lam = lam.ravel()  # (3T,)
        self.W = np.swapaxes(H_gp @ self.Q, 1, 2).reshape(-1, 3)  # (3T, 3): H_gp's columns in the eigenbases
        # Full rank as scipy's least_squares judges it: the least singular value of the Jacobian above
        # eps * (number of residuals) times the largest.
        inv0 = 1.0 / np.maximum(self.lam, 1e-300)
        Wi0 = self.W * inv0[:, None]
        S0 = H_gg - self.W.T @ Wi0
        # alpha = 0's factors when no eigenvalue is 0 (the Gauss-Newton step; ``factor`` would repeat them)
        self._factor0 = (inv0, Wi0, S0) if lam.min(initial=np.inf) > 0 else None
        eig_s = np.linalg.eigvalsh(S0) if np.all(np.isfinite(S0)) else np.array([-1.0])
        largest = max(float(lam.max(initial=0.0)), float(eig_s.max()))
        threshold = (np.finfo(float).eps * n_residuals) ** 2 * largest
        self.full_rank = bool(lam.min(initial=np.inf) > threshold and eig_s.min() > threshold)

    def to_eigen(self, x_p: FloatArray) -> FloatArray:
        """Per-track vectors (T, 3) in the tracks' eigenbases, flattened: (3T,)."""
        return (np.swapaxes(self.Q, 1, 2) @ x_p[..., None]).ravel()

    def from_eigen(self, y: FloatArray) -> FloatArray:
        """Flattened eigenbasis vectors (3T,) back to per-track vectors (T, 3)."""
        return (self.Q @ y.reshape(-1, 3, 1))[..., 0]

    def factor(self, alpha: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """For one alpha: 1 / (lam + alpha) (3T,), W scaled by it (3T, 3), the Schur complement's inverse (3, 3)."""
        if alpha == 0.0 and self._factor0 is not None:
            inv, Wi, S0 = self._factor0
            return inv, Wi, _inverse_3x3(S0)
        inv = 1.0 / (self.lam + alpha)
        Wi = self.W * inv[:, None]
        return inv, Wi, _inverse_3x3(self.H_gg + alpha * _EYE3 - self.W.T @ Wi)

    @staticmethod
    def solve(factors: tuple[FloatArray, FloatArray, FloatArray], b_g: FloatArray, b_y: FloatArray
              ) -> tuple[FloatArray, FloatArray]:
        """x_g (3,), y (3T,) for b_g (3,), b_y (3T,) (eigenbases), with ``factor``'s factors."""
        inv, Wi, S_inv = factors
        x_g = S_inv @ (b_g - Wi.T @ b_y)
        return x_g, inv * b_y - Wi @ x_g


class _TrustRegionModel:
    """The quadratic model 0.5 x^T H x + g^T x of one linearization, and its trust-region steps.

    The steps of every radius tried at one linearization share the Gauss-Newton step (alpha = 0), which
    does not depend on the radius: it is solved once (a rejected step's retry then costs its alpha search).
    """

    def __init__(self, system: _ArrowSystem, g_g: FloatArray, g_p: FloatArray):
        self.system, self.g_g = system, g_g
        self.g_y = system.to_eigen(g_p)
        self._gauss_newton: tuple[FloatArray, FloatArray, float, float] | None = None

    def _step_and_norm(self, a: float) -> tuple[FloatArray, FloatArray, float, float]:
        """The step (3,), (3T,) (eigenbases) for alpha = a, its length, and the length's derivative by alpha."""
        system = self.system
        factors = system.factor(a)
        x_g, x_y = system.solve(factors, -self.g_g, -self.g_y)
        norm = float(np.sqrt(x_g @ x_g + x_y @ x_y))
        q_g, q_y = system.solve(factors, x_g, x_y)
        return x_g, x_y, norm, -float(x_g @ q_g + x_y @ q_y) / norm

    def step(self, radius: float, alpha: float) -> tuple[FloatArray, FloatArray, float]:
        """The step minimizing the model within ``radius``: (3,), (3T,) (the points' part in the eigenbases), alpha.

        Of length ``radius``, or shorter (Gauss-Newton, alpha = 0); alpha is the Levenberg-Marquardt parameter.
        The variables are scaled; alpha is found by Newton's method on the step's length (More's, as
        scipy's ``solve_lsq_trust_region`` does with an SVD of the Jacobian; here through the arrow
        system, in its eigenbases), starting from the given alpha.
        """
        system, g_g, g_y = self.system, self.g_g, self.g_y
        full_rank = system.full_rank
        if full_rank:
            if self._gauss_newton is None:
                self._gauss_newton = self._step_and_norm(0.0)
            x_g, x_y, norm, phi_prime = self._gauss_newton
            phi = norm - radius
            # (the Schur complement of a nearly singular system can lose the step's accuracy: then as
            # rank deficient)
            full_rank = bool(np.isfinite(phi) and np.isfinite(phi_prime) and phi_prime < 0)
            if full_rank and phi <= 0:
                return x_g, x_y, 0.0
        alpha_upper = float(np.sqrt(g_g @ g_g + g_y @ g_y)) / radius
        alpha_lower = -phi / phi_prime if full_rank else 0.0
        if not full_rank and alpha == 0:
            alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
        for _ in range(10):
            if alpha < alpha_lower or alpha > alpha_upper:
                alpha = max(0.001 * alpha_upper, (alpha_lower * alpha_upper) ** 0.5)
            _, _, norm, phi_prime = self._step_and_norm(alpha)
            phi = norm - radius
            if phi < 0:
                alpha_upper = alpha
            ratio = phi / phi_prime
            alpha_lower = max(alpha_lower, alpha - ratio)
            alpha -= (phi + radius) * ratio / radius
            if abs(phi) < 0.01 * radius:
                break
        x_g, x_y = system.solve(system.factor(alpha), -g_g, -g_y)
        shrink = radius / float(np.sqrt(x_g @ x_g + x_y @ x_y))
        return x_g * shrink, x_y * shrink, alpha

    def decrease(self, h_g: FloatArray, h_y: FloatArray) -> float:
        """The decrease the model predicts for a step h_g (3,), h_y (3T,) (eigenbases): -(0.5 h^T H h + g^T h)."""
        system = self.system
        quadratic = h_g @ system.H_gg @ h_g + 2.0 * float(h_y @ (system.W @ h_g)) + float((system.lam * h_y) @ h_y)
        return -(0.5 * quadratic + float(h_g @ self.g_g) + float(h_y @ self.g_y))


def _refine(tracks: _Tracks, a: FloatArray, p: FloatArray, X0: FloatArray, focal: float,
            config: RigidAxisConfig, max_evaluations: int = 100, unit_scale: bool = False):
    """Robust (Cauchy) least squares over the line (a, p: 3 degrees of freedom) and every track's point.

    scipy's trust-region reflective method without bounds (``least_squares(method="trf",
    tr_solver="exact", x_scale="jac", loss="cauchy")``: Triggs' robust scaling, Jacobian-scaled
    variables, More's exact trust-region steps, its radius updates and ftol/xtol/gtol = 1e-8 tests),
    with the analytic Jacobian and the normal equations solved through the Schur complement over the
    points instead of an SVD of the dense Jacobian. The line's three unknowns: tilts of the axis about
    the start's two normals (u, v) and a turn of p about the axis. With ``unit_scale`` the variables are
    not scaled (``x_scale=1.0``: radians and metres as they are).

    Returns a (3,), p (3,), X0 (T, 3) and every track's RMS residual (T,) px.
    """
    s2 = config.loss_scale_px ** 2
    u, v = _basis(a)

    def cost(r: FloatArray) -> float:
        return 0.5 * s2 * float(np.sum(np.log1p(r ** 2 / s2)))

    def linearize(a: FloatArray, p: FloatArray, X0: FloatArray, projection: _Projection | None = None):
        # (a trial's projection at the same point gives the same residuals: not computed twice)
        projection = projection or _project(tracks, tracks.rotations(a), p, X0, focal)
        r = projection.r
        J_frame, J_point = _jacobians(projection, focal)
        z = r ** 2 / s2
        blocks = _normal_blocks(tracks, _hessian_weights(z), r / (1.0 + z),
                                (J_frame.reshape(-1, 3) @ np.column_stack([u, v, a])).reshape(-1, 2, 3), J_point)
        scale_inv = (np.sqrt(np.diag(blocks[0])), np.sqrt(np.diagonal(blocks[2], axis1=1, axis2=2)))
        return r, blocks, scale_inv

    r, blocks, (inv_g, inv_p) = linearize(a, p, X0)
    if unit_scale:
        inv_g, inv_p = np.ones_like(inv_g), np.ones_like(inv_p)
    else:
        inv_g, inv_p = np.where(inv_g == 0, 1.0, inv_g), np.where(inv_p == 0, 1.0, inv_p)
    c = cost(r)
    theta = float(np.arctan2(p @ v, p @ u))  # scipy's x: (0, 0, theta, X0), its norm in the xtol test
    radius = float(np.sqrt((theta * inv_g[2]) ** 2 + np.sum((X0 * inv_p) ** 2))) or 1.0
    alpha, n_eval, done = 0.0, 1, False
    while not done and n_eval < max_evaluations:
        H_gg, H_gp, H_pp, g_g, g_p = blocks
        if max(np.max(np.abs(g_g)), np.max(np.abs(g_p))) < 1e-8:
            break
        d_g, d_p = 1.0 / inv_g, 1.0 / inv_p  # the variables scaled by the Jacobian's column norms
        H_gg, H_gp, H_pp = (H_gg * np.outer(d_g, d_g), H_gp * d_g[None, :, None] * d_p[:, None, :],
                            H_pp * d_p[:, :, None] * d_p[:, None, :])
        g_g, g_p = g_g * d_g, g_p * d_p
        system = _ArrowSystem(H_gg, H_gp, H_pp, r.size)
        model = _TrustRegionModel(system, g_g, g_p)
        frame = np.column_stack([u, v, a])  # the line's three unknowns' directions
        reduction = -1.0
        while reduction <= 0 and n_eval < max_evaluations:
            h_g, h_y, alpha = model.step(radius, alpha)
            predicted = model.decrease(h_g, h_y)
            h_p = system.from_eigen(h_y)
            step_g, step_p = h_g * d_g, h_p * d_p
            a_new, p_new = _turn(frame @ step_g, a, p)
            X0_new = X0 + step_p
            trial = _project(tracks, tracks.rotations(a_new), p_new, X0_new, focal)
            r_new = trial.r
            n_eval += 1
            h_norm = float(np.sqrt(h_g @ h_g + h_y @ h_y))  # (the eigenbases keep lengths)
            if not np.all(np.isfinite(r_new)):
                radius = 0.25 * h_norm
                continue
            c_new = cost(r_new)
            reduction = c - c_new
            ratio = reduction / predicted if predicted > 0 else (1.0 if predicted == reduction == 0 else 0.0)
            if ratio < 0.25:
                new_radius = 0.25 * h_norm
            elif ratio > 0.75 and h_norm > 0.95 * radius:
                new_radius = 2.0 * radius
            else:
                new_radius = radius
            step_norm = float(np.sqrt(step_g @ step_g + np.sum(step_p ** 2)))
            x_norm = float(np.sqrt((theta + step_g[2]) ** 2 + np.sum(X0_new ** 2)))
            done = (reduction < 1e-8 * c and ratio > 0.25) or step_norm < 1e-8 * (1e-8 + x_norm)
            if done:
                break
            alpha *= radius / new_radius
            radius = new_radius
        if reduction > 0:
            a, p, X0, c, theta = a_new, p_new, X0_new, c_new, theta + step_g[2]
            if done or n_eval >= max_evaluations:  # the last point: only its residuals are needed
                r = r_new
                break
            r, blocks, (new_g, new_p) = linearize(a, p, X0, trial)
            if not unit_scale:
                inv_g, inv_p = np.maximum(inv_g, new_g), np.maximum(inv_p, new_p)
    track_rms = np.sqrt(tracks.per_track(np.sum(r ** 2, axis=1)) / np.diff(np.append(tracks.first, len(r))))
    return a, p, X0, track_rms


def _axis_std(tracks: _Tracks, a: FloatArray, p: FloatArray, X0: FloatArray, focal: float,
              config: RigidAxisConfig) -> float:
    """Largest 1-sigma, rad, of the axis direction's two angles at a fit, with the points marginalized.

    The Gauss-Newton normal matrix of the robust cost (Triggs' weights of the Cauchy loss, as scipy's
    least_squares reports its Jacobian), its Schur complement over the points, and the residuals'
    robust scale.
    """
    r, J_frame, J_point = _residuals(tracks, tracks.rotations(a), p, X0, focal, jacobian=True)
    H_gg, H_gp, H_pp, _, _ = _normal_blocks(tracks, _hessian_weights(r ** 2 / config.loss_scale_px ** 2), r,
                                            J_frame, J_point)
    try:
        S = H_gg - np.einsum("tij,tjk->ik", H_gp,
                             np.linalg.solve(H_pp + 1e-12 * np.eye(3), H_gp.transpose(0, 2, 1)))
        sigma2 = max(float(np.median(r ** 2) / 0.455), 1e-4)  # robust per-coordinate variance, px^2
        cov = np.linalg.inv(S) * sigma2
    except np.linalg.LinAlgError:
        return float("inf")
    # A turn w tilts the axis by w x a: its angles are w's components along two normals of a.
    normals = np.column_stack(_basis(a))
    d = np.diag(normals.T @ cov @ normals)
    return float(np.sqrt(np.max(d))) if np.all(d > 0) else float("inf")


def _track_rms(tracks: _Tracks, a: FloatArray, p: FloatArray, focal: float,
               max_iterations: int = 30) -> FloatArray:
    """RMS residual (T,) px of each track's best point under a fixed rigid motion (a, p).

    Every track's point by its own Levenberg-Marquardt from the linear triangulation, all tracks at once.
    """
    Rs = tracks.rotations(a)
    X0 = _triangulate(tracks, Rs, p)
    r, _, J = _residuals(tracks, Rs, p, X0, focal, jacobian=True)
    cost = tracks.per_track(np.sum(r ** 2, axis=1))
    damping = np.full(len(X0), 1e-3)
    active = np.ones(len(X0), dtype=bool)
    for _ in range(max_iterations):
        H = tracks.per_track(np.einsum("nki,nkj->nij", J, J))
        g = tracks.per_track(np.einsum("nki,nk->ni", J, r))
        D = _damping_scale(H)
        step = -np.linalg.solve(H + damping[:, None, None] * D[:, :, None] * np.eye(3), g[..., None])[..., 0]
        X_new = np.where(active[:, None], X0 + step, X0)
        r_new, _, J_new = _residuals(tracks, Rs, p, X_new, focal, jacobian=True)
        cost_new = tracks.per_track(np.sum(r_new ** 2, axis=1))
        better = active & (cost_new < cost)
        converged = active & (np.abs(cost - cost_new) <= 1e-10 * cost)
        active &= ~converged & (damping < 1e10)
        damping = np.where(better, np.maximum(damping / 10.0, 1e-9), damping * 10.0)
        X0 = np.where(better[:, None], X_new, X0)
        cost = np.where(better, cost_new, cost)
        keep = better[tracks.track]
        r = np.where(keep[:, None], r_new, r)
        J = np.where(keep[:, None, None], J_new, J)
        if not active.any():
            break
    return np.sqrt(cost / np.diff(np.append(tracks.first, len(r))))


def track_noise_px(uv: list[FloatArray], focal: float) -> float:
    """px: the tracks' jitter, from second differences, independent of any motion model (0: too short to tell).

    For points sampled densely along a smooth path, ``x[k+1] - 2 x[k] + x[k-1]`` is noise with variance
    6 sigma^2 per coordinate; the median over the tracks of sqrt(mean |d2|^2 / 12) estimates sigma.
    Tracks that slide smoothly (highlights, silhouettes) do not raise it, nor does a rigid-motion misfit.

    Args:
        uv: L tracks, each (n_i, 2) float64 normalized camera coordinates.
        focal: mean focal length, px.
    """
    per_track = [np.mean(np.sum(np.diff(t, n=2, axis=0) ** 2, axis=1)) / 12.0 for t in uv if len(t) >= 3]
    return float(np.sqrt(np.median(per_track)) * focal) if per_track else 0.0


def rms_threshold(track_rms: FloatArray, config: RigidAxisConfig, noise_px: float) -> float:
    """px: the largest RMS residual of a consistent track, given every track's RMS (T,) px (inf: not fitted).

    ``config.max_track_rms_px``, or if larger ``config.noise_factor`` times the ``config.noise_quantile``
    of the finite RMS values (noisier tracks) -- but never above ``_JITTER_FACTOR`` times the tracks'
    own jitter ``noise_px`` (px, ``track_noise_px``) or ``_SMOOTH_ERROR_PX``, whichever is larger, so a
    misfit that every track shares (a motion the model cannot explain, e.g. straight tracks) does not
    pass as noise.
    """
    finite = track_rms[np.isfinite(track_rms)]
    if finite.size == 0:
        return config.max_track_rms_px
    cap = max(_JITTER_FACTOR * noise_px, _SMOOTH_ERROR_PX)
    adaptive = min(config.noise_factor * float(np.quantile(finite, config.noise_quantile)), cap)
    return max(config.max_track_rms_px, adaptive)


#: ``rms_threshold`` never exceeds this many times the tracks' jitter (a consistent track's RMS is ~1.4x it) ...
_JITTER_FACTOR = 4.0
#: ... or this, px, if larger: trackers also err smoothly (a template turning under the light drifts by
#: fractions of a pixel over a sweep), which the jitter does not show.
_SMOOTH_ERROR_PX = 1.5


def _fit_from_start(uv: list[FloatArray], deltas: list[FloatArray], a: FloatArray, p: FloatArray, focal: float,
                    config: RigidAxisConfig, noise_px: float, unit_scale: bool = False
                    ) -> tuple[float, FloatArray, FloatArray, _Tracks, FloatArray, int]:
    """Refine one start: fit, drop the tracks that do not move rigidly with the others, refit (3 rounds).

    ``unit_scale``: ``_refine``'s.

    Returns the truncated cost over every track (a dropped track costs the threshold), a (3,), p (3,),
    the tracks of the last fit and their points (T, 3), and how many tracks the fit keeps.
    """
    n = len(uv)
    keep = np.ones(n, dtype=bool)
    for _ in range(3):
        idx = np.flatnonzero(keep)
        tracks = _Tracks.of([uv[t] for t in idx], [deltas[t] for t in idx])
        X0 = _triangulate(tracks, tracks.rotations(a), p)
        a, p, X, rms = _refine(tracks, a, p, X0, focal, config, unit_scale=unit_scale)
        if np.median(X[:, 2]) < 0:  # negating p and every point projects the same: keep them in front
            p, X = -p, -X
        track_rms = np.full(n, np.inf)
        track_rms[idx] = rms
        threshold = rms_threshold(track_rms, config, noise_px)
        new_keep = track_rms <= threshold
        done = new_keep.sum() < config.min_tracks or np.array_equal(new_keep, keep)
        keep = new_keep
        if done:
            break
    cost = float(np.sum(np.minimum(track_rms, threshold) ** 2))
    return cost, a, p, tracks, X, int(keep.sum())


def fit_rigid_axis(uv: list[FloatArray], deltas: list[FloatArray], focal: float,
                   config: RigidAxisConfig | None = None,
                   starts: Starts | None = None,
                   predicted: tuple[FloatArray, FloatArray] | None = None) -> RigidAxisFit:
    """Fit one rotation by known angles about an unknown line to all tracks of a motion.

    Args:
        uv: L tracks, each (n_i, 2) float64 normalized camera coordinates (undistorted).
        deltas: L arrays (n_i,) float64, rad: the joint's turn from the motion's start in each frame.
        focal: mean focal length, px (residuals and thresholds are in px).
        config: thresholds; ``RigidAxisConfig()`` if None.
        starts: more starting guesses (axis (3,) unit, a point of the axis (3,)), e.g. the conic
            front end's, tried before the relative poses; the fit keeps whichever start ends with the
            lowest truncated cost (and tries no more once one keeps ``enough_inlier_fraction``); or a
            function giving them, called only when they are tried (not when the predicted start is taken).
        predicted: the axis (3,) unit and a point of it (3,), camera frame, that a camera pose predicts
            (e.g. ``R_camera_base @ axis_base`` and ``T_camera_base @ point_base``), tried before anything
            else: when its fit stays within ``config.predicted_angle`` of it and keeps ``min_inlier_fraction``
            of the fit tracks, that fit is taken and no other start (nor the searches) is tried; else it is
            set aside and the starts above decide, as without it. The fit is still the tracks' own.

    Returns:
        The axis, the axis point at unit distance, per-track residuals and inliers.

    Raises:
        DegenerateMotionError: too few tracks, no frame pair shared by enough of them, or an axis direction the
            tracks do not fix.
        NonRigidTracksError: too few tracks moving rigidly together (its ``fit``: the best fit, when at least
            ``min_tracks`` follow it and it fixes the axis).
    """
    config = config or RigidAxisConfig()
    if len(uv) != len(deltas):
        raise InvalidInputError(f"{len(uv)} tracks but {len(deltas)} delta arrays")
    L = len(uv)
    if L < config.min_tracks:
        raise DegenerateMotionError(f"rigid front end: {L} tracks (need {config.min_tracks})")
    noise_px = track_noise_px(uv, focal)
    # The fit: tracks spread over the list (not the longest: silhouette points that slide live long),
    # each subsampled evenly; every track is checked against the fit after.
    fit_set = evenly_spaced(L, config.max_fit_tracks).tolist()
    picks = [evenly_spaced(len(deltas[t]), config.max_fit_frames) for t in fit_set]
    all_uv, all_deltas = uv, deltas
    uv = [all_uv[t][k] for t, k in zip(fit_set, picks, strict=True)]
    deltas = [all_deltas[t][k] for t, k in zip(fit_set, picks, strict=True)]
    n_fit = len(fit_set)
    angles, frames = _frame_table(deltas)

    usable = max(config.min_tracks, config.min_inlier_fraction * n_fit)  # fewest fit tracks a usable fit keeps

    def candidates():  # the given starts first, then the searches (only if those are not enough)
        yield from _line_starts((starts() if callable(starts) else starts) or [])
        yield from _grid_starts(uv, deltas, focal, config)
        if not config.relative_pose_if_needed or best is None or best[5] < usable:  # (best: the loop's below)
            yield from _relative_pose(uv, frames, angles, focal, config)

    singular = 0  # starts whose normal equations went singular: no fit from them

    def fitted(a0: FloatArray, p0: FloatArray, unit_scale: bool = False
               ) -> tuple[float, FloatArray, FloatArray, _Tracks, FloatArray, int] | None:
        nonlocal singular
        try:
            return _fit_from_start(uv, deltas, a0, p0, focal, config, noise_px, unit_scale)
        except np.linalg.LinAlgError:
            singular += 1
            return None

    best = None
    for a0, p0 in _line_starts([predicted] if predicted is not None else []):
        fit = fitted(a0, p0)
        if fit is not None and fit[5] >= usable and fit[1] @ a0 >= np.cos(config.predicted_angle):
            best = fit
    from_prediction = best is not None
    for a0, p0 in candidates() if best is None else ():
        fit = fitted(a0, p0)
        if fit is not None and (best is None or fit[0] < best[0]):
            best = fit
        if best is not None and best[5] >= config.enough_inlier_fraction * n_fit:
            break
    if best is None and singular:
        raise DegenerateMotionError(f"rigid front end: the fit from each of {singular} starts went singular")
    if best is None:
        raise DegenerateMotionError(
            f"rigid front end: no two frames {config.min_pair_angle} rad apart share "
            f"{max(config.min_tracks, 8)} tracks")
    if config.polish:  # (RigidAxisConfig.polish: from where the chosen fit ended, unscaled)
        polished = fitted(best[1], best[2], unit_scale=True)
        if polished is not None and polished[0] < best[0]:
            best = polished
    _, a, p, tracks, X, _ = best
    axis_std = _axis_std(tracks, a, p, X, focal, config)
    track_rms = _track_rms(_Tracks.of(all_uv, all_deltas), a, p, focal)
    threshold = rms_threshold(track_rms, config, noise_px)
    keep = track_rms <= threshold
    n_in, n_need = int(keep.sum()), max(config.min_tracks, int(np.ceil(config.min_inlier_fraction * L)))
    rms_in = float(np.sqrt(np.mean(track_rms[keep] ** 2))) if n_in else float("inf")
    fit = RigidAxisFit(a, p, axis_std, track_rms, keep, rms_in, from_prediction)
    fixed = axis_std <= config.max_axis_std
    if n_in < n_need:
        raise NonRigidTracksError(f"rigid front end: only {n_in} of {L} tracks move rigidly together within "
                                  f"{threshold:.2g} px (need {n_need})",
                                  fit if n_in >= config.min_tracks and fixed else None)
    if not fixed:
        raise DegenerateMotionError(
            f"rigid front end: the tracks do not fix the axis (1-sigma {axis_std:.3f} rad > {config.max_axis_std})")
    return fit


def _line_starts(lines: list[tuple[FloatArray, FloatArray]]) -> list[tuple[FloatArray, FloatArray]]:
    """Starts (a (3,) unit, p (3,) unit and perpendicular to a) from axes (3,) and points (3,) of them.

    A line through the camera centre (no perpendicular offset) gives no start.
    """
    out = []
    for a, p in lines:
        a = np.asarray(a, dtype=np.float64) / np.linalg.norm(a)
        p = np.asarray(p, dtype=np.float64) - a * (a @ p)
        if np.linalg.norm(p) > 1e-9:
            out.append((a, p / np.linalg.norm(p)))
    return out


def rigid_axis_of_motion(obs: MotionObservation, intrinsics: CameraIntrinsics,
                         config: RigidAxisConfig | None = None,
                         starts: Starts | None = None,
                         predicted: tuple[FloatArray, FloatArray] | None = None) -> RigidAxisFit:
    """``fit_rigid_axis`` on a motion's tracks in pixels (undistorted through the intrinsics)."""
    uv = [normalized_from_pixels(t.pixels, intrinsics) for t in obs.tracks]
    return fit_rigid_axis(uv, [t.delta for t in obs.tracks], float(np.mean(intrinsics.focal)), config, starts,
                          predicted)


def geometry_from_rigid_fit(fit: RigidAxisFit) -> MotionGeometry:
    """The fit as the stage-one geometry the linear calibration takes (axis, reference ray, plane)."""
    reference = fit.point_cam / np.linalg.norm(fit.point_cam)
    normal = np.cross(reference, fit.axis_cam)
    return MotionGeometry(axis_cam=fit.axis_cam, reference_cam=reference,
                          plane_normal=normal / np.linalg.norm(normal), track_inliers=fit.track_inliers,
                          score=fit.rms_px ** 2, ambiguity=float("inf"), rms_px=fit.rms_px)
