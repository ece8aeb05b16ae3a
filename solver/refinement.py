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

Time offset (ours, ``RefinementConfig.estimate_time_offset``): when every track carries the moving
joint's velocity v at each frame, the adjustment can also estimate one scalar s (seconds) by which the
joint clock is off from the camera clock, on top of any offset the joint values were already read with
(the sign of ``arc_env.robot.timing``: d = t_joint - t_camera, so the joint value at an exposure is
the series read s later). Each frame's turn becomes delta + v s (first order in s; the joint's
acceleration over s is neglected), and x = (omega, tau, s, q_1..q_T). A Gaussian prior s ~ N(0,
``time_offset_bound_s``^2) is one more residual; an estimate beyond the bound is refused
(``TimeOffsetError``), not clipped. The covariance is the Gauss-Newton one over all of (omega, tau,
s) with the points marginalized, so the pose's 1-sigma includes what s and the pose trade off.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.linalg import eigh
from scipy.optimize import least_squares
from scipy.optimize._lsq.common import (  # scipy's own steps, for _trf_subspace
    check_termination,
    minimize_quadratic_1d,
    solve_trust_region_2d,
    update_tr_radius,
)
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, norm
from scipy.stats import t as student_t

from solver.arrays import FloatArray
from solver.errors import InsufficientMotionsError, InvalidInputError, TimeOffsetError
from solver.frames import perturb, pose_difference, rotation_about_axis, skew, transform_from_rt
from solver.schur import PosePrior, normal_blocks, robust_sigma, solve_schur, track_starts

IntArray = NDArray[np.int64]
Backend = Literal["schur", "scipy"]


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
        robust_pose_tol: a warm-started ``refine`` (``points_init`` given: a relinearization, pose and points
            near their optimum) ends its robust pass (Schur backend) also once a step moves the pose by less
            than this fraction of its 1-sigma (``solver.schur.pose_step_sigmas``), while the outlier tracks'
            points may still creep: a relinearization over every motion took 7 instead of 12 iterations
            (scripts/bench_solver.py --all-tracks, pose 1 seed 0, motion 24). None: ``robust_ftol`` alone.
            Not from a cold start, nor in ``refine_increment`` (2-3 iterations): the first adjustment from
            a linear pose, stopped so, kept one borderline track that later batches drop, and the
            increments built on it stayed 0.41 sigma from the batch adjustment (pose 2, seed 4).
        estimate_time_offset: estimate the time offset s between the joint and camera clocks (the
            module doc): True, False, or None (the default) for on exactly when every track carries
            joint velocities (``TrackSet.velocity``).
        time_offset_bound_s: s; the prior's 1-sigma, and the largest |s| accepted: beyond it the
            clocks are too far apart for the first-order model (give the offset, e.g.
            ``arc-calib calibrate --time-offset``).
        backend: "schur" (``solver.schur``: Levenberg-Marquardt on the normal equations with the points
            eliminated; needed for incremental updates' pose priors) or "scipy" (TRF/LSMR on the sparse
            Jacobian, the earlier path). ``max_nfev`` caps either's Jacobian evaluations.
        track_weights: weight each kept track in the final pass by its own noise, estimated from its
            residuals after the robust pass, shrunk towards the common sigma with ``weight_prior_dof``
            degrees of freedom: sigma_t^2 = (nu sigma^2 + RSS_t) / (nu + 2 M_t - 3), so that many mediocre
            tracks cannot outvote good ones. On as-shipped surfaces most tracks are not on a surface point:
            of the 1314 tracks of a realistic as-shipped Panda episode (1080p, pose 3, 25 motions) 197 stay
            within 1.5 px of the point they started on (their residual RMS at the estimate 0.31 px, median),
            618 slide by more than 3 px (1.51 px) and 264 start off the moving links; the sliding majority
            sets the common sigma and the outlier bound, and biases the depth by millimetres (4.80 mm off;
            0.92 mm from the 197 alone). Weighted, the same tracks give 3.47 mm. But the weights come from
            the residuals they weigh and leave errors shared by every track (a bias no sandwich sees): with
            the weighted covariance alone, rendered as-shipped Panda runs (at 1e65389) were flagged usable
            5.98 mm off and clean painted ones declared convergence over 3x off in 2 of 4. So the reported
            covariance is at least the unweighted fit's plus the two estimates' difference
            (``weighted_covariance_bound``, from each motion's unweighted twin summary): the weights may make
            the estimate better, never its claimed precision. Replays of captured episodes are in the README.
        weight_prior_dof: see ``track_weights``.
        free_rates: "all": each track may turn by its own multiple s_t of the joint's turn, eliminated per track
            (``_Problem``'s variable projection): a corner on a smooth casting that follows its shading or a
            highlight lags the surface, tracing a shorter arc about the same axis, and with the rate fixed at 1
            those shorter arcs read as a farther camera. Costs each track one degree of freedom and the pose the
            turns' phase information. Off: replayed on captured realistic tracks (25 motions) it removed a lag
            bias on some (as-shipped Panda 1080p pose 3: 3.31 -> 2.06 mm; Panda 720p pose 0: 4.62 -> 1.30 mm,
            with a 1-sigma of 25 mm) and added error on others (as-shipped poses 0, 1, 2: 0.84 -> 5.35, 0.32 ->
            3.12, 6.25 -> 12.25 mm), and widened the clean painted 1-sigma 2-3x: the phase the rate carries is
            most of what fixes the depth. "tested": only the tracks whose robust-pass residuals a rate explains
            beyond their own noise (``lagging_tracks``) get one in the final pass; replayed on the same nine
            captures at 25 motions, as-shipped Panda 1080p poses 0-3 went from 2.01e-3 / 0.84, 9.04e-4 / 0.32,
            1.68e-3 / 6.25, 1.52e-3 / 3.31 (rad / mm, "off") to 1.99e-3 / 3.18, 6.43e-4 / 1.32, 1.07e-3 / 5.75,
            1.25e-3 / 1.89; clean painted poses 0 and 2 from 6.17e-5 / 0.35, 1.01e-4 / 0.19 to 8.35e-5 / 0.64,
            2.39e-4 / 0.21; xArm 6 pose 1 from 7.47e-4 / 0.72 (truth's chi-square 2.3) to 1.03e-3 / 0.71 (13.9):
            no consistent gain, so off.
        motion_clusters: the covariance is also at least the motion-clustered sandwich
            (``summaries_covariance``): errors shared by a sweep bias the pose beyond what the track-clustered
            one sees. Without it, realistic rendered 1080p Panda episodes (25 motions, every track, per-track
            weights) had rotation errors 3-4x their 1-sigma from motion 10 on, and one of three declared
            convergence while over 3x off.
        motion_jackknife: with ``motion_clusters``, the covariance is also at least the leave-one-motion-out
            jackknife (``motion_jackknife_covariance``) wherever the motions' scores are over-dispersed
            against independent pixel noise (``motion_overdispersion``; on realistic images 7-20 times the
            expected value, on synthetic independent noise about 1). Without it, realistic rendered 1080p Panda episodes
            (random motions, poses 3 and 4 of the benchmark) declared convergence at 3.1-3.4x (3.5 mm off,
            1-sigma norm 1.0-1.1 mm, motions 14-24) and 3.0x (motion 7) their 1-sigma; with it, replayed on the
            same tracks, at most 1.9x and 2.5x.
        motion_dispersion: under the same test, the covariance is also at least the model's scaled by the
            motions' dispersion (``summaries_covariance``): the jackknife of M motions has rank M - 1 at most,
            so up to 6 motions it leaves whole directions to the track sandwich.
        max_split_px: px; after the robust pass a track is also dropped when a point fitted to either half of
            its frames misses the other half by more than this (``split_half_residuals``: the larger of the two
            RMS distances): a corner that slides over the surface or along an outline fits a rigid point over a
            short stretch, but not the same point over both halves. None (the default): no such test. Measured
            offline on as-shipped realistic Panda 1080p captures (poses 0, 2; 25 motions), with a plain Cauchy
            adjustment started from the default's estimate, the test told the tracks that stay within 1.5 px
            of their surface point from the rest with an area under the curve of 0.93; calibrated with only the
            tracks within 1 / 2 px: 2.44 / 3.01 mm and 3.95 / 3.94 mm off, against the default's 3.34 and 6.00 mm.
            Replayed through the Calibrator on captured tracks (25 motions; translation error, 1-sigma in
            brackets), None -> 1 px: as-shipped Panda 1080p poses 0-3 0.84 (4.90), 0.32 (5.77), 6.25 (14.2),
            3.31 (3.09) -> 0.36 (5.63), 0.92 (2.90), 4.64 (8.02), 3.20 (2.84) mm: usable 0 -> 2 of 4; realistic
            Panda and iiwa 720p pose 0 4.62 -> 6.64 and 3.95 -> 4.50 mm, xArm 6 1080p poses 1 and 6 0.72 -> 0.56
            and 0.26 -> 0.26 mm; clean painted Panda 1080p poses 0-3 unchanged (0.35, 0.01, 0.19, 0.08 mm); at
            2 px as-shipped 1.09, 0.22, 6.29, 3.37 mm, none usable; at 1.5 px 0.57, 0.78, 6.92, 3.02 mm, none
            usable, realistic Panda and iiwa 720p 4.77 and 6.63 mm. Not monotonic in the threshold, worse on two
            realistic runs of three: within what track choice moves these runs by, so off.
    """

    cauchy_scale_px: float = 1.0
    outlier_px: float = 0.5
    outlier_sigmas: float = 1.8
    max_nfev: int = 50
    min_track_frames: int = 4
    robust_ftol: float = 1e-5
    robust_pose_tol: float | None = 0.05
    estimate_time_offset: bool | None = None
    time_offset_bound_s: float = 0.1
    backend: Backend = "schur"
    track_weights: bool = True
    weight_prior_dof: float = 10.0
    free_rates: Literal["off", "all", "tested"] = "off"
    motion_clusters: bool = True
    motion_jackknife: bool = True
    motion_dispersion: bool = True
    max_split_px: float | None = None

    def __post_init__(self) -> None:
        if not self.time_offset_bound_s > 0:
            raise InvalidInputError(f"time_offset_bound_s must be > 0 s, got {self.time_offset_bound_s}")
        if self.max_split_px is not None and not self.max_split_px > 0:
            raise InvalidInputError(f"max_split_px must be > 0 px or None, got {self.max_split_px}")


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
        axis: (T, 3) float64: a_b of each track's motion (base frame, unit); None: not given.
        delta: (P,) float64, rad: each observation's turn (``rot`` is Rot(a_b, delta)); None: not given.
        velocity: (P,) float64, rad/s: the moving joint's velocity at each observation; None unless
            every track carries one.
        free_rates: (T,) bool: the tracks that turn by their own multiple of the joint's turn
            (``RefinementConfig.free_rates``); None: none. Set by ``refine`` and ``refine_increment``.
    """

    uv: FloatArray
    track: IntArray
    rot: FloatArray
    pivot: FloatArray
    motion: IntArray
    focal: FloatArray
    axis: FloatArray | None = None
    delta: FloatArray | None = None
    velocity: FloatArray | None = None
    free_rates: NDArray[np.bool_] | None = None

    @property
    def n_tracks(self) -> int:
        """Number of tracks T."""
        return int(self.pivot.shape[0])


def build_track_set(motions: Sequence[tuple[FloatArray, FloatArray, Sequence[tuple[FloatArray, ...]]]],
                    focal: FloatArray, min_frames: int = 4) -> TrackSet:
    """Flatten motions into a TrackSet.

    Args:
        motions: per motion (axis_base (3,), point_base (3,) m, tracks), each track a pair
            (uv (M, 2) normalized coordinates, delta (M,) rad) or a triple with the joint's velocity
            (M,) rad/s at each frame (None: unknown) last.
        focal: (2,) float64, px: (fx, fy), to express residuals in pixels.
        min_frames: shorter tracks are skipped.
    """
    uv, track, rot, pivot, motion, axes, deltas, velocity = [], [], [], [], [], [], [], []
    every_velocity = True
    for i, (axis, point, tracks) in enumerate(motions):
        kept = [t for t in tracks if t[0].shape[0] >= min_frames]
        if not kept:
            continue
        for t in kept:
            uv.append(t[0])
            track.append(np.full(t[0].shape[0], len(pivot)))
            pivot.append(point)
            motion.append(i)
            axes.append(axis)
            v = t[2] if len(t) > 2 else None
            every_velocity = every_velocity and v is not None
            if every_velocity:
                velocity.append(v)
        turns = np.concatenate([t[1] for t in kept])
        deltas.append(turns)
        rot.append(rotation_about_axis(axis, turns))  # one call per motion
    if not pivot:
        raise InsufficientMotionsError("no track long enough to refine")
    return TrackSet(np.concatenate(uv), np.concatenate(track).astype(np.int64), np.concatenate(rot),
                    np.array(pivot), np.array(motion, dtype=np.int64), np.asarray(focal, float),
                    np.array(axes, dtype=np.float64), np.concatenate(deltas),
                    np.concatenate(velocity).astype(np.float64) if every_velocity else None)


def triangulate_tracks(tracks: TrackSet, T_camera_base: FloatArray) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Each track's point p0 (base frame, start configuration) given the pose: linear, closed form.

    With y = p0 - d_b and M_k = R Rot_k, the camera point is M_k y + (R d_b + t); requiring it on
    the observed ray (x - u z = 0, y - v z = 0) is linear in y. Solved per track by least squares.

    Returns:
        points (T, 3) float64, m, and ok (T,) bool: False where the system is singular or the point
        falls behind the camera.
    """
    points, ok, _ = _triangulated(tracks, T_camera_base)
    return points, ok


def _triangulated(tracks: TrackSet, T_camera_base: FloatArray) -> tuple[FloatArray, NDArray[np.bool_], FloatArray]:
    """``triangulate_tracks``' points (T, 3) and ok (T,), and every observation's camera point (P, 3) of them."""
    points, ok, camera = _triangulated_at(tracks, T_camera_base[None])
    return points[0], ok[0], camera[0]


def _triangulated_at(tracks: TrackSet, poses: FloatArray) -> tuple[FloatArray, NDArray[np.bool_], FloatArray]:
    """``_triangulated`` at each of poses (N, 4, 4) at once: points (N, T, 3), ok (N, T), camera points (N, P, 3)."""
    R, t = poses[:, :3, :3], poses[:, :3, 3]
    n, T = len(poses), tracks.n_tracks
    M = R[:, None] @ tracks.rot  # (N, P, 3, 3)
    c = tracks.pivot[tracks.track] @ R.transpose(0, 2, 1) + t[:, None]  # (N, P, 3)
    u, v = tracks.uv[:, 0, None], tracks.uv[:, 1, None]
    A = np.stack([M[..., 0, :] - u * M[..., 2, :], M[..., 1, :] - v * M[..., 2, :]], axis=2)  # (N, P, 2, 3)
    b = np.stack([u[:, 0] * c[..., 2] - c[..., 0], v[:, 0] * c[..., 2] - c[..., 1]], axis=2)  # (N, P, 2)
    # per-track sums over the observations: a (T, P) sparse matrix of ones, its rows in observation order
    sums = sp.csr_matrix((np.ones(tracks.track.size), (tracks.track, np.arange(tracks.track.size))),
                         shape=(T, tracks.track.size))
    At = A.swapaxes(2, 3)  # (N, P, 3, 2)
    AtA = (sums @ (At @ A).swapaxes(0, 1).reshape(tracks.track.size, -1)).reshape(T, n, 3, 3)
    Atb = (sums @ (At @ b[..., None]).swapaxes(0, 1).reshape(tracks.track.size, -1)).reshape(T, n, 3)
    AtA, Atb = AtA.transpose(1, 0, 2, 3).copy(), Atb.transpose(1, 0, 2)
    det = np.linalg.det(AtA)
    scale = np.einsum("ntii->nt", AtA) ** 3
    ok = det > 1e-12 * np.maximum(scale, 1e-300)
    AtA[~ok] = np.eye(3)
    y = np.linalg.solve(AtA, Atb[..., None])[..., 0]  # (N, T, 3)
    points = y + tracks.pivot
    camera = np.einsum("npij,npj->npi", M, y[:, tracks.track]) + c
    counts = np.bincount(tracks.track, minlength=T)
    front = (sums @ (camera[..., 2] > 0).T.astype(float)).T  # (N, T): observations in front of the camera
    ok &= front == counts
    return points, ok, camera


def track_camera_points(tracks: TrackSet, T_camera_base: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(P, 3) m: every observation's camera point of its track's y = p0 - d_b (T, 3) m, and M_k = R Rot_k (P, 3, 3).

    Notation as in ``triangulate_tracks``: the camera point at frame k is M_k y + (R d_b + t).
    """
    R, t = T_camera_base[:3, :3], T_camera_base[:3, 3]
    M = np.einsum("ij,pjk->pik", R, tracks.rot)
    c = tracks.pivot[tracks.track] @ R.T + t
    return np.einsum("pij,pj->pi", M, y[tracks.track]) + c, M


def track_pixel_residuals(tracks: TrackSet, pc: FloatArray) -> FloatArray:
    """(..., P, 2) px: the projections of camera points pc (..., P, 3) m minus the observations."""
    return (pc[..., :2] / pc[..., 2:] - tracks.uv) * tracks.focal


def _left_jacobian(omega: FloatArray) -> FloatArray:
    theta = float(np.linalg.norm(omega))
    W = skew(omega)
    if theta < 1e-8:
        return np.eye(3) + 0.5 * W
    return (np.eye(3) + (1 - np.cos(theta)) / theta**2 * W
            + (theta - np.sin(theta)) / theta**3 * W @ W)


class _Problem:
    """Residuals and sparse Jacobian of the bundle adjustment over x = (omega, tau, [s,] q_1..q_T).

    Each track's unknown is q, its point in the camera frame at the start configuration (delta =
    0), not its base-frame point p0 = R^T (q - t): the frame-0 residual then does not depend on the
    pose, which decouples points from pose and makes the sparse normal equations far better
    conditioned for LSMR. The pose's marginal covariance is the same in either parameterization
    (the change of variables is block-triangular with an identity pose block).

    With ``prior_weight`` (px per s) given, the time offset s (the module doc) is the 7th parameter
    and one last residual prior_weight * s is its prior; the "pose" blocks below then span
    (omega, tau, s). Without it the problem is the 6-parameter one, computed exactly as before.

    ``scale`` (P,), when given, multiplies each observation's residual and Jacobian rows: the weights of
    a weighted least squares (``RefinementConfig.track_weights``), in units that keep residuals in px.
    """

    def __init__(self, tracks: TrackSet, T0: FloatArray, prior_weight: float | None = None,
                 scale: FloatArray | None = None):
        self.tracks = tracks
        self.T0 = T0
        self.prior_weight = prior_weight
        self.scale = scale
        self.n_pose = 6 if prior_weight is None else 7
        if prior_weight is not None and (tracks.velocity is None or tracks.axis is None or tracks.delta is None):
            raise InvalidInputError("a time-offset estimate needs every track's joint velocity")
        P, n = tracks.uv.shape[0], self.n_pose
        cols = np.empty((P, 2, n + 3), dtype=np.int64)
        cols[:, :, :n] = np.arange(n)
        cols[:, :, n:] = (n + 3 * tracks.track)[:, None, None] + np.arange(3)
        self.cols = cols.ravel()  # CSR column indices: every row has the pose entries and its point's 3
        self.indptr = np.arange(0, (n + 3) * 2 * P + 1, n + 3)
        self.shape = (2 * P, n + 3 * tracks.n_tracks)
        if prior_weight is not None:  # the prior's row: the pose columns (only s's is non-zero unwhitened)
            self.cols = np.concatenate([self.cols, np.arange(n)])
            self.indptr = np.append(self.indptr, self.indptr[-1] + n)
            self.shape = (2 * P + 1, self.shape[1])
        self.rate_free = tracks.free_rates is not None and bool(tracks.free_rates.any())
        if prior_weight is not None or self.rate_free:
            if tracks.axis is None or tracks.delta is None:
                raise InvalidInputError("a time offset or free turn rates need every track's axis and turns")
            self.obs_axis = tracks.axis[tracks.track]  # (P, 3): each observation's a_b
        self.obs_pivot = tracks.pivot[tracks.track]  # (P, 3) m: each observation's d_b
        if self.rate_free:
            assert tracks.free_rates is not None
            self.starts = track_starts(tracks.track)
            self.rate_turn = _turns_since_start(tracks) * tracks.free_rates[tracks.track]  # (P,) rad, 0 if fixed

    def pose(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """R (3, 3) and t (3,) at parameters x."""
        return Rotation.from_rotvec(x[:3]).as_matrix() @ self.T0[:3, :3], self.T0[:3, 3] + x[3:6]

    def rotations(self, x: FloatArray) -> FloatArray:
        """(P, 3, 3): Rot(a_b, delta + v s) of each observation (the given ``rot`` without s)."""
        tr = self.tracks
        if self.prior_weight is None:
            return tr.rot
        return Rotation.from_rotvec(self.obs_axis * (tr.delta + tr.velocity * x[6])[:, None]).as_matrix()

    def _camera_points(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
        tr = self.tracks
        R, t = self.pose(x)
        rot = self.rotations(x)
        q = x[self.n_pose:].reshape(-1, 3)[tr.track]
        y = (q - t) @ R  # R^T (q - t): the base-frame point at delta = 0
        p_base = np.matmul(rot, (y - self.obs_pivot)[:, :, None])[:, :, 0] + self.obs_pivot
        return p_base @ R.T + t, R, t, q, rot

    def residuals(self, x: FloatArray) -> FloatArray:
        """(2P,) float64, px: reprojection errors (then the prior's residual when s is estimated)."""
        pc, R, t, _, _ = self._camera_points(x)
        r = (pc[:, :2] / pc[:, 2:] - self.tracks.uv) * self.tracks.focal
        if self.rate_free:
            J_rate = self._rate_column(pc, R, t, self._pixel_derivative(pc), self.rate_turn)
            r = r - J_rate * self._rate_coefficients(J_rate, r[:, :, None])[self.tracks.track]
        r = (r if self.scale is None else r * self.scale[:, None]).ravel()
        return r if self.prior_weight is None else np.append(r, self.prior_weight * x[6])

    def csr(self, blocks: FloatArray, prior_row: FloatArray | None) -> sp.csr_matrix:
        """The sparse Jacobian from the observations' blocks (P, 2, n_pose + 3) and the prior's row (n_pose,)."""
        data = blocks.ravel() if prior_row is None else np.concatenate([blocks.ravel(), prior_row])
        return sp.csr_matrix((data, self.cols, self.indptr), shape=self.shape)

    def prior_row(self) -> FloatArray | None:
        """(n_pose,): the prior residual's derivatives by the pose parameters (None without s)."""
        if self.prior_weight is None:
            return None
        row = np.zeros(self.n_pose)
        row[6] = self.prior_weight
        return row

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        """(2P, n_pose + 3T) sparse Jacobian of ``residuals`` (one more row for the prior with s)."""
        return self.csr(self.jacobian_blocks(x), self.prior_row())

    def jacobian_blocks(self, x: FloatArray) -> FloatArray:
        """(P, 2, n_pose + 3): each observation's derivatives by (omega, tau[, s]) and by its track's point q.

        With D the (2, 3) derivative of the pixel by the camera point and M = R Rot_k R^T, the
        camera point's derivatives are -[pc - t]x + M [q - t]x by omega (times the left Jacobian of
        SO(3)), I - M by tau and M by q; a row v of D times [a]x is v x a. By s: v R (a_b x
        (p_base - d_b)), the turn's rate times the point's velocity about the axis.
        """
        tr = self.tracks
        pc, R, t, q, rot = self._camera_points(x)
        P = pc.shape[0]
        D = self._pixel_derivative(pc)
        DM = np.matmul((D.reshape(2 * P, 3) @ R).reshape(P, 2, 3), rot).reshape(2 * P, 3) @ R.T  # D M
        DM = DM.reshape(P, 2, 3)
        d_omega = np.cross(DM, (q - t)[:, None, :]) - np.cross(D, (pc - t)[:, None, :])
        d_omega = (d_omega.reshape(2 * P, 3) @ _left_jacobian(x[:3])).reshape(P, 2, 3)
        if self.prior_weight is None:
            blocks = np.concatenate([d_omega, D - DM, DM], axis=2)
        else:
            d_s = self._rate_column(pc, R, t, D, tr.velocity)  # (P, 2): pixel by s, the turn v s
            blocks = np.concatenate([d_omega, D - DM, d_s[:, :, None], DM], axis=2)
        if self.rate_free:
            J_rate = self._rate_column(pc, R, t, D, self.rate_turn)
            blocks = blocks - J_rate[:, :, None] * self._rate_coefficients(J_rate, blocks)[tr.track][:, None, :]
        return blocks if self.scale is None else blocks * self.scale[:, None, None]

    def _pixel_derivative(self, pc: FloatArray) -> FloatArray:
        """(P, 2, 3) px/m: each observation's pixel by its camera point pc (P, 3) m."""
        focal = self.tracks.focal
        inv_z = 1.0 / pc[:, 2]
        D = np.zeros((pc.shape[0], 2, 3))
        D[:, 0, 0] = focal[0] * inv_z
        D[:, 1, 1] = focal[1] * inv_z
        D[:, 0, 2] = -focal[0] * pc[:, 0] * inv_z**2
        D[:, 1, 2] = -focal[1] * pc[:, 1] * inv_z**2
        return D

    def _rate_column(self, pc: FloatArray, R: FloatArray, t: FloatArray, D: FloatArray, turn: FloatArray
                     ) -> FloatArray:
        """(P, 2) px: each observation's pixel by a parameter that turns it by ``turn`` (P,) per unit.

        ``turn`` times the point's velocity about the axis, v R (a_b x (p_base - d_b)): for a track's own turn
        rate (``TrackSet.free_rates``) the turn since its first frame; for the time offset the joint's velocity.
        """
        arm = (pc - t) @ R - self.obs_pivot  # p_base - d_b
        d_rate = np.cross(self.tracks.axis[self.tracks.track], arm) @ R.T * turn[:, None]  # camera point by the rate
        return np.einsum("pij,pj->pi", D, d_rate)

    def _rate_coefficients(self, J_rate: FloatArray, values: FloatArray) -> FloatArray:
        """(T, K): per track, sum J_rate . values / sum J_rate . J_rate, for values (P, 2, K) (0 where J_rate is).

        Subtracting J_rate times these from the residuals (K = 1) or the Jacobian's blocks minimizes over each
        track's turn rate (to first order; variable projection, Kaufman's Jacobian): a track that turns by a
        multiple of the joint's turn (a shading feature lagging the surface) fits without biasing the pose.
        """
        starts = self.starts
        num = np.add.reduceat(np.einsum("pi,pik->pk", J_rate, values), starts)
        den = np.add.reduceat(np.sum(J_rate**2, axis=1), starts)
        return np.where(den[:, None] > 1e-9, num / np.maximum(den, 1e-9)[:, None], 0.0)


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
        time_offset_s: the estimated time offset s (the module doc), s; None when not estimated.
        time_offset_std_s: its 1-sigma, s, from the same covariance as the pose's (whose
            ``covariance`` is then the pose block of the (7, 7) one: s marginalized); None likewise.
        time_offset_correlation: (6,) the correlation of s with each of (omega, tau) in that
            covariance; None likewise. Near +-1 the tracks cannot tell s from a pose change.
        summaries: each motion's summary (``refine_increment``); empty from a backend without them.
        robust_sigma_px: the robust pass's pixel sigma, the outlier scale later updates reuse.
        sandwich_covariance: (6, 6) ``covariance`` before the motion jackknife (``summaries_covariance``):
            whether the geometry fixes the pose is judged on it (``Calibrator``), since from a few motions
            the jackknife measures how much they disagree rather than what they leave free; None when
            the backend gives only one.
    """

    T_camera_base: FloatArray
    covariance: FloatArray
    points_base: FloatArray
    track_inliers: NDArray[np.bool_]
    rms_px: float
    sigma_px: float
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    time_offset_correlation: FloatArray | None = None
    summaries: tuple[MotionSummary, ...] = ()
    robust_sigma_px: float | None = None
    sandwich_covariance: FloatArray | None = None


@dataclass(frozen=True)
class MotionSummary:
    """What one motion's kept tracks say about the pose, their points marginalized (``refine_increment``).

    Its cost as a function of the pose near the linearization point, the points re-optimized, is
    0.5 d^T information d + gradient^T d + rss / 2 with d the pose parameters' change from there
    (``solver.frames`` perturbation, then the time offset's change): the Gauss-Newton expansion.

    Attributes:
        motion: the motion's index (``TrackSet.motion``).
        T_lin: (4, 4) float64: the pose it is linearized at.
        time_offset_lin: s, the time offset there (None without it).
        information: (n, n) float64: U - W V^-1 W^T of its observations, px^2 per (rad, m[, s])^2.
        gradient: (n,) float64: the reduced gradient J_p^T r - W V^-1 J_x^T r there, px^2 per (rad, m[, s]).
        meat: (n, n) float64: sum over its tracks of g_t g_t^T (``clustered_pose_covariance``).
        rss: px^2, the sum of its squared residuals there.
        n_residuals: how many residuals: 2 per observation, less one per track with free turn rates
            (``RefinementConfig.free_rates``: each has a degree of freedom fewer).
        n_tracks: its kept tracks.
        unweighted: with per-track weights (``RefinementConfig.track_weights``), the same motion's summary
            at the same point without them (what ``weighted_covariance_bound`` reads); None unweighted.
    """

    motion: int
    T_lin: FloatArray
    time_offset_lin: float | None
    information: FloatArray
    gradient: FloatArray
    meat: FloatArray
    rss: float
    n_residuals: int
    n_tracks: int
    unweighted: MotionSummary | None = None


def _with_unweighted(problem: _Problem, x: FloatArray, fun: FloatArray, raw: FloatArray,
                     scale: FloatArray | None) -> tuple[MotionSummary, ...]:
    """The motions' summaries at x: ``_motion_summaries`` of the residuals ``fun`` (2P,) px.

    When ``scale`` (P,) weighted them, each carries its unweighted twin from the raw residuals ``raw`` (2P,) px.
    A track's weight is one number for all its observations (``_track_scale``), so its weighted score,
    information and RSS are the plain ones times its weight (the scale squared): one pass gives both.
    """
    if scale is None:
        return _motion_summaries(problem, x, fun)
    plain_problem = _Problem(problem.tracks, problem.T0, problem.prior_weight)
    weight = scale[track_starts(problem.tracks.track)] ** 2  # (T,)
    return tuple(replace(w, unweighted=u) for w, u in _summary_pairs(plain_problem, x, raw, weight))


def weighted_covariance_bound(cov: FloatArray, summaries: Sequence[MotionSummary], prior_row: FloatArray | None,
                              T0: FloatArray | None, s0: float | None, config: RefinementConfig,
                              gauge: FloatArray | None = None) -> FloatArray:
    """The covariance (n, n) of a weighted estimate, at least its unweighted twin's (``track_weights``).

    ``cov`` is the weighted adjustment's (``summaries_covariance`` of ``summaries``, about (T0, s0), or about
    their own linearization point when T0 is None). The same tracks unweighted (each summary's
    ``unweighted``) have their optimum a Gauss-Newton step d (n,) away; the bound is their covariance there
    (``summaries_covariance``, the same settings), plus d d^T, the two estimates' difference, when they differ
    beyond their noise (``weights_disagree``): where the weights and the plain fit disagree, that much is
    unknown. Returns ``cov`` when the summaries carry no unweighted twins (weights off). ``gauge``: as
    ``summaries_covariance``'s.
    """
    if not summaries or all(m.unweighted is None for m in summaries):
        return cov
    plain = [m.unweighted if m.unweighted is not None else m for m in summaries]
    T_a = plain[0].T_lin if T0 is None else T0
    s_a = plain[0].time_offset_lin if T0 is None else s0
    quadratic = summaries_prior(plain, T_a, s_a)
    S, G = quadratic.information, quadratic.gradient
    if prior_row is not None:  # the time offset's prior residual prior_row @ (0, .., s)
        S = S + np.outer(prior_row, prior_row)
        G = G + prior_row * (prior_row[-1] * (s_a or 0.0))
    if gauge is not None:
        S = S + gauge
    d = -np.linalg.lstsq(S, G, rcond=None)[0]
    T_u = perturb(T_a, d[:6])
    s_u = None if s_a is None else s_a + float(d[6])
    bound, _, _ = summaries_covariance(plain, prior_row, T_u, s_u, config.motion_clusters, config.motion_jackknife,
                                       config.motion_dispersion, gauge)
    if weights_disagree(d, bound, cov):
        bound = bound + np.outer(d, d)
    return conservative_covariance(cov, bound)


def weights_disagree(d: FloatArray, plain: FloatArray, weighted: FloatArray) -> bool:
    """Whether the weighted and the plain estimate, d (n,) apart, differ more than their noise makes them.

    A Hausman test: when every track's weight is right, both estimates are unbiased and the weighted one
    the more precise, so their difference has covariance ``plain`` - ``weighted`` ((n, n) each) and
    d^T (plain - weighted)^+ d is chi-square with its rank's degrees of freedom. Above the quantile at
    ``HAUSMAN_TEST_LEVEL`` the weights (or the plain fit) are biased by errors the residuals do not show,
    and the difference itself is added to the bound. The pseudo-inverse is taken in ``plain``'s whitened
    coordinates, over the directions where the weights gain more than ``HAUSMAN_MIN_GAIN`` of the variance;
    elsewhere the two estimates should agree to within the plain one's own noise times that gain's root.
    """
    L = np.linalg.cholesky(plain + 1e-300 * np.eye(len(d)))
    Li = np.linalg.inv(L)
    gain, V = np.linalg.eigh(np.eye(len(d)) - Li @ weighted @ Li.T)  # 1 - weighted/plain per direction
    z = V.T @ (Li @ d)  # d in plain's whitened coordinates, along the gain's directions
    keep = gain > HAUSMAN_MIN_GAIN
    stat = float(np.sum(z[keep] ** 2 / gain[keep]) + np.sum(z[~keep] ** 2) / HAUSMAN_MIN_GAIN)
    return stat > chi2.ppf(1.0 - HAUSMAN_TEST_LEVEL, len(d))


#: ``weights_disagree``'s test level: the plain-fit difference d d^T is added to a weighted covariance only where the
#: two estimates differ beyond this quantile (seen: with d d^T always added, synthetic all-track episodes' 95 % regions
#: held the truth 74 times in 74, too wide).
HAUSMAN_TEST_LEVEL = 0.01

#: ``weights_disagree``'s smallest gain in variance (1 - weighted / plain, whitened) taken as a direction of its own.
HAUSMAN_MIN_GAIN = 0.01


class _Whitened:
    """A ``_Problem`` in block-whitened coordinates z about x0: x = x0 + A z.

    A is block diagonal: the pose's (6, 6) block (with the time offset (7, 7), the prior's row
    included) and each track's (3, 3) block are L^-T for the Cholesky factor L of that block of
    J^T J at x0. Then J^T J in z has identity diagonal blocks for the points, so J^T J - I has rank
    at most 12 (14: the pose's coupling) and LSMR converges in
    a few dozen iterations instead of hundreds; and z starts at 0, so TRF's first trust region is
    unit-sized in these units (x0 itself would make it the size of the points' coordinates).
    """

    def __init__(self, problem: _Problem, x0: FloatArray):
        self.problem = problem
        self.x0 = x0
        blocks = problem.jacobian_blocks(x0)
        U, V = _diagonal_blocks(blocks, problem.tracks)
        prior = problem.prior_row()
        self.Ap = _inverse_cholesky_t(U if prior is None else U + np.outer(prior, prior))
        self.Aq = _inverse_cholesky_t(V)
        self.Aq_obs = self.Aq[problem.tracks.track]  # (P, 3, 3)
        self.prior_row = None if prior is None else prior @ self.Ap  # the prior's row by z
        self._blocks_x0: FloatArray | None = blocks  # TRF's first Jacobian is at z = 0: x0's blocks

    def native(self, z: FloatArray) -> FloatArray:
        """(n_pose + 3T,) the problem's parameters x at whitened z."""
        n = self.problem.n_pose
        dq = np.matmul(self.Aq, z[n:].reshape(-1, 3, 1))[:, :, 0]
        return self.x0 + np.concatenate([self.Ap @ z[:n], dq.ravel()])

    def residuals(self, z: FloatArray) -> FloatArray:
        """(2P,) float64, px: the problem's residuals at x(z) (and the prior's, with the time offset)."""
        return self.problem.residuals(self.native(z))

    def jacobian(self, z: FloatArray) -> sp.csr_matrix:
        """(2P, n_pose + 3T) sparse Jacobian of ``residuals`` by z."""
        return self.problem.csr(self.jacobian_blocks(z), self.prior_row)

    def jacobian_blocks(self, z: FloatArray) -> FloatArray:
        """(P, 2, n_pose + 3): ``jacobian``'s blocks, each observation's derivatives by the pose's z and its point's."""
        p = self.problem
        n = p.n_pose
        if self._blocks_x0 is not None and not np.any(z):
            blocks, self._blocks_x0 = self._blocks_x0, None
        else:
            blocks = p.jacobian_blocks(self.native(z))
        P = blocks.shape[0]
        blocks[:, :, :n] = (blocks[:, :, :n].reshape(2 * P, n) @ self.Ap).reshape(P, 2, n)
        blocks[:, :, n:] = np.matmul(blocks[:, :, n:], self.Aq_obs)
        return blocks


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
    """The pose's block U (n, n) and each track's point block V (T, 3, 3) of the observations' J^T J.

    From the blocks (P, 2, n + 3), n = 6 (or 7 with the time offset).
    """
    n = blocks.shape[2] - 3
    Jp, Jx = blocks[:, :, :n], blocks[:, :, n:]
    return np.einsum("pki,pkj->ij", Jp, Jp), _per_track_sum(np.einsum("pki,pkj->pij", Jx, Jx), tracks)


#: TRF's first trust region in whitened units (a unit step changes the residual vector by about
#: 1 px in norm): large enough for a warm start's step, so a pass does not spend its first
#: iterations doubling a unit region (20-40% fewer evaluations on scripts/bench_solver.py).
_TRUST_SCALE = 32.0
#: ``linear_track_scores`` triangulates at most about this many observations at once (poses x observations)
_SCORED_OBSERVATIONS = 200_000


def _solve(tracks: TrackSet, T0: FloatArray, points: FloatArray, loss: str, f_scale: float,
           max_nfev: int, lsmr_tol: float = 1e-12, ftol: float = 1e-9,
           time_offset: tuple[float, float] | None = None, backend: Backend = "schur",
           scale: FloatArray | None = None, prior: PosePrior | None = None, pose_tol: float | None = None
           ) -> tuple[FloatArray, FloatArray, _Problem, FloatArray, object]:
    """One least-squares pass from pose T0 and base-frame points (T, 3).

    ``backend`` "schur": ``solver.schur.solve_schur`` (``max_nfev`` its iterations); "scipy": scipy's TRF
    in ``_Whitened`` coordinates, where ``lsmr_tol`` must be tight (1e-12) far from the optimum (TRF
    otherwise stalls) and the final pass, starting at the robust optimum, converges with a looser one.
    ``ftol`` is the relative cost change that ends the pass. ``time_offset``: (start s, prior weight px/s)
    to estimate the time offset too; None not to. ``scale``: (P,) each observation's residual multiplier
    (``_Problem``). ``prior``: a quadratic cost on the pose parameters (Schur backend only). ``pose_tol``:
    the Schur backend also stops once a step moves the pose by less than this fraction of its 1-sigma.

    Returns:
        pose (4, 4), base points (T, 3), the problem, its parameters x at the solution, and the
        solver's result (whose ``fun`` is the residual vector there, the prior's last with s).
    """
    problem = _Problem(tracks, T0, None if time_offset is None else time_offset[1], scale)
    n = problem.n_pose
    q0 = points @ T0[:3, :3].T + T0[:3, 3]
    pose0 = np.zeros(6) if time_offset is None else np.append(np.zeros(6), time_offset[0])
    start = np.concatenate([pose0, q0.ravel()])
    if backend == "schur":
        sol = solve_schur(problem, start, loss, f_scale, max_nfev, ftol, prior, pose_tol)
        x = sol.x
    else:
        if prior is not None:
            raise InvalidInputError("the scipy backend takes no pose prior (incremental updates need backend='schur')")
        white = _Whitened(problem, start)
        sol = least_squares(white.residuals, np.zeros(n + 3 * tracks.n_tracks), jac=white.jacobian,
                            method="trf", loss=loss, f_scale=f_scale, tr_solver="lsmr", max_nfev=max_nfev,
                            x_scale=_TRUST_SCALE,
                            tr_options={"atol": lsmr_tol, "btol": lsmr_tol}, xtol=1e-10, ftol=ftol)
        x = white.native(sol.x)
    R, t = problem.pose(x)
    return perturb(T0, x[:6]), (x[n:].reshape(-1, 3) - t) @ R, problem, x, sol


def _schur_parts(problem: _Problem, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The Jacobian's dense blocks (P, 2, n + 3), W (T, n, 3), V^-1 (T, 3, 3) and S = U - W V^-1 W^T (n, n) at x.

    Built track by track (each observation touches the pose and its own point only); S is the pose
    block of J^T J with every track's point marginalized out, px^2 per (rad or m)^2. n = 6, or 7 with
    the time offset (px^2 per s^2 for it), when S also holds the prior's row.
    """
    n = problem.n_pose
    blocks = problem.jacobian_blocks(x)
    U, V = _diagonal_blocks(blocks, problem.tracks)
    W = _per_track_sum(np.einsum("pki,pkj->pij", blocks[:, :, :n], blocks[:, :, n:]), problem.tracks)
    V_inv = np.linalg.inv(V + 1e-12 * np.eye(3))
    S = U - np.einsum("tij,tjk,tlk->il", W, V_inv, W)
    prior = problem.prior_row()
    return blocks, W, V_inv, S if prior is None else S + np.outer(prior, prior)


def _schur_information(problem: _Problem, x: FloatArray) -> FloatArray:
    """U - W V^-1 W^T (6, 6): the pose block of J^T J at x with every track's point marginalized out."""
    return _schur_parts(problem, x)[3]


def pose_covariance(problem: _Problem, x: FloatArray, sigma2: float) -> FloatArray:
    """Covariance (6, 6) of the pose block at x: sigma^2 (U - W V^-1 W^T)^-1 (Schur complement).

    With the time offset it is (7, 7), of (omega, tau, s).

    Args:
        problem: the bundle adjustment.
        x: (n + 3T,) its parameters (pose perturbation [and s], then the tracks' camera-frame points).
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
    n_pose = problem.n_pose
    Jp, Jx = blocks[:, :, :n_pose], blocks[:, :, n_pose:]
    r = residuals[:2 * problem.tracks.uv.shape[0]].reshape(-1, 2)  # the observations' (not the prior's)
    tracks = problem.tracks
    g = (_per_track_sum(np.einsum("pki,pk->pi", Jp, r), tracks)
         - np.einsum("tij,tjk,tk->ti", W, V_inv, _per_track_sum(np.einsum("pki,pk->pi", Jx, r), tracks)))
    S_inv = np.linalg.inv(S)
    T, m, n = tracks.n_tracks, r.size, x.size
    scale = T / max(T - 1, 1) * m / max(m - n, 1)
    C = scale * S_inv @ (g.T @ g) @ S_inv
    return sigma2 * S_inv, 0.5 * (C + C.T)


def _motion_summaries(problem: _Problem, x: FloatArray, residuals: FloatArray,
                      blocks: FloatArray | None = None) -> tuple[MotionSummary, ...]:
    """Each motion's ``MotionSummary`` at the optimum x (the time offset's prior row left out).

    ``residuals``: (2P,) float64, px, the observations' residuals at x; ``blocks``: the problem's
    ``jacobian_blocks`` at x when already computed.
    """
    return tuple(plain for _, plain in _summary_pairs(problem, x, residuals, None, blocks))


def _summary_pairs(problem: _Problem, x: FloatArray, residuals: FloatArray, track_weight: FloatArray | None,
                   blocks: FloatArray | None = None) -> list[tuple[MotionSummary, MotionSummary]]:
    """Each motion's (weighted, unweighted) ``MotionSummary`` at x from one pass over the observations.

    ``track_weight`` (T,): each track's weight on all its observations (None: the weighted one is the plain one).
    """
    n = problem.n_pose
    tracks = problem.tracks
    r = residuals.reshape(-1, 2)
    blocks = problem.jacobian_blocks(x) if blocks is None else blocks
    U, W, V, gp, gx = normal_blocks(blocks, r, np.ones(r.shape[0]), track_starts(tracks.track), per_track_pose=True)
    WVinv = np.matmul(W, np.linalg.inv(V + 1e-12 * np.eye(3)))
    g = gp - np.matmul(WVinv, gx[:, :, None])[:, :, 0]  # (T, n): each track's score, its point marginalized
    info = U - np.matmul(WVinv, W.transpose(0, 2, 1))  # (T, n, n)
    rss = np.bincount(tracks.track, weights=np.sum(r**2, axis=1), minlength=tracks.n_tracks)
    n_obs = np.bincount(tracks.track, minlength=tracks.n_tracks)
    R, t = problem.pose(x)
    T = transform_from_rt(R, t)
    s_lin = float(x[6]) if n == 7 else None
    motions, first = np.unique(tracks.motion, return_index=True)  # tracks are grouped by motion
    free = np.zeros(tracks.n_tracks, np.int64) if tracks.free_rates is None else tracks.free_rates.astype(np.int64)

    def summary(m: int, a: int, b: int, w: FloatArray | None) -> MotionSummary:
        H = info[a:b].sum(axis=0) if w is None else np.einsum("t,tij->ij", w, info[a:b])
        gw = g[a:b] if w is None else g[a:b] * w[:, None]
        rss_m = float(rss[a:b].sum() if w is None else w @ rss[a:b])
        return MotionSummary(int(m), T, s_lin, 0.5 * (H + H.T), gw.sum(axis=0), gw.T @ gw, rss_m,
                             2 * int(n_obs[a:b].sum()) - free[a:b].sum(), int(b - a))

    out = []
    for m, a, b in zip(motions, first, np.append(first[1:], tracks.n_tracks), strict=True):
        plain = summary(m, a, b, None)
        out.append((plain if track_weight is None else summary(m, a, b, track_weight[a:b]), plain))
    return out


def _summary_offsets(summaries: Sequence[MotionSummary], T0: FloatArray, s0: float | None) -> FloatArray:
    """(M, n): each summary's pose parameters d at the anchor (T0, s0): Log(R0 R_lin^T), t0 - t_lin[, s0 - s_lin].

    To first order in the rotations' difference (they are within a few sigma of each other).
    """
    xi = pose_difference(np.array([m.T_lin for m in summaries]), T0)
    if s0 is None:
        return xi
    return np.column_stack([xi, [s0 - (m.time_offset_lin or 0.0) for m in summaries]])


def summaries_prior(summaries: Sequence[MotionSummary], T0: FloatArray, s0: float | None = None) -> PosePrior:
    """The summed cost of ``summaries`` as a quadratic in the pose parameters about (T0, s0).

    Args:
        summaries: the earlier motions (``MotionSummary``), all of the same pose size n.
        T0: (4, 4) float64: the anchor pose (the parameters' zero).
        s0: s, the anchor's time offset (None: no time offset, n = 6); 0 when the parameter is s itself.
    """
    d = _summary_offsets(summaries, T0, s0)
    H = sum(m.information for m in summaries)
    g = sum(m.information @ dm + m.gradient for m, dm in zip(summaries, d, strict=True))
    c = sum(0.5 * dm @ m.information @ dm + m.gradient @ dm + 0.5 * m.rss for m, dm in zip(summaries, d, strict=True))
    return PosePrior(np.asarray(H, dtype=np.float64), np.asarray(g, dtype=np.float64), float(c))


#: ``_symmetric_inverse``: an information matrix whose smallest eigenvalue is at most this fraction of its largest is
#: singular. Rounding leaves null directions near 1e-15; the weakest held direction seen, the weak prior on the free
#: directions beside what the tracks fix (``refine``'s ``free_direction``), sits near 1.7e-10.
SINGULAR_RCOND = 1e-12


def _symmetric_inverse(S: FloatArray) -> FloatArray:
    """The inverse (n, n) of a symmetric positive definite S (n, n) from its eigen-decomposition.

    Symmetric to rounding and positive definite however far apart S's eigenvalues lie (a weak prior on the
    directions the tracks leave free beside their information on the rest: a condition number near 1e10). An LU
    inverse is not symmetric there (seen: entries 5e-6 apart across the diagonal where the largest is 93 and the
    smallest variance 1.7e-8), and a Cholesky reads one triangle: ``conservative_covariance`` then found its model
    covariance not positive definite (a realistic 720p xArm 6, an adjustment held in every direction).

    S is singular when its smallest eigenvalue is at most ``SINGULAR_RCOND`` times its largest: rounding alone
    leaves such a direction's eigenvalue at either sign (seen: 9.4e-16 and 9.9e-16 of the largest on four motions whose
    axes meet in a point, with the depth not held), and its "variance" (there 1.9e5 m) is no estimate.

    Raises:
        np.linalg.LinAlgError: S is not positive definite, or singular to rounding.
    """
    lam, V = np.linalg.eigh(0.5 * (S + S.T))
    if not lam[0] > SINGULAR_RCOND * lam[-1]:
        raise np.linalg.LinAlgError("the information matrix is not positive definite (singular to rounding: "
                                    f"smallest eigenvalue {lam[0]:.3g} of the largest {lam[-1]:.3g})")
    return (V / lam) @ V.T


def summaries_covariance(summaries: Sequence[MotionSummary], prior_row: FloatArray | None = None,
                         T0: FloatArray | None = None, s0: float | None = None,
                         motion_clusters: bool = True, motion_jackknife: bool = True,
                         motion_dispersion: bool = True, gauge: FloatArray | None = None
                         ) -> tuple[FloatArray, float, FloatArray]:
    """The pose covariance (n, n) of all ``summaries``, the residual sigma (px) and the covariance before the jackknife.

    The model's covariance, enlarged where the track-clustered sandwich is larger and, with
    ``motion_clusters``, where the motion-clustered one is: S^-1 (sum_m g_m g_m^T) S^-1 with g_m motion m's
    score at the pose (its summary's gradient moved there by its information), scaled by M / (M - 1)
    and the fitted parameters. Errors shared by a whole sweep (its blur, its timing, the surface it shows)
    are correlated across that motion's tracks; the track-clustered estimate misses them.

    Args:
        summaries: every motion's summary.
        prior_row: (n,) the time offset's prior residual's row, counted once.
        T0: (4, 4) the pose the covariance is for (the summaries' own linearization points when None).
        s0: s, the time offset there (with n = 7).
        motion_clusters: also take the motion-clustered sandwich (needs 3 motions or more).
        motion_jackknife: with ``motion_clusters``, also take the leave-one-motion-out jackknife
            (``motion_jackknife_covariance``) when the motions' scores are over-dispersed
            (``motion_overdispersion`` above its chi-square quantile at ``JACKKNIFE_TEST_LEVEL``): the
            sandwich's scores are taken at an optimum each motion helped to set, so with few motions, or one
            motion that alone fixes a direction, it is too small.
        motion_dispersion: with ``motion_clusters``, under the same test also take the model's covariance
            scaled by the motions' dispersion Q / dof (``motion_overdispersion``: how many times more spread
            their scores are than independent pixel noise makes them; the quasi-likelihood scale). The
            jackknife of M motions has rank M - 1 at most and, with few motions, misses whole directions
            this one covers.
        gauge: (n, n) px^2 per unit^2, a weak prior's information on a direction the tracks leave free (``refine``'s
            ``free_direction``), added to the model's.
    """
    S = sum(m.information for m in summaries)
    if prior_row is not None:
        S = S + np.outer(prior_row, prior_row)
    if gauge is not None:
        S = S + gauge
    meat = sum(m.meat for m in summaries)
    m_res = sum(m.n_residuals for m in summaries)
    T = sum(m.n_tracks for m in summaries)
    n_par = 3 * T + S.shape[0]
    sigma2 = sum(m.rss for m in summaries) / max(m_res - n_par, 1)
    S_inv = _symmetric_inverse(S)
    dof = m_res / max(m_res - n_par, 1)
    C = T / max(T - 1, 1) * dof * S_inv @ meat @ S_inv
    cov = conservative_covariance(sigma2 * S_inv, C)
    M = len(summaries)
    if motion_clusters and M >= 3:
        H = np.array([m.information for m in summaries])
        g = np.array([m.gradient for m in summaries])
        if T0 is not None:
            g = g + np.einsum("mij,mj->mi", H, _summary_offsets(summaries, T0, s0))
        C_motion = M / (M - 1) * dof * S_inv @ (g.T @ g) @ S_inv
        cov = conservative_covariance(cov, C_motion)
        if motion_jackknife or motion_dispersion:
            q, q_dof = motion_overdispersion(H, g, S, sigma2)
            if q_dof > 0 and q > chi2.ppf(1.0 - JACKKNIFE_TEST_LEVEL, q_dof):
                wide = cov
                if motion_jackknife:
                    wide = conservative_covariance(wide, dof * motion_jackknife_covariance(H, g, S))
                if motion_dispersion:
                    wide = conservative_covariance(wide, q / q_dof * sigma2 * S_inv)
                return wide, float(np.sqrt(sigma2)), cov
    return cov, float(np.sqrt(sigma2)), cov


#: The jackknife is taken only where the motions' scores are over-dispersed at this level (``motion_overdispersion``):
#: with independent pixel noise it would only add its own sampling noise (seen: synthetic all-track episodes' 95 %
#: regions held the truth 74 times in 74 with it always on, against 0.97 without).
JACKKNIFE_TEST_LEVEL = 0.01


#: The jackknife's largest leverage of one motion along a direction (``motion_jackknife_covariance``): a motion
#: that alone fixes a direction (leverage 1) would leave it undetermined without it; capped, its shift is taken
#: as 1 / (1 - 0.9) = 10 times its one-step pull.
JACKKNIFE_MAX_LEVERAGE = 0.9


def motion_overdispersion(information: FloatArray, gradient: FloatArray, S: FloatArray,
                          sigma2: float) -> tuple[float, int]:
    """Whether the motions' scores at the optimum are more spread than independent pixel noise makes them.

    With independent noise of variance sigma2 (px^2), motion m's score g_m (n,) at the joint optimum has
    covariance sigma2 (H_m - H_m S^-1 H_m); whitened by S^-1/2 that is sigma2 U diag(l (1 - l)) U^T for the
    eigen-decomposition U diag(l) U^T of its leverage P_m = S^-1/2 H_m S^-1/2. Returns Q, the sum over motions
    and eigen-directions with 0.01 < l < 0.9 of (U^T S^-1/2 g_m)^2 / (sigma2 l (1 - l)), and the number of
    those terms: about chi-square with that many degrees of freedom when the noise is independent, far above
    it when errors are shared by a sweep (its blur, timing or sliding tracks).

    Args:
        information: (M, n, n) each motion's information H_m, px^2 per parameter^2.
        gradient: (M, n) each motion's score g_m at the optimum.
        S: (n, n) the total information, positive definite.
        sigma2: px^2, the pixel noise variance; (0.0, 0) when it is not positive (noise-free residuals
            carry no evidence of spread).
    """
    if not sigma2 > 0:
        return 0.0, 0
    _, lev, _, u = _whitened_leverages(information, gradient, S)
    ok = (lev > 0.01) & (lev < JACKKNIFE_MAX_LEVERAGE)
    return float(np.sum(u[ok] ** 2 / (sigma2 * lev[ok] * (1.0 - lev[ok])))), int(ok.sum())


def _whitened_leverages(information: FloatArray, gradient: FloatArray, S: FloatArray
                        ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """S^-1/2 (n, n) and each motion's leverage eigen-decomposition with its whitened score in that basis.

    With P_m = S^-1/2 H_m S^-1/2 = U_m diag(l_m) U_m^T returns (S^-1/2, l (M, n), U (M, n, n),
    U_m^T S^-1/2 g_m (M, n)) for ``motion_overdispersion`` and ``motion_jackknife_covariance``.
    """
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    S_ih = (V / np.sqrt(w)) @ V.T  # S^-1/2
    H = np.asarray(information, dtype=np.float64)
    lev, U = np.linalg.eigh(S_ih @ (0.5 * (H + np.swapaxes(H, 1, 2))) @ S_ih)  # (M, n), (M, n, n)
    u = np.einsum("mji,mj->mi", U, np.asarray(gradient, dtype=np.float64) @ S_ih)
    return S_ih, lev, U, u


def motion_jackknife_covariance(information: FloatArray, gradient: FloatArray, S: FloatArray,
                                max_leverage: float = JACKKNIFE_MAX_LEVERAGE) -> FloatArray:
    """Leave-one-motion-out jackknife covariance (n, n) of the pose at a least-squares optimum.

    Motion m's estimate without it is, to first order, x_-m = x + (S - H_m)^-1 g_m (exact for linear least
    squares), with H_m (n, n) its information, g_m (n,) its score J_m^T r_m at the optimum and S (n, n) the
    total information; the jackknife is (M - 1) / M sum_m (d_m - d_mean)(d_m - d_mean)^T of d_m = x_-m - x
    (CR3, the cluster-robust estimate that stays honest with few clusters). Written with the leverage
    P_m = S^-1/2 H_m S^-1/2 as d_m = S^-1/2 (I - P_m)^-1 S^-1/2 g_m, whose eigenvalues are capped at
    ``max_leverage`` so a motion that alone fixes a direction gives a bounded shift.

    Args:
        information: (M, n, n) each motion's information H_m.
        gradient: (M, n) each motion's score g_m at the optimum.
        S: (n, n) the total information (the H_m and any prior), positive definite.
        max_leverage: cap on P_m's eigenvalues, in [0, 1).
    """
    if not 0 <= max_leverage < 1:
        raise InvalidInputError(f"max_leverage must be in [0, 1), got {max_leverage}")
    M = len(gradient)
    S_ih, lev, U, u = _whitened_leverages(information, gradient, S)
    d = np.einsum("mij,mj->mi", U, u / (1.0 - np.clip(lev, 0.0, max_leverage))) @ S_ih  # (M, n)
    dc = d - d.mean(axis=0)
    out = (M - 1) / M * dc.T @ dc
    return 0.5 * (out + out.T)


def newest_motion_leverage(summaries: Sequence[MotionSummary]) -> float:
    """The largest share (0..1) of the pose information the last summary's motion carries in any direction.

    The largest eigenvalue of its leverage S^-1/2 H_m S^-1/2 with H_m its information and S the sum of every
    summary's: 1 when the motion alone fixes some direction of the pose, near 0 when its tracks add next to
    nothing to what the others say. Its estimate then repeats the one before (``ConvergenceConfig.min_leverage``).

    Raises:
        InvalidInputError: no summaries, or their total information is not positive definite.
    """
    if not summaries:
        raise InvalidInputError("newest_motion_leverage needs at least one motion summary")
    H = np.array([m.information for m in summaries], dtype=np.float64)
    S = H.sum(axis=0)
    if not np.all(np.isfinite(S)) or np.linalg.eigvalsh(0.5 * (S + S.T))[0] <= 0:
        raise InvalidInputError("the motions' total information is not positive definite")
    _, lev, _, _ = _whitened_leverages(H[-1:], np.zeros((1, S.shape[0])), S)
    return float(np.clip(lev.max(), 0.0, 1.0))


def few_clusters_factor(clusters: int, level: float = 0.95) -> float:
    """How much wider a variance known from ``clusters`` independent clusters must be taken: (t_{G-1}(q) / z(q))^2.

    q = (1 + level) / 2; t_{G-1} is Student's t with G - 1 degrees of freedom, z the normal's quantile. An interval
    of ``level`` from a variance estimated from G clusters is t_{G-1}(q) standard errors wide, not z(q): this factor
    on the variance makes the normal's interval that wide (G = 3: 4.82, 4: 2.64, 5: 2.01, 6: 1.72; 1 as G grows).

    Raises:
        InvalidInputError: fewer than 2 clusters, or a level outside (0, 1).
    """
    if clusters < 2 or not 0.0 < level < 1.0:
        raise InvalidInputError(f"need at least 2 clusters and a level in (0, 1), got {clusters} and {level}")
    q = 0.5 * (1.0 + level)
    return float((student_t.ppf(q, clusters - 1) / norm.ppf(q)) ** 2)


def conservative_covariance(model: FloatArray, clustered: FloatArray) -> FloatArray:
    """The smallest covariance (6, 6) at least as large as both, in the model's eigen-directions.

    With C v = l M v (generalized eigenvectors, V^T M V = I), returns M V diag(max(l, 1)) V^T M:
    ``model`` where the clustered estimate is smaller, the clustered one where it is larger. Both are
    symmetrized first: ``eigh`` reads one triangle, and an inverse by LU leaves them asymmetric by rounding.
    """
    model = 0.5 * (model + model.T)
    lam, V = eigh(0.5 * (clustered + clustered.T), model)
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


#: ``refine``'s weak prior along a free direction: one pixel of cost per this many units (rad or m) of the direction,
#: i.e. a 1-sigma of about sigma_px x 10 m along it: the tracks' information on any direction they fix is 1e6 times or
#: more (px^2 per m^2), and an outline fit that follows adds ~1e5 per m^2 or more, so the prior changes neither.
GAUGE_PX_PER_UNIT = 0.1


def _free_projector(free_direction: FloatArray) -> FloatArray:
    """The orthogonal projector (6, 6) onto the span of (6,) or (k, 6) directions, or InvalidInputError."""
    w = np.asarray(free_direction, dtype=np.float64)
    w = w.reshape(1, -1) if w.ndim == 1 else w
    if w.ndim != 2 or w.shape[1] != 6 or not 1 <= w.shape[0] <= 6 or not np.all(np.isfinite(w)):
        raise InvalidInputError("the free directions must be a finite (6,) or (k, 6) array, 1 <= k <= 6")
    Q, R = np.linalg.qr(w.T)  # (6, k), (k, k)
    diag = np.abs(np.diag(R))
    if diag.min() <= 1e-9 * max(float(diag.max()), 1e-300):
        raise InvalidInputError("the free directions must be non-zero and independent")
    return Q @ Q.T


def refine(tracks: TrackSet, T_init: FloatArray, config: RefinementConfig | None = None,
           points_init: FloatArray | None = None, free_direction: FloatArray | None = None) -> RefinementResult:
    """Bundle-adjust T_camera_base and the track points, starting from ``T_init``.

    With the time offset estimated (``RefinementConfig.estimate_time_offset``) it starts at 0 and
    its prior residual is weighted as one pixel of noise per ``time_offset_bound_s`` in the robust
    pass, as that pass's robust noise estimate in the final one (so the prior is s ~ N(0, bound^2)
    in both the estimate and its covariance).

    Args:
        tracks: the observations (``build_track_set``).
        T_init: (4, 4) float64: starting pose, e.g. the linear calibration.
        config: settings; defaults to ``RefinementConfig()``.
        points_init: (T, 3) float64, m: starting points; triangulated from ``T_init`` if None. Given (a warm
            start), the robust pass also ends when the pose stands still (``robust_pose_tol``).
        free_direction: (6,) a direction of (omega, tau) that the tracks may leave free (the depth of joints whose
            axes meet in one point), or (k, 6) k <= 6 independent ones (e.g. the identity: whatever the kept tracks
            leave free): a weak prior (``GAUGE_PX_PER_UNIT``) holds the pose along them where each pass starts, so
            that the adjustment and its covariance exist; the covariance says the rest honestly and, along them,
            that they are free (metres). Schur backend only.

    Raises:
        InsufficientMotionsError: fewer than two tracks survive triangulation or outlier removal.
        InvalidInputError: the time offset is to be estimated but a track carries no joint velocity; a free
            direction with the scipy backend, or not finite (6,) / (k, 6) independent directions.
        TimeOffsetError: the estimated time offset is beyond ``time_offset_bound_s``.
    """
    config = config or RefinementConfig()
    if not np.all(np.isfinite(T_init)):
        raise InvalidInputError("T_init contains NaN or infinite values")
    gauge = None
    if free_direction is not None:
        gauge = GAUGE_PX_PER_UNIT**2 * _free_projector(free_direction)
        if config.backend != "schur":
            raise InvalidInputError("a free direction needs backend='schur' (scipy's takes no pose prior)")
    tracks = replace(tracks, free_rates=np.ones(tracks.n_tracks, bool) if config.free_rates == "all" else None)
    estimate = config.estimate_time_offset
    if estimate is None:
        estimate = tracks.velocity is not None
    if estimate and tracks.velocity is None:
        raise InvalidInputError("estimate_time_offset is on but not every track carries the joint's velocity "
                                "(KeypointTrack.velocity)")
    bound = config.time_offset_bound_s
    if gauge is not None and estimate:
        gauge = np.pad(gauge, (0, 1))
    prior = None if gauge is None else PosePrior(gauge, np.zeros(len(gauge)))
    points, keep = start_points(tracks, T_init, points_init)
    sub = _subset(tracks, keep)
    T, pts, problem, x, sol = _solve(sub, T_init, points[keep], "cauchy", config.cauchy_scale_px,
                                     config.max_nfev, ftol=config.robust_ftol,
                                     time_offset=(0.0, 1.0 / bound) if estimate else None, backend=config.backend,
                                     pose_tol=config.robust_pose_tol if points_init is not None else None, prior=prior)
    res = sol.fun[:2 * sub.uv.shape[0]].reshape(-1, 2)
    sigma = robust_sigma(res)
    good = agreeing_tracks(sub, res, sigma, config) & split_agreeing_tracks(
        sub, T, config, float(x[6]) if estimate else None)
    if good.sum() < 2:
        raise InsufficientMotionsError("fewer than two tracks agree with the refined pose")
    if config.free_rates == "tested":
        sub = replace(sub, free_rates=lagging_tracks(problem, x, res))
    sub2 = _subset(sub, good)
    scale = _track_scale(sub, res, good, sigma, config) if config.track_weights else None
    T, pts2, problem, x, sol = _solve(sub2, T, pts[good], "linear", 1.0, config.max_nfev, 1e-8,
                                      time_offset=(float(x[6]), max(sigma, 1e-6) / bound) if estimate else None,
                                      backend=config.backend, scale=scale, prior=prior)
    fun = sol.fun[:2 * sub2.uv.shape[0]]  # the observations' residuals (the prior's is last, with s)
    raw = fun if scale is None else (fun.reshape(-1, 2) / scale[:, None]).ravel()  # px, unweighted
    summaries = _with_unweighted(problem, x, fun, raw, scale)
    prior_row = problem.prior_row()
    cov, sigma_fit, sandwich = summaries_covariance(summaries, prior_row, motion_clusters=config.motion_clusters,
                                                     motion_jackknife=config.motion_jackknife,
                                                     motion_dispersion=config.motion_dispersion, gauge=gauge)
    cov = weighted_covariance_bound(cov, summaries, prior_row, None, None, config, gauge)
    cov, offset, offset_std, correlation = _split_time_offset(cov, x, bound) if estimate else (cov, None, None, None)
    inliers, all_points = kept_points(tracks.n_tracks, keep, good, pts2)
    return RefinementResult(T, cov, all_points, inliers, float(np.sqrt(np.mean(raw**2))),
                            sigma_fit, offset, offset_std, correlation, summaries, sigma, sandwich[:6, :6])


def reprojection_residuals(tracks: TrackSet, result: RefinementResult) -> FloatArray:
    """(P, 2) px: every observation's reprojection error under a refinement of ``tracks`` (NaN: a dropped track).

    The refinement's pose, points and, when it estimated one, time offset; unweighted.
    """
    s = result.time_offset_s
    problem = _Problem(tracks, result.T_camera_base, prior_weight=None if s is None else 1.0)
    R, t = result.T_camera_base[:3, :3], result.T_camera_base[:3, 3]
    x = np.concatenate([np.zeros(problem.n_pose), (result.points_base @ R.T + t).ravel()])
    if s is not None:
        x[6] = s
    return problem.residuals(x)[:2 * tracks.uv.shape[0]].reshape(-1, 2)


def refine_increment(tracks: TrackSet, T0: FloatArray, earlier: Sequence[MotionSummary], sigma_px: float,
                     config: RefinementConfig | None = None, time_offset_s: float | None = None,
                     n_earlier_residuals: int | None = None) -> RefinementResult:
    """Add new motions' tracks to an adjustment whose earlier motions are summarized (incremental, ours).

    The earlier motions enter only through their ``MotionSummary`` (their points marginalized,
    linearized where they were last solved: ``summaries_prior``); the pose and the new tracks' points
    are solved as in ``refine`` (a Cauchy pass, the tracks far off the noise dropped, a least-squares
    pass), with the outlier threshold from the robust sigma pooled over the earlier (``sigma_px``) and
    the new residuals. Exact to first order in the pose's move from the summaries' linearization points:
    relinearize (``refine`` over every motion) when it moves by a good fraction of its 1-sigma.

    Args:
        tracks: the new motions' observations (``build_track_set``; ``motion`` indices distinct from the
            earlier ones').
        T0: (4, 4) float64: the pose to start from (the last estimate).
        earlier: the earlier motions' summaries (``RefinementResult.summaries``), non-empty.
        sigma_px: px, the earlier adjustment's robust noise estimate (``RefinementResult.robust_sigma_px``).
        config: settings (the Schur backend is used whatever ``config.backend`` says: scipy's takes no prior).
        time_offset_s: s, the current time-offset estimate when it is estimated (the summaries then have n = 7).
        n_earlier_residuals: residuals behind ``sigma_px`` (default: the summaries').

    Returns:
        The result over all motions: pose and covariance (from every summary, the new ones included), the
        new tracks' points and inliers, and the new motions' summaries appended to ``earlier``.
    """
    config = config or RefinementConfig()
    if not earlier:
        raise InvalidInputError("refine_increment needs the earlier motions' summaries (run refine first)")
    tracks = replace(tracks, free_rates=np.ones(tracks.n_tracks, bool) if config.free_rates == "all" else None)
    estimate = earlier[0].time_offset_lin is not None
    if estimate and (tracks.velocity is None or time_offset_s is None):
        raise InvalidInputError("the earlier motions estimate the time offset: the new tracks need joint velocities "
                                "and time_offset_s the current estimate")
    bound = config.time_offset_bound_s
    points, keep = start_points(_turned_by_offset(tracks, time_offset_s) if estimate else tracks, T0, what="new tracks")
    sub = _subset(tracks, keep)
    # The time offset is the problem's 7th parameter itself (not a change from an anchor): the prior's s0 is 0.
    prior = summaries_prior(earlier, T0, 0.0 if estimate else None)
    s0 = float(time_offset_s) if estimate else None
    T, pts, problem, x, sol = _solve(sub, T0, points[keep], "cauchy", config.cauchy_scale_px, config.max_nfev,
                                     ftol=config.robust_ftol, time_offset=(s0, 1.0 / bound) if estimate else None,
                                     prior=prior)
    res = sol.fun[:2 * sub.uv.shape[0]].reshape(-1, 2)
    n_old = sum(m.n_residuals for m in earlier) if n_earlier_residuals is None else n_earlier_residuals
    sigma_new = robust_sigma(res)
    sigma = float(np.sqrt((n_old * sigma_px**2 + res.size * sigma_new**2) / (n_old + res.size)))
    good = agreeing_tracks(sub, res, sigma, config) & split_agreeing_tracks(
        sub, T, config, float(x[6]) if estimate else None)
    if good.sum() < 1:
        raise InsufficientMotionsError("no new track agrees with the refined pose")
    if config.free_rates == "tested":
        sub = replace(sub, free_rates=lagging_tracks(problem, x, res))
    sub2 = _subset(sub, good)
    scale = _track_scale(sub, res, good, sigma, config) if config.track_weights else None
    # The summaries' pose parameters are about T0; after the robust pass the anchor moves to its pose.
    s1 = float(x[6]) if estimate else None
    prior = summaries_prior(earlier, T, 0.0 if estimate else None)
    T, pts2, problem, x, sol = _solve(sub2, T, pts[good], "linear", 1.0, config.max_nfev, 1e-8,
                                      time_offset=(s1, max(sigma, 1e-6) / bound) if estimate else None,
                                      scale=scale, prior=prior)
    fun = sol.fun[:2 * sub2.uv.shape[0]]
    raw = fun if scale is None else (fun.reshape(-1, 2) / scale[:, None]).ravel()
    summaries = tuple(earlier) + _with_unweighted(problem, x, fun, raw, scale)
    s_now = float(x[6]) if estimate else None
    prior_row = problem.prior_row()
    cov, sigma_fit, sandwich = summaries_covariance(summaries, prior_row, T, s_now, config.motion_clusters,
                                                     config.motion_jackknife, config.motion_dispersion)
    cov = weighted_covariance_bound(cov, summaries, prior_row, T, s_now, config)
    cov, offset, offset_std, correlation = _split_time_offset(cov, x, bound) if estimate else (cov, None, None, None)
    inliers, all_points = kept_points(tracks.n_tracks, keep, good, pts2)
    return RefinementResult(T, cov, all_points, inliers, float(np.sqrt(np.mean(raw**2))),
                            sigma_fit, offset, offset_std, correlation, summaries, sigma, sandwich[:6, :6])


@dataclass(frozen=True)
class _SubspaceResult:
    """Where ``_trf_subspace`` ended: the whitened parameters x and the residuals fun (2P,) px there."""

    x: FloatArray
    fun: FloatArray


class _BlockOperator:
    """A Jacobian (2P, n + 3T) given by its observations' blocks (P, 2, n + 3).

    Each observation touches the pose's n columns and its track's 3 (observations grouped by track, ``track``
    (P,) their tracks, ``starts`` (T,) the first of each).
    """

    def __init__(self, blocks: FloatArray, track: NDArray[np.int64], starts: NDArray[np.int64]):
        self.blocks, self.track, self.starts = blocks, track, starts
        self.n = blocks.shape[2] - 3

    def dot(self, v: FloatArray) -> FloatArray:
        """J v (2P,) for v (n + 3T,)."""
        n = self.n
        q = v[n:].reshape(-1, 3)[self.track]  # (P, 3)
        return (self.blocks[:, :, :n] @ v[:n] + np.einsum("pki,pi->pk", self.blocks[:, :, n:], q)).ravel()

    def damped_solution(self, f: FloatArray, damp: float) -> FloatArray:
        """Argmin |J x - f|^2 + damp^2 |x|^2 (n + 3T,), exactly: the normal equations through the Schur complement.

        Without damping a J that leaves a direction unseen (a point or pose direction no observation moves) makes
        the normal equations singular: then a least-squares solution through pseudo-inverses (as LSMR, which
        scipy's TRF uses here, would give one) instead of numpy's "Singular matrix".
        """
        n = self.n
        U, W, V, gp, gx = normal_blocks(self.blocks, f.reshape(-1, 2), np.ones(self.blocks.shape[0]), self.starts)
        d2 = damp * damp
        try:
            V_inv = np.linalg.inv(V + d2 * np.eye(3))
        except np.linalg.LinAlgError:
            V_inv = np.linalg.pinv(V + d2 * np.eye(3), hermitian=True)
        WV = np.matmul(W, V_inv)  # (T, n, 3)
        S = U + d2 * np.eye(n) - np.einsum("tij,tkj->ik", WV, W)
        rhs = gp - np.einsum("tij,tj->i", WV, gx)
        try:
            xp = np.linalg.solve(S, rhs)
        except np.linalg.LinAlgError:
            xp = np.linalg.lstsq(S, rhs, rcond=None)[0]
        xq = np.matmul(V_inv, (gx - np.einsum("tji,j->ti", W, xp))[:, :, None])[:, :, 0]
        return np.concatenate([xp, xq.ravel()])


def _trf_subspace(white: _Whitened, f_scale: float, max_nfev: int, ftol: float, xtol: float = 1e-10,
                  gtol: float = 1e-8) -> _SubspaceResult:
    """Scipy's ``least_squares(method="trf", loss="cauchy", tr_solver="lsmr", x_scale=_TRUST_SCALE)`` from z = 0.

    The same iteration (scipy 1.17's ``trf_no_bounds``: Triggs' robust scaling, the regularized Gauss-Newton
    step, the two-dimensional subspace of it and the gradient, the radius updates and the ftol/xtol/gtol
    tests, with scipy's own helpers), with that Gauss-Newton step solved exactly through the Schur complement
    over the points (``_BlockOperator.damped_solution``) instead of by LSMR (to 1e-12 there), without LSMR's
    hundreds of sparse products per step. The two differ where LSMR is inexact, along directions the
    Gauss-Newton matrix nearly leaves free: on well-posed synthetic scenes by under 1 % of the pass's move
    (tests), on a weakly posed one (3 motions of 4 tracks) by 2 cm at an equal cost; the 10 captured
    realistic episodes of issue 18 gave the same family starts and decisions with either (poses within
    2.2e-5 of their 1-sigma). The screening of the pose family (``screen_start``) was tuned with scipy's pass.
    """
    problem = white.problem
    track, starts = problem.tracks.track, track_starts(problem.tracks.track)
    c2 = f_scale ** 2
    x = np.zeros(problem.n_pose + 3 * problem.tracks.n_tracks)
    f_true = white.residuals(x)
    nfev = 1

    def robust(f: FloatArray, blocks: FloatArray) -> tuple[float, _BlockOperator, FloatArray, FloatArray]:
        # scipy's cauchy rho and scale_for_robust_loss_function: rows of J and f scaled
        z = f ** 2 / c2
        rho1, rho2 = 1.0 / (1.0 + z), -1.0 / (1.0 + z) ** 2 / c2
        scale = rho1 + 2 * rho2 * f ** 2
        scale[scale < np.finfo(float).eps] = np.finfo(float).eps
        scale **= 0.5
        fs = f * (rho1 / scale)
        J = _BlockOperator(blocks * scale.reshape(-1, 2, 1), track, starts)
        g = np.concatenate([np.einsum("pki,pk->i", J.blocks[:, :, :J.n], fs.reshape(-1, 2)),
                            np.add.reduceat(np.einsum("pki,pk->pi", J.blocks[:, :, J.n:], fs.reshape(-1, 2)),
                                            starts).ravel()])
        return 0.5 * c2 * float(np.sum(np.log1p(z))), J, fs, g

    cost, J, f, g = robust(f_true, white.jacobian_blocks(x))
    d = _TRUST_SCALE
    Delta = 1.0  # norm(x0 / scale) is 0
    while nfev < max_nfev and np.max(np.abs(g)) >= gtol:
        g_h = d * g
        J_h = _BlockOperator(J.blocks * d, track, starts)
        v = J_h.dot(-g_h)
        _, ag_value = minimize_quadratic_1d(0.5 * float(v @ v), float(-(g_h @ g_h)), 0, Delta / np.linalg.norm(g_h))
        gn_h = J_h.damped_solution(f, (-ag_value / Delta ** 2) ** 0.5)
        S, _ = np.linalg.qr(np.vstack((g_h, gn_h)).T)
        JS = np.column_stack([J_h.dot(S[:, 0]), J_h.dot(S[:, 1])])
        B_S, g_S = JS.T @ JS, S.T @ g_h
        actual_reduction, status = -1.0, None
        while actual_reduction <= 0 and nfev < max_nfev:
            p_S, _ = solve_trust_region_2d(B_S, g_S, Delta)
            step_h = S @ p_S
            Js = J_h.dot(step_h)
            predicted_reduction = -(0.5 * float(Js @ Js) + float(g_h @ step_h))
            step = d * step_h
            x_new = x + step
            f_new = white.residuals(x_new)
            nfev += 1
            step_h_norm = float(np.linalg.norm(step_h))
            if not np.all(np.isfinite(f_new)):
                Delta = 0.25 * step_h_norm
                continue
            cost_new = 0.5 * c2 * float(np.sum(np.log1p(f_new ** 2 / c2)))
            actual_reduction = cost - cost_new
            Delta_new, ratio = update_tr_radius(Delta, actual_reduction, predicted_reduction, step_h_norm,
                                                step_h_norm > 0.95 * Delta)
            status = check_termination(actual_reduction, cost, float(np.linalg.norm(step)), float(np.linalg.norm(x)),
                                       ratio, ftol, xtol)
            if status is not None:
                break
            Delta = Delta_new
        if actual_reduction > 0:
            x, f_true = x_new, f_new
            if status is not None:
                break
            cost, J, f, g = robust(f_true, white.jacobian_blocks(x))
        elif status is not None:
            break
    return _SubspaceResult(x, f_true)


def screen_start(tracks: TrackSet, T_init: FloatArray, config: RefinementConfig, max_nfev: int,
                 cap_px: float) -> tuple[FloatArray, float]:
    """A short robust pass of the bundle adjustment from ``T_init``, scored so that starts compare.

    The points are triangulated from ``T_init`` and the pose and points take at most ``max_nfev``
    evaluations of the Cauchy pass (``refine``'s first). The score is the mean over every
    observation of min(r^2, cap_px^2) per coordinate, r the residual where the pass ended, and
    cap_px^2 for every observation of a track that could not be triangulated (behind the camera):
    a start that leaves tracks out is not rewarded for it. The pass is scipy's TRF (its iteration with
    exact subspace steps, ``_trf_subspace``) whatever ``config.backend`` says: the screening's scale (how far
    a member gets in ``max_nfev`` evaluations) was measured with it, and the Schur backend's Gauss-Newton
    steps reach the optimum from much farther within them, which would leave members indistinguishable.

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
    problem = _Problem(_subset(tracks, ok), T_init, None, None)
    q0 = points[ok] @ T_init[:3, :3].T + T_init[:3, 3]  # the points in the camera frame, as ``_solve`` starts
    white = _Whitened(problem, np.concatenate([np.zeros(6), q0.ravel()]))
    sol = _trf_subspace(white, config.cauchy_scale_px, max_nfev, config.robust_ftol)
    T = perturb(T_init, white.native(sol.x)[:6])
    n_left_out = int(np.sum(~ok[tracks.track]))
    total = float(np.sum(np.minimum(sol.fun**2, cap_px**2))) + 2 * n_left_out * cap_px**2
    return T, total / (2 * tracks.track.size)


def linear_track_scores(tracks: TrackSet, poses: FloatArray, cap_px: float) -> FloatArray:
    """How well each pose lets every track be one rigid point, without an adjustment: (N,) px^2, comparable.

    At each of poses (N, 4, 4), each track's point is triangulated linearly (``triangulate_tracks``); the score is
    the mean over every observation of min(r^2, cap_px^2) per coordinate, r its reprojection residual, and cap_px^2
    for every observation of a track that cannot be triangulated or falls behind the camera (as ``screen_start``,
    with no pass of the adjustment: thousands of poses can be scored, e.g. ``solver.one_axis.search_one_axis``; a
    few at a time, together).
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    scores = np.empty(len(poses))
    chunk = max(1, _SCORED_OBSERVATIONS // max(tracks.track.size, 1))
    for start in range(0, len(poses), chunk):
        _, ok, pc = _triangulated_at(tracks, poses[start:start + chunk])
        good = ok[:, tracks.track]  # (an ok track's every observation is in front of the camera)
        pc[~good, 2] = 1.0  # any depth: these observations cost the cap
        r2 = np.minimum(np.sum(track_pixel_residuals(tracks, pc) ** 2, axis=2) / 2, cap_px**2)
        scores[start:start + chunk] = np.mean(np.where(good, r2, cap_px**2), axis=1)
    return scores


def start_points(tracks: TrackSet, T_init: FloatArray, points_init: FloatArray | None = None,
                 what: str = "tracks") -> tuple[FloatArray, NDArray[np.bool_]]:
    """Where an adjustment's points start: (T, 3) m base-frame points and (T,) bool, the tracks it can use.

    Triangulated from ``T_init`` (``triangulate_tracks``); rows of ``points_init`` (T, 3) that are finite
    replace them (a warm start).

    Raises:
        InsufficientMotionsError: fewer than two of the ``what`` can be triangulated.
    """
    points, keep = triangulate_tracks(tracks, T_init)
    if points_init is not None:
        points = np.where(np.isfinite(points_init).all(axis=1)[:, None], points_init, points)
    if keep.sum() < 2:
        raise InsufficientMotionsError(f"fewer than two {what} could be triangulated from the pose")
    return points, keep


def agreeing_tracks(tracks: TrackSet, res: FloatArray, sigma: float, config: RefinementConfig) -> NDArray[np.bool_]:
    """(T,) bool: the tracks whose RMS residual (per coordinate) is within the outlier bound.

    ``res`` (P, 2) px are the robust pass's residuals of ``tracks``; the bound is the larger of
    ``config.outlier_px`` and ``config.outlier_sigmas`` times ``sigma`` px.
    """
    counts = np.maximum(np.bincount(tracks.track, minlength=tracks.n_tracks), 1)
    track_rms = np.sqrt(np.bincount(tracks.track, weights=np.sum(res**2, axis=1), minlength=tracks.n_tracks)
                        / counts / 2)
    return track_rms <= max(config.outlier_px, config.outlier_sigmas * sigma)


#: Frames each half of a track needs for ``split_half_residuals`` (fewer: the track is not tested).
SPLIT_MIN_FRAMES = 4


def split_half_residuals(tracks: TrackSet, T_camera_base: FloatArray) -> FloatArray:
    """(T,) px: how far a point fitted to one half of each track's frames misses the other half, at the given pose.

    Each track's observations are cut in two (the first M // 2 frames, the rest); a point is triangulated from
    each half alone (``triangulate_tracks``, linear) and reprojected into the other half's frames; the result is
    the larger of the two RMS pixel distances. A point fixed on the link fits both halves with one point; a corner
    that slides (along an outline, with a highlight) fits each half with a different one. NaN for tracks with fewer
    than ``SPLIT_MIN_FRAMES`` frames in a half, or whose half-point is not determined (singular, behind the camera).
    """
    starts = track_starts(tracks.track)
    counts = np.diff(np.append(starts, tracks.track.size))
    rank = np.arange(tracks.track.size) - starts[tracks.track]  # each observation's place in its track
    first = rank < (counts // 2)[tracks.track]
    testable = counts // 2 >= SPLIT_MIN_FRAMES
    out = np.full((2, tracks.n_tracks), np.nan)
    for side, (fit, other) in enumerate(((first, ~first), (~first, first))):
        points, ok = triangulate_tracks(_observations(tracks, fit), T_camera_base)
        seen = _observations(tracks, other)
        camera, _ = track_camera_points(seen, T_camera_base, points - tracks.pivot)
        with np.errstate(divide="ignore", invalid="ignore"):
            error = track_pixel_residuals(seen, camera)
        d2 = np.where(camera[:, 2] > 0, np.sum(error**2, axis=1), np.inf)
        n = np.bincount(seen.track, minlength=tracks.n_tracks)
        rms = np.sqrt(np.bincount(seen.track, weights=d2, minlength=tracks.n_tracks) / np.maximum(n, 1))
        out[side] = np.where(ok & testable & (n > 0), rms, np.nan)
    return np.where(np.isnan(out).any(axis=0), np.nan, out.max(axis=0))


def _observations(tracks: TrackSet, keep: NDArray[np.bool_]) -> TrackSet:
    """``tracks`` with only the observations keep (P,) bool; every track keeps its index, pivot and axis."""
    return replace(tracks, uv=tracks.uv[keep], track=tracks.track[keep], rot=tracks.rot[keep],
                   delta=None if tracks.delta is None else tracks.delta[keep],
                   velocity=None if tracks.velocity is None else tracks.velocity[keep], free_rates=None)


def split_agreeing_tracks(tracks: TrackSet, T_camera_base: FloatArray, config: RefinementConfig,
                          time_offset_s: float | None = None) -> NDArray[np.bool_]:
    """(T,) bool: the tracks ``RefinementConfig.max_split_px`` keeps (all when it is None; untested ones too).

    With ``time_offset_s`` (s) the observations are turned by it first (``_turned_by_offset``), only when tested.
    """
    if config.max_split_px is None:
        return np.ones(tracks.n_tracks, dtype=bool)
    if time_offset_s is not None:
        tracks = _turned_by_offset(tracks, time_offset_s)
    split = split_half_residuals(tracks, T_camera_base)
    return ~(split > config.max_split_px)  # NaN (not tested) keeps the track


def kept_points(n_tracks: int, keep: NDArray[np.bool_], good: NDArray[np.bool_], points: FloatArray
                ) -> tuple[NDArray[np.bool_], FloatArray]:
    """The inliers (T,) bool and points (T, 3) m (NaN elsewhere) of all T tracks.

    From ``keep`` (T,) the tracks triangulated, ``good`` the kept ones among those, and their ``points``.
    """
    inliers = np.zeros(n_tracks, dtype=bool)
    kept_idx = np.flatnonzero(keep)[good]
    inliers[kept_idx] = True
    all_points = np.full((n_tracks, 3), np.nan)
    all_points[kept_idx] = points
    return inliers, all_points


def _track_scale(tracks: TrackSet, res: FloatArray, good: NDArray[np.bool_], sigma: float,
                 config: RefinementConfig) -> FloatArray:
    """(P_good,) each kept observation's residual multiplier sigma / sigma_t (``RefinementConfig.track_weights``).

    ``res`` (P, 2) px are the robust pass's residuals of ``tracks``, ``good`` (T,) the tracks kept, ``sigma``
    px the common noise; returned for the observations of the kept tracks, in order.
    """
    kept = good[tracks.track]
    rss = np.bincount(tracks.track, weights=np.sum(res**2, axis=1), minlength=tracks.n_tracks)[good]
    dof = 2 * np.bincount(tracks.track[kept], minlength=tracks.n_tracks)[good] - 3
    nu = config.weight_prior_dof
    track_sigma = np.sqrt((nu * sigma**2 + rss) / (nu + np.maximum(dof, 0)))
    per_track = max(sigma, 1e-6) / np.maximum(track_sigma, 1e-6)
    return per_track[(np.cumsum(good) - 1)[tracks.track[kept]]]


def _turns_since_start(tracks: TrackSet) -> FloatArray:
    """(P,) rad: each observation's turn since its track's first frame."""
    assert tracks.delta is not None
    return tracks.delta - tracks.delta[track_starts(tracks.track)][tracks.track]


def lagging_tracks(problem: _Problem, x: FloatArray, res: FloatArray) -> NDArray[np.bool_]:
    """(T,) bool: the tracks whose residuals res (P, 2) px at x a turn rate of their own explains beyond their noise.

    ``res`` are ``problem``'s residuals at x (weighted when it is).

    Per track, the score test of a rate s_t = 1 (``RefinementConfig.free_rates``): the residuals' component along
    the rate's column, with the track's point re-fitted (the column made orthogonal to the point's three), squared
    over the track's own noise (its RSS over 2 M - 3) times the column's norm; chi-square with one degree of
    freedom when the track turns with the joint, so above its quantile at ``RATE_TEST_LEVEL`` it lags (or leads).
    """
    tracks, n = problem.tracks, problem.n_pose
    if tracks.axis is None or tracks.delta is None:
        raise InvalidInputError("the turn-rate test needs every track's axis and turns (build_track_set gives them)")
    pc, R, t, _, _ = problem._camera_points(x)
    J_rate = problem._rate_column(pc, R, t, problem._pixel_derivative(pc), _turns_since_start(tracks))  # (P, 2)
    if problem.scale is not None:  # res and the blocks carry it already
        J_rate = J_rate * problem.scale[:, None]
    Jq = problem.jacobian_blocks(x)[:, :, n:]  # (P, 2, 3): by the point
    starts = track_starts(tracks.track)
    A = np.add.reduceat(np.einsum("pki,pkj->pij", Jq, Jq), starts) + 1e-12 * np.eye(3)
    b = np.add.reduceat(np.einsum("pki,pk->pi", Jq, J_rate), starts)
    v = np.add.reduceat(np.einsum("pki,pk->pi", Jq, res), starts)
    c = np.add.reduceat(np.sum(J_rate**2, axis=1), starts)
    u = np.add.reduceat(np.sum(J_rate * res, axis=1), starts)
    Ainv_b = np.linalg.solve(A, b[:, :, None])[:, :, 0]
    score = u - np.einsum("ti,ti->t", Ainv_b, v)
    norm2 = c - np.einsum("ti,ti->t", Ainv_b, b)
    rss = np.add.reduceat(np.sum(res**2, axis=1), starts)
    dof = np.maximum(2 * np.diff(np.append(starts, tracks.track.size)) - 3, 1)
    stat = score**2 / np.maximum(rss / dof * norm2, 1e-300)
    return (norm2 > 1e-9) & (stat > chi2.ppf(1.0 - RATE_TEST_LEVEL, 1))


#: ``lagging_tracks``' test level.
RATE_TEST_LEVEL = 0.001


def _split_time_offset(cov: FloatArray, x: FloatArray, bound: float
                       ) -> tuple[FloatArray, float, float, FloatArray]:
    """The pose covariance (6, 6), the time offset s, its 1-sigma and correlations from the (7, 7) covariance.

    Raises:
        TimeOffsetError: |s| beyond ``bound``.
    """
    offset, offset_std = float(x[6]), float(np.sqrt(cov[6, 6]))
    correlation = cov[6, :6] / np.sqrt(np.diag(cov)[:6] * cov[6, 6])
    if abs(offset) > bound:
        raise TimeOffsetError(f"the estimated time offset between the joint and camera clocks is "
                              f"{offset * 1e3:+.1f} ms (1-sigma {offset_std * 1e3:.1f} ms), beyond the "
                              f"+-{bound * 1e3:g} ms the bundle adjustment may estimate: give the offset "
                              "(e.g. calibrate --time-offset) or turn the estimate off")
    return cov[:6, :6], offset, offset_std, correlation


def _turned_by_offset(tracks: TrackSet, time_offset_s: float) -> TrackSet:
    """The tracks with each observation's rotation Rot(a_b, delta + v s) at time offset s (module doc)."""
    rot = Rotation.from_rotvec(tracks.axis[tracks.track] * (tracks.delta + tracks.velocity * time_offset_s)[:, None])
    return replace(tracks, rot=rot.as_matrix())


def _subset(tracks: TrackSet, keep: NDArray[np.bool_]) -> TrackSet:
    new_index = np.cumsum(keep) - 1
    mask = keep[tracks.track]
    return TrackSet(tracks.uv[mask], new_index[tracks.track[mask]].astype(np.int64), tracks.rot[mask],
                    tracks.pivot[keep], tracks.motion[keep], tracks.focal,
                    None if tracks.axis is None else tracks.axis[keep],
                    None if tracks.delta is None else tracks.delta[mask],
                    None if tracks.velocity is None else tracks.velocity[mask],
                    None if tracks.free_rates is None else tracks.free_rates[keep])


