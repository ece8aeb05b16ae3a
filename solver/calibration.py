"""Linear calibration from collinearity and coplanarity (paper §V-A/B) and stage-two pruning (§V-C-2).

Per motion i, with Gamma(Q_i, J_i) = (a_b, d_b) from the robot and (A^c, rho) from the camera:

* collinearity: [A^c]x R a_b = 0, i.e. [A^c]x (a_b^T kron I3) vec(R) = 0 (three rows, rank two);
* coplanarity: rho . (R d_b + t) = 0, i.e. (d_b^T kron rho^T) vec(R) + rho^T t = 0 (one row).

Stacked: H r + K t = 0. t is eliminated with t = -(K^T K)^-1 K^T H r, leaving S r = 0 with
S = (I - K (K^T K)^-1 K^T) H; r is S's least right singular vector scaled to ||r|| = sqrt(3) (the
norm of any rotation), R its nearest rotation (SVD, det = +1), and t is recovered from R.
Coplanarity rows are metres; they are divided by the distance of the joint from the camera (taken
from a first solve) so that both kinds of row are angles.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray
from solver.errors import InsufficientMotionsError, InvalidInputError, UnobservablePoseError
from solver.frames import project_to_so3, skew, transform_from_rt

#: Fewest motions for a pose: three planes fix t, and two non-parallel axes fix R.
MIN_MOTIONS = 3

#: Fewest motions for the paper's relaxed linear system: it has 3N - 3 independent equations
#: for the 8 degrees of freedom of r up to scale, so N >= 4; with three motions R comes from the
#: axis pairs alone (``solve_minimal``).
MIN_MOTIONS_RELAXED = 4

#: Smallest singular value of the pose Jacobian, relative to the largest, for a pose to count as
#: observable. Motions of joints whose axes all meet in one point leave the depth of that point
#: free, which shows as a ratio of ~1e-16 noise-free and well below this value with noise.
MIN_OBSERVABILITY = 1e-3


@dataclass(frozen=True)
class AxisCorrespondence:
    """One motion's axis seen by the robot and by the camera.

    Attributes:
        axis_base: (3,) float64: unit joint axis a_b in the base frame.
        point_base: (3,) float64, m: a point d_b on the joint axis in the base frame.
        axis_cam: (3,) float64: unit axis A^c in the camera frame.
        plane_normal: (3,) float64: unit rho of the plane through the camera centre and the axis.
    """

    axis_base: FloatArray
    point_base: FloatArray
    axis_cam: FloatArray
    plane_normal: FloatArray


def _rows(correspondences: Sequence[AxisCorrespondence], depths: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Rows of H (4N, 9) and K (4N, 3), four per motion; each coplanarity row divided by its depth (N,) m.

    A motion's collinearity rows are [A^c]x (a_b^T kron I): entry (i, 3 j + k) is [A^c]x[i, k] a_b[j]; its
    coplanarity row is (d_b kron rho) / depth in H and rho / depth in K.
    """
    n = len(correspondences)
    axis_cam = np.array([c.axis_cam for c in correspondences])
    axis_base = np.array([c.axis_base for c in correspondences])
    point_base = np.array([c.point_base for c in correspondences])
    normal = np.array([c.plane_normal for c in correspondences])
    skews = skew(axis_cam)  # (N, 3, 3)
    H = np.zeros((n, 4, 9))
    K = np.zeros((n, 4, 3))
    H[:, :3] = (skews[:, :, None, :] * axis_base[:, None, :, None]).reshape(n, 3, 9)
    H[:, 3] = (point_base[:, :, None] * normal[:, None, :]).reshape(n, 9) / depths[:, None]
    K[:, 3] = normal / depths[:, None]
    return H.reshape(4 * n, 9), K.reshape(4 * n, 3)


def _translation(correspondences: Sequence[AxisCorrespondence], R: FloatArray,
                 depths: FloatArray) -> FloatArray:
    K = np.array([c.plane_normal / d for c, d in zip(correspondences, depths, strict=True)])
    b = -np.array([c.plane_normal @ (R @ c.point_base) / d
                   for c, d in zip(correspondences, depths, strict=True)])
    sv = np.linalg.svd(K, compute_uv=False)
    if sv[-1] < 1e-6 * sv[0]:
        raise UnobservablePoseError(
            "the motions' reference planes do not span 3-D space, so the translation is not fixed: "
            "add motions of other joints or from other start configurations"
        )
    return np.linalg.lstsq(K, b, rcond=None)[0]


def _rotation_from_axes(correspondences: Sequence[AxisCorrespondence]) -> FloatArray:
    """R (3, 3) maximizing sum A^c . R a_b (Procrustes: SVD, det = +1); two non-parallel axes suffice.

    Raises:
        UnobservablePoseError: the axes are parallel.
    """
    B = sum(np.outer(c.axis_cam, c.axis_base) for c in correspondences)
    sv = np.linalg.svd(B, compute_uv=False)
    if sv[1] < 1e-6 * sv[0]:
        raise UnobservablePoseError(
            "the rotation is not fixed by these motions (their axes are parallel): add motions of "
            "joints with other axis directions"
        )
    return project_to_so3(B)


def solve_minimal(correspondences: Sequence[AxisCorrespondence]) -> FloatArray:
    """T_camera_base (4, 4) from three or more motions by Procrustes, then t by least squares.

    R maximizes sum A^c . R a_b (SVD, det = +1); t solves the coplanarity rows given R.

    Raises:
        InsufficientMotionsError: fewer than three motions.
        UnobservablePoseError: the axes are all parallel or the planes do not span R^3.
    """
    n = len(correspondences)
    if n < MIN_MOTIONS:
        raise InsufficientMotionsError(f"{n} motion(s) given; a pose needs at least {MIN_MOTIONS}")
    R = _rotation_from_axes(correspondences)
    return transform_from_rt(R, _translation(correspondences, R, np.ones(n)))


def pose_family(correspondences: Sequence[AxisCorrespondence]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The poses [R | t0 + s u] (s real) that two or more motions' axes allow, and their rotation.

    Two motions with non-parallel axes fix R (Procrustes, as ``solve_minimal``) but only two
    components of t: each reference plane through the camera centre gives one (coplanarity), and
    the circles' images fix each axis only up to its own distance from the camera, so t stays free
    along u, the direction in which both planes contain the camera centre's ray (rho_1 x rho_2).
    With more motions u is t's weakest direction and t0 the least-squares translation.

    Returns:
        R (3, 3); t0 (3,) m, the translation of least norm (the member nearest the camera
        centre); u (3,) unit.

    Raises:
        InsufficientMotionsError: fewer than two motions.
        UnobservablePoseError: the axes are parallel (R is not fixed).
    """
    n = len(correspondences)
    if n < 2:
        raise InsufficientMotionsError(f"{n} motion(s) given; a rotation needs at least 2")
    R = _rotation_from_axes(correspondences)
    K = np.array([c.plane_normal for c in correspondences])
    b = -np.array([c.plane_normal @ (R @ c.point_base) for c in correspondences])
    t0 = np.linalg.lstsq(K, b, rcond=None)[0]  # of least norm when K has rank 2
    return R, t0, np.linalg.svd(K)[2][-1]


def family_offsets(R: FloatArray, t0: FloatArray, u: FloatArray, points_base: FloatArray,
                   distances: FloatArray) -> FloatArray:
    """Members s of the pose family [R | t0 + s u] that put the robot in front of the camera at given distances.

    For each distance d, the offsets s at which the centroid of ``points_base`` lies d from the
    camera centre and in front of it (z > 0): the roots of |p0 + s u| = d with p0 = R c + t0 (none
    when the line p0 + s u passes farther than d from the camera; both when both are in front).

    Args:
        R: (3, 3) rotation of the family (``pose_family``).
        t0: (3,) m, its translation at s = 0.
        u: (3,) unit direction of its free translation.
        points_base: (N, 3) float64, m: points of the robot that the camera sees (e.g. the joint
            points of the motions), base frame.
        distances: (D,) float64, m: the distances to place their centroid at.

    Returns:
        (K,) float64, m: the offsets s, ascending (K <= 2 D).
    """
    p0 = R @ np.mean(np.asarray(points_base, dtype=np.float64), axis=0) + t0
    b = float(p0 @ u)
    offsets = []
    for d in np.asarray(distances, dtype=np.float64):
        disc = b * b - float(p0 @ p0) + d * d
        if disc >= 0:
            offsets += [s for s in (-b - np.sqrt(disc), -b + np.sqrt(disc)) if (p0 + s * u)[2] > 0]
    return np.unique(offsets)


def solve_linear(correspondences: Sequence[AxisCorrespondence],
                 depths: FloatArray | None = None) -> FloatArray:
    """T_camera_base (4, 4) by the paper's linear method.

    Needs four or more motions; three go to ``solve_minimal``.

    Args:
        correspondences: the motions' axis correspondences.
        depths: (N,) float64, m: distances used to scale the coplanarity rows; when None, a first
            solve with unit depths provides them.

    Raises:
        InsufficientMotionsError: fewer than three motions.
        UnobservablePoseError: the plane normals do not span R^3, or the rotation is not fixed.
    """
    n = len(correspondences)
    if n < MIN_MOTIONS_RELAXED:
        return solve_minimal(correspondences)
    unit_depths = depths is None
    depths = np.ones(n) if depths is None else np.asarray(depths, dtype=np.float64)
    if depths.shape != (n,):
        raise InvalidInputError(f"depths must have shape ({n},), got {depths.shape}")
    H, K = _rows(correspondences, depths)
    sv_K = np.linalg.svd(K, compute_uv=False)
    if sv_K[-1] < 1e-6 * sv_K[0]:
        raise UnobservablePoseError(
            "the motions' reference planes do not span 3-D space, so the translation is not fixed: "
            "add motions of other joints or from other start configurations"
        )
    K_pinv = np.linalg.pinv(K)
    S = H - K @ (K_pinv @ H)
    _, sv, Vt = np.linalg.svd(S)
    if sv[-2] < 1e-9 * sv[0]:
        raise UnobservablePoseError(
            "the rotation is not fixed by these motions (their axes are parallel): add motions of "
            "joints with other axis directions"
        )
    r = Vt[-1] * np.sqrt(3.0)
    R_raw = r.reshape(3, 3, order="F")
    if np.linalg.det(R_raw) < 0:
        R_raw = -R_raw
    R = project_to_so3(R_raw)
    t = -K_pinv @ H @ R.reshape(-1, order="F")
    T = transform_from_rt(R, t)
    if unit_depths:
        cam_points = np.array([R @ c.point_base + t for c in correspondences])
        new_depths = np.maximum(np.linalg.norm(cam_points, axis=1), 0.1)
        return solve_linear(correspondences, new_depths)
    return T


def consistency_errors(c: AxisCorrespondence, T_camera_base: FloatArray) -> tuple[float, float]:
    """The paper's eps_a (rad, Eq. 23) and eps_d (m, Eq. 24) of one motion against a pose."""
    R, t = T_camera_base[:3, :3], T_camera_base[:3, 3]
    eps_a = float(np.arccos(np.clip(c.axis_cam @ (R @ c.axis_base), -1.0, 1.0)))
    eps_d = float(abs(c.plane_normal @ (R @ c.point_base + t)))
    return eps_a, eps_d


def pose_observability(correspondences: Sequence[AxisCorrespondence],
                       T_camera_base: FloatArray) -> tuple[float, FloatArray]:
    """How well the motions fix the pose near T_camera_base.

    Builds the Jacobian of the constraints (collinearity and coplanarity, the latter with the
    plane predicted from the pose so that the answer is the geometry's, not the noise's) with
    respect to the perturbation (omega, tau), tau in units of the mean joint depth.

    Returns:
        The ratio of the smallest to the largest singular value, and the weakest direction (6,).
    """
    R, t = T_camera_base[:3, :3], T_camera_base[:3, 3]
    rows = []
    depth = float(np.mean([np.linalg.norm(R @ c.point_base + t) for c in correspondences]))
    for c in correspondences:
        a_c = R @ c.axis_base
        p_c = R @ c.point_base + t
        rho = np.cross(p_c, a_c)
        rho /= max(np.linalg.norm(rho), 1e-300)
        J = np.zeros((4, 6))
        J[:3, :3] = -skew(a_c) @ skew(a_c)  # d(a_c x Exp(w) a_c)/dw
        J[3, :3] = -rho @ skew(R @ c.point_base)  # d(Exp(w) R d_b)/dw = -[R d_b]x
        J[3, 3:] = rho * depth
        rows.append(J)
    J = np.concatenate(rows)
    _, sv, Vt = np.linalg.svd(J)
    return float(sv[-1] / sv[0]), Vt[-1]


def check_observable(correspondences: Sequence[AxisCorrespondence], T_camera_base: FloatArray) -> None:
    """Raise UnobservablePoseError when the motions leave a direction of the pose free."""
    ratio, direction = pose_observability(correspondences, T_camera_base)
    if ratio < MIN_OBSERVABILITY:
        kind = "translation" if np.linalg.norm(direction[3:]) > np.linalg.norm(direction[:3]) else "rotation"
        raise UnobservablePoseError(
            f"these motions cannot fix the pose: the {kind} along {np.round(direction, 3).tolist()} "
            f"(omega, tau) is free (observability {ratio:.1e} < {MIN_OBSERVABILITY}); joints whose "
            "axes all meet in one point (e.g. the Panda's joints 1-3) cannot fix depth: add a distal joint"
        )


def _errors(correspondences: Sequence[AxisCorrespondence], T_camera_base: FloatArray) -> tuple[FloatArray, FloatArray]:
    """eps_a (N,) rad and eps_d (N,) m of every motion against a pose (``consistency_errors``)."""
    R, t = T_camera_base[:3, :3], T_camera_base[:3, 3]
    axis_base = np.array([c.axis_base for c in correspondences])
    axis_cam = np.array([c.axis_cam for c in correspondences])
    point_cam = np.array([c.point_base for c in correspondences]) @ R.T + t
    normal = np.array([c.plane_normal for c in correspondences])
    eps_a = np.arccos(np.clip(np.einsum("ij,ij->i", axis_cam, axis_base @ R.T), -1.0, 1.0))
    return eps_a, np.abs(np.einsum("ij,ij->i", normal, point_cam))  # consistency_errors, all motions at once


@dataclass(frozen=True)
class ConsensusResult:
    """Outcome of the robust linear calibration.

    Attributes:
        T_camera_base: (4, 4) float64: the pose refitted on the motions in ``used``.
        inliers: (N,) bool: motions consistent with it (within the pruning bounds).
        eps_a: (N,) float64, rad: each motion's axis error against it.
        eps_d: (N,) float64, m: each motion's plane distance against it.
        used: (N,) bool: the motions of the final fit: the inliers within the tighter fit bounds
            when enough of them fix the pose, else all inliers.
    """

    T_camera_base: FloatArray
    inliers: NDArray[np.bool_]
    eps_a: FloatArray
    eps_d: FloatArray
    used: NDArray[np.bool_]


#: RANSAC stops once this many minimal samples were scored and, with the largest consistent set's share w
#: of the motions, 1 - (1 - w^3)^k reaches ``RANSAC_CONFIDENCE``: with 90 % consistent motions that is
#: after 10 samples instead of all 100 (the linear stage was 70-90 % of an update's time at 25 motions).
RANSAC_MIN_SAMPLES = 10
RANSAC_CONFIDENCE = 0.999


def _samples_needed(inlier_share: float) -> float:
    """Minimal samples after which RANSAC has drawn an all-inlier triple with ``RANSAC_CONFIDENCE``."""
    p_good = inlier_share ** MIN_MOTIONS
    if p_good >= 1.0:
        return 0.0
    if p_good <= 0.0:
        return np.inf
    return float(np.log(1 - RANSAC_CONFIDENCE) / np.log(1 - p_good))


def solve_consensus(correspondences: Sequence[AxisCorrespondence], max_eps_a: float,
                    max_eps_d: float, rng: np.random.Generator, iterations: int = 100,
                    fit_eps: tuple[float, float] | None = None) -> ConsensusResult:
    """Linear calibration robust to wrong motions: RANSAC over minimal sets of three motions.

    Each sample's pose scores the motions by the paper's eps_a and eps_d (§V-C-2), up to ``iterations``
    samples or fewer once enough were scored (``RANSAC_CONFIDENCE``); the largest consistent set is
    refitted, and inliers are re-selected against the refit until stable.
    With ``fit_eps`` = (rad, m), the pose is then refitted on the inliers within those tighter
    bounds, re-selected until stable, as long as at least four of them fix the pose: the pruning
    bounds keep a motion from being rejected, but motions with axis errors of several degrees
    still pull the least-squares solution (paper §V-A weighs every row alike).

    Raises:
        InsufficientMotionsError: fewer than three motions, or fewer than three consistent ones.
        UnobservablePoseError: the consistent motions cannot fix the pose.
    """
    n = len(correspondences)
    if n < MIN_MOTIONS:
        raise InsufficientMotionsError(
            f"{n} usable motion(s); the calibration needs at least {MIN_MOTIONS}"
        )

    def score(T: FloatArray) -> tuple[NDArray[np.bool_], FloatArray, FloatArray]:
        ea, ed = _errors(correspondences, T)
        return (ea <= max_eps_a) & (ed <= max_eps_d), ea, ed

    best: NDArray[np.bool_] | None = None
    best_cost = np.inf
    unobservable: UnobservablePoseError | None = None
    samples = [np.arange(n)] + [rng.choice(n, MIN_MOTIONS, replace=False) for _ in range(iterations)]
    for k, idx in enumerate(samples):
        if best is not None and k > RANSAC_MIN_SAMPLES and k >= _samples_needed(best.sum() / n):
            break  # drawn all the same: the random stream does not depend on where the loop stops
        try:
            T = solve_minimal([correspondences[i] for i in idx]) if len(idx) == MIN_MOTIONS \
                else solve_linear([correspondences[i] for i in idx])
        except UnobservablePoseError as exc:
            unobservable = exc
            continue
        except InsufficientMotionsError:
            continue
        inl, ea, ed = score(T)
        # MSAC cost: inliers pay their normalized error, outliers the threshold.
        cost = float(np.sum(np.minimum((ea / max_eps_a) ** 2 + (ed / max_eps_d) ** 2, 1.0)))
        if inl.sum() >= MIN_MOTIONS and cost < best_cost:
            best, best_cost = inl, cost
    if best is None and unobservable is not None:
        raise unobservable
    if best is None:
        raise InsufficientMotionsError(
            f"no three of the {n} motions agree on a pose within {max_eps_a} rad / {max_eps_d} m"
        )
    inliers = best
    for _ in range(5):
        T = solve_linear([correspondences[i] for i in np.flatnonzero(inliers)])
        new, ea, ed = score(T)
        if new.sum() < MIN_MOTIONS or np.array_equal(new, inliers):
            break
        inliers = new
    check_observable([correspondences[i] for i in np.flatnonzero(inliers)], T)
    used = inliers
    if fit_eps is not None:
        T, used = _tighten(correspondences, T, inliers, fit_eps)
        _, ea, ed = score(T)
    return ConsensusResult(T, inliers, ea, ed, used)


def _tighten(correspondences: Sequence[AxisCorrespondence], T: FloatArray, inliers: NDArray[np.bool_],
             fit_eps: tuple[float, float]) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Refit T on the inliers within ``fit_eps`` until the set is stable; keeps T when it cannot."""
    used = inliers
    for _ in range(5):
        ea, ed = _errors(correspondences, T)
        new = inliers & (ea <= fit_eps[0]) & (ed <= fit_eps[1])
        if new.sum() < MIN_MOTIONS_RELAXED or np.array_equal(new, used):
            break
        subset = [correspondences[i] for i in np.flatnonzero(new)]
        try:
            T_new = solve_linear(subset)
            check_observable(subset, T_new)
        except UnobservablePoseError:
            break
        T, used = T_new, new
    return T, used
