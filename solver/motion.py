"""One exploratory motion's observed geometry, end to end (paper §IV): tracks -> axis and plane.

Pipeline: pixels -> normalized coordinates -> conics (Eq. 9-11) -> two signed axis candidates per
trajectory (Eq. 12-14) -> phase-model circles on each candidate's plane and the candidate with the
smallest Eq. 18 score -> (ours) the axis refined by variable projection, whole trajectories that
do not fit dropped -> RANSAC reference line through the circle centres -> rho = D x A.

Stage-one pruning (§V-C-1, no pose estimate yet) happens here: a motion whose trajectories are not
ellipses, disagree on the axis, or leave the choice between the two axis branches ambiguous raises
``DegenerateMotionError`` with the reason.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from solver.arrays import FloatArray
from solver.camera import normalized_from_pixels, rays_from_normalized
from solver.circle_normals import plane_orientations, sensed
from solver.conics import fit_conics_independent, fit_conics_shared
from solver.errors import DegenerateMotionError, DegenerateTrajectoryError, InvalidInputError
from solver.observations import CameraIntrinsics, KeypointTrack, MotionObservation
from solver.reference_lines import (
    PhaseCircles,
    candidate_scores,
    centres_3d,
    fit_phase_circles,
    fit_reference_plane,
    phase_circle_solution,
    plane_basis,
    project_to_plane,
)

BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class MotionConfig:
    """Settings of the per-motion estimation and its stage-one pruning.

    Attributes:
        conic_fit: "independent" (per-trajectory direct ellipse fits) or "shared" (the paper's
            joint fit with shared orientation, Eq. 9-11).
        min_pixel_motion: px; a trajectory that moves less is dropped as static.
        min_delta_span: rad; a trajectory seen over a smaller joint turn is dropped.
        min_tracks: fewest usable trajectories for a motion.
        max_candidates: at most this many conic-derived axis candidates are scored with Eq. 18.
        grid_size: directions of a Fibonacci sphere scored alongside the conic candidates (ours;
            0 disables): short noisy arcs often give no valid ellipse, never a grid direction.
        refine_top: this many best-scoring, mutually distinct candidates are refined (ours).
        min_ellipses: fewest trajectories whose conic must be a valid ellipse. They give the
            paper's axis candidates and every moving trajectory still takes part in the circle
            fits; short noisy arcs often fail the test, and whether the motion as a whole shows
            curvature is judged by ``line_ratio``.
        line_ratio: when straight lines fit the trajectories to within this factor of the
            circles' misfit, the trajectories carry no curvature (lines, not ellipses).
        min_view_angle: rad; when the camera's rays meet the plane of rotation at a smaller
            median angle, the camera lies in that plane and the trajectories are lines.
        track_outlier_px: px; a trajectory whose RMS misfit exceeds this (and 3x the median) is
            dropped from the motion.
        ambiguity_ratio: the best candidate of the other axis branch must score at least this
            many times worse than the best, else the motion is ambiguous.
        branch_angle: rad; candidates farther than this from the best belong to another branch.
        min_inlier_fraction: fewest trajectories, as a fraction, that must agree with the axis and
            with the reference line.
        line_inlier_angle: rad; RANSAC threshold of the reference line (offset / distance).
    """

    conic_fit: Literal["independent", "shared"] = "independent"
    min_pixel_motion: float = 3.0
    min_delta_span: float = 0.05
    min_tracks: int = 4
    max_candidates: int = 48
    grid_size: int = 600
    refine_top: int = 6
    min_ellipses: int = 0
    min_view_angle: float = 0.05
    line_ratio: float = 1.05
    track_outlier_px: float = 1.5
    ambiguity_ratio: float = 1.1
    branch_angle: float = 0.1
    min_inlier_fraction: float = 0.5
    line_inlier_angle: float = 0.02

    def __post_init__(self) -> None:
        if self.refine_top < 2:
            raise InvalidInputError("refine_top must be >= 2 to judge the axis's ambiguity")
        if self.conic_fit not in ("independent", "shared"):
            raise InvalidInputError(
                f"conic_fit must be 'independent' or 'shared', got {self.conic_fit!r}"
            )
        if self.min_tracks < 1 or self.max_candidates < 2:
            raise InvalidInputError("min_tracks must be >= 1 and max_candidates >= 2")


@dataclass(frozen=True)
class MotionGeometry:
    """A motion's rotation axis and reference plane seen from the camera.

    Attributes:
        axis_cam: (3,) float64: unit rotation axis A^c (right-handed for positive delta).
        reference_cam: (3,) float64: unit ray D^c towards a point of the axis.
        plane_normal: (3,) float64: unit rho, normal of the plane through the camera centre that
            contains the axis (rho is parallel to D^c x A^c).
        track_inliers: (L,) bool: trajectories consistent with the axis and the line.
        score: mean squared circle misfit of the best 75% of trajectories, px^2, after refinement.
        ambiguity: the same score of the best refined candidate of another branch divided by
            the chosen one's (inf when no other branch exists).
        rms_px: RMS circle misfit of the inlier trajectories, pixels (approximate).
    """

    axis_cam: FloatArray
    reference_cam: FloatArray
    plane_normal: FloatArray
    track_inliers: BoolArray
    score: float
    ambiguity: float
    rms_px: float


@dataclass(frozen=True)
class _Points:
    """The usable trajectories' points, concatenated trajectory after trajectory.

    Attributes:
        rays: (P, 3) rays (u, v, 1), camera frame.
        delta: (P,) rad, the joint's turn at each point.
        ids: (P,) slot of the trajectory among the usable ones (non-decreasing).
        n: number of trajectories.
        rays_t: (3, P) ``rays`` transposed (contiguous).
        first: (n,) index of each trajectory's first point; counts: (n,) its number of points.
        phase: (P,) complex exp(i delta).
        sums: (n,) complex, each trajectory's sum of ``phase``.
    """

    rays: FloatArray
    delta: FloatArray
    ids: NDArray[np.int64]
    n: int
    rays_t: FloatArray
    first: NDArray[np.int64]
    counts: NDArray[np.int64]
    phase: NDArray[np.complex128]
    sums: NDArray[np.complex128]


def _gather(rays: list[FloatArray], deltas: list[FloatArray], slots: list[int]) -> _Points:
    ids = np.concatenate([np.full(rays[s].shape[0], k) for k, s in enumerate(slots)]).astype(np.int64)
    delta = np.concatenate([deltas[s] for s in slots])
    counts = np.array([rays[s].shape[0] for s in slots], dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(counts[:-1])]).astype(np.int64)
    phase = np.exp(1j * delta)
    sums = np.add.reduceat(phase, first)
    all_rays = np.concatenate([rays[s] for s in slots])
    return _Points(all_rays, delta, ids, len(slots), np.ascontiguousarray(all_rays.T), first, counts, phase, sums)


def _circles(points: _Points, axis: FloatArray) -> PhaseCircles:
    return fit_phase_circles(project_to_plane(points.rays, axis), points.delta, points.ids, points.n)


def _phase_model(points: _Points, z: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """The phase circles' model points (K, P) fitted to plane coordinates z (K, P), u + i v, row by row.

    ``fit_phase_circles``'s closed form (c + gamma exp(i delta) per trajectory), whose unknowns are
    linear in z: applied to a derivative of z it gives the model's derivative.
    """
    Z1 = np.add.reduceat(z, points.first, axis=1)  # (K, n)
    Z2 = np.add.reduceat(points.phase.conj() * z, points.first, axis=1)
    c, gamma, _ = phase_circle_solution(points.counts.astype(np.float64), points.sums, Z1, Z2)
    return np.repeat(c, points.counts, axis=1) + np.repeat(gamma, points.counts, axis=1) * points.phase


@dataclass(frozen=True)
class _ImageFit:
    """The phase circles of one axis mapped back to the image (``_image_fit``).

    Attributes:
        axis: (3,) unit axis a; e1, e2: (3,) sigma's basis (``plane_basis``).
        z: (P,) complex plane coordinates u + i v of the points; model: (P,) complex, the circles' points.
        Y: (3, P) the model points on sigma, camera frame.
        residuals: (2, P) normalized units, model image minus observed (x row, y row).
    """

    axis: FloatArray
    e1: FloatArray
    e2: FloatArray
    z: NDArray[np.complex128]
    model: NDArray[np.complex128]
    Y: FloatArray
    residuals: FloatArray


def _image_fit(points: _Points, axis: FloatArray) -> _ImageFit:
    """The phase circles fitted on sigma (the plane a . X = 1) and their image-space misfit.

    The circles are fitted on sigma in closed form; their model points are mapped back to the
    image through the camera centre, so the misfit is measured where the noise lives.
    """
    e1, e2 = plane_basis(axis)
    frame = np.array([axis, e1, e2])  # (3, 3) rows a, e1, e2
    w = frame @ points.rays_t  # (3, P): depth along a, then e1, e2
    z = (w[1] + 1j * w[2]) / w[0]
    m = _phase_model(points, z[None])[0]
    Y = frame.T @ np.array([np.ones_like(m.real), m.real, m.imag])  # a + Re(m) e1 + Im(m) e2
    return _ImageFit(axis, e1, e2, z, m, Y, Y[:2] / Y[2] - points.rays_t[:2])


def _image_residuals(points: _Points, axis: FloatArray) -> FloatArray:
    """Image-space misfit (P, 2), normalized units, of the phase circles fitted on sigma (``_image_fit``)."""
    return _image_fit(points, axis).residuals.T


def _image_jacobian(points: _Points, fit: _ImageFit, d_axis: FloatArray) -> FloatArray:
    """Derivatives (2, P, J) of ``fit``'s residuals along d_axis (J, 3), derivatives of its unit axis (perpendicular).

    The misfit does not depend on sigma's in-plane basis (turning it turns the coordinates, the circles and
    their model points alike), so the basis is carried along the axis without turning (de1 = -(e1 . da) a):
    a point X = ray / (ray . a) = a + u e1 + v e2 of sigma moves by dz = -Re(z conj(zeta)) z - zeta in
    z = u + i v, zeta = (e1 + i e2) . da; the model points by the fit of dz (the fit is linear), and
    Y = a + Re(m) e1 + Im(m) e2 by da + Re(dm) e1 + Im(dm) e2 - Re(m conj(zeta)) a.
    """
    z, m, Y = fit.z, fit.model, fit.Y
    zeta = np.column_stack([d_axis @ fit.e1, d_axis @ fit.e2])  # (J, 2): Re, Im
    dz = -(zeta @ np.array([z.real, z.imag])) * z - (zeta[:, 0] + 1j * zeta[:, 1])[:, None]  # (J, P)
    dm = _phase_model(points, dz)
    along = zeta @ np.array([m.real, m.imag])  # (J, P): Re(m conj(zeta))
    basis = np.column_stack([fit.e1, fit.e2, fit.axis])  # (3, 3) columns e1, e2, a
    inv_depth = 1.0 / Y[2]
    image = Y[:2] * inv_depth  # (2, P): the model's image
    out = np.empty((2, Y.shape[1], d_axis.shape[0]))
    for j, da in enumerate(d_axis):
        dY = da[:, None] + basis @ np.array([dm[j].real, dm[j].imag, -along[j]])  # (3, P)
        out[:, :, j] = (dY[:2] - image * dY[2]) * inv_depth
    return out


def _refine_axis(points: _Points, axis: FloatArray) -> FloatArray:
    """The axis (3,) unit minimizing the image misfit (``_image_fit``) from ``axis`` (3,) unit: LM over two tilts."""
    e1, e2 = plane_basis(axis)
    tilts = np.array([e1, e2])
    last: dict[bytes, _ImageFit] = {}  # the misfit at the last point evaluated (MINPACK's Jacobian follows it)

    def axis_of(theta: FloatArray) -> FloatArray:
        a = axis + theta[0] * e1 + theta[1] * e2
        return a / np.linalg.norm(a)

    def fun(theta: FloatArray) -> FloatArray:
        fit = _image_fit(points, axis_of(theta))
        last.clear()
        last[theta.tobytes()] = fit
        return fit.residuals.ravel()

    def jac(theta: FloatArray) -> FloatArray:  # (2P, 2): d a / d theta_j = (I - a a^T) e_j / |axis + theta e|
        fit = last.get(theta.tobytes())
        if fit is None:
            fit = _image_fit(points, axis_of(theta))
        n = np.linalg.norm(axis + theta[0] * e1 + theta[1] * e2)
        return _image_jacobian(points, fit, (tilts - np.outer(tilts @ fit.axis, fit.axis)) / n).reshape(-1, 2)

    sol = least_squares(fun, np.zeros(2), jac=jac, method="lm", x_scale=np.full(2, 1e-2))
    return axis_of(sol.x)


def _track_rms(points: _Points, axis: FloatArray) -> FloatArray:
    res = _image_residuals(points, axis)
    sq = np.bincount(points.ids, weights=np.sum(res**2, axis=1), minlength=points.n)
    return np.sqrt(sq / np.maximum(np.bincount(points.ids, minlength=points.n), 1))


#: How stage one's verdict on a motion seen edge-on begins (the ellipses degenerate into lines).
LINES_NOT_ELLIPSES = "the trajectories are lines, not ellipses"


def fibonacci_sphere(n: int) -> FloatArray:
    """N nearly uniform unit vectors on the sphere: (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    r = np.sqrt(1 - z * z)
    phi = np.pi * (1 + 5**0.5) * k
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _line_rms(pixels: FloatArray) -> float:
    """RMS distance, px, of a trajectory's points (M, 2) from their total-least-squares line."""
    centred = pixels - pixels.mean(axis=0)
    return float(np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(pixels.shape[0]))


def _trimmed_ms(track_rms: FloatArray, keep_fraction: float = 0.75) -> float:
    sq = np.sort(track_rms**2)
    return float(np.mean(sq[: max(1, int(np.ceil(keep_fraction * sq.size)))]))


def track_moved(track: KeypointTrack, config: MotionConfig) -> bool:
    """True when a track moved at least ``min_pixel_motion`` px over ``min_delta_span`` rad."""
    return (len(track) >= 2 and np.max(np.ptp(track.pixels, axis=0)) >= config.min_pixel_motion
            and np.ptp(track.delta) >= config.min_delta_span)


def estimate_motion_geometry(obs: MotionObservation, intrinsics: CameraIntrinsics,
                             config: MotionConfig | None = None,
                             rng: np.random.Generator | None = None) -> MotionGeometry:
    """Estimate A^c, D^c and rho of one exploratory motion from its keypoint tracks.

    Args:
        obs: the motion's tracks (pixels and delta per frame).
        intrinsics: the camera, used once to normalize the pixels.
        config: thresholds; defaults to ``MotionConfig()``.
        rng: randomness of the RANSAC line fit; defaults to a fixed seed.

    Raises:
        DegenerateMotionError: the motion cannot give an axis and a reference line; the message
            says why (too few moving trajectories, lines instead of ellipses, ambiguous axis, axis
            through the camera centre, centres off one line).
    """
    config = config or MotionConfig()
    rng = rng if rng is not None else np.random.default_rng(0)
    focal = float(np.mean(intrinsics.focal))
    L = len(obs.tracks)
    usable: list[int] = []
    rays: list[FloatArray] = []
    deltas: list[FloatArray] = []
    for track in obs.tracks:
        rays.append(rays_from_normalized(normalized_from_pixels(track.pixels, intrinsics)))
        deltas.append(track.delta)
        if track_moved(track, config):
            usable.append(len(rays) - 1)
    if len(usable) < config.min_tracks:
        raise DegenerateMotionError(
            f"only {len(usable)} of {L} trajectories moved at least {config.min_pixel_motion} px over "
            f"{config.min_delta_span} rad (need {config.min_tracks}): nothing moved in view"
        )
    uv = [rays[s][:, :2] for s in usable]
    try:
        fits = fit_conics_shared(uv) if config.conic_fit == "shared" else fit_conics_independent(uv)
    except DegenerateTrajectoryError:
        fits = []
    normals = [np.zeros((0, 3))]  # each ellipse's two circle normals (Eq. 14), signs not yet known
    owners: list[int] = []
    for fit, s in zip(fits, usable, strict=False):
        if fit.ok:
            try:
                normals.append(plane_orientations(fit.matrix))
            except DegenerateTrajectoryError:
                continue
            owners += [s, s]
    cand = np.concatenate(normals)
    n_ellipses = sum(f.ok for f in fits)
    if n_ellipses < config.min_ellipses:
        reasons = sorted({f.reason for f in fits if not f.ok})
        raise DegenerateMotionError(
            f"only {n_ellipses} of {len(usable)} moving trajectories are ellipses (need "
            f"{config.min_ellipses}): {'; '.join(reasons)}"
        )
    picked = np.arange(cand.shape[0])
    if cand.shape[0] > config.max_candidates:
        picked = rng.choice(cand.shape[0], config.max_candidates, replace=False)
    # the rotation sense only of the candidates scored (``axis_candidates``'s signs, for a sample of them)
    cand = np.array([sensed(cand[k], rays[owners[k]], deltas[owners[k]]) for k in picked]).reshape(-1, 3)
    if config.grid_size:
        cand = np.concatenate([cand, fibonacci_sphere(config.grid_size)])
    if cand.shape[0] == 0:
        raise DegenerateMotionError("no trajectory gave an ellipse, so no axis candidate exists")

    points = _gather(rays, deltas, usable)
    scores = candidate_scores(points.rays, points.delta, points.ids, points.n, cand)
    seeds: list[FloatArray] = []
    for k in np.argsort(scores):
        if all(np.arccos(np.clip(cand[k] @ s, -1, 1)) > config.branch_angle for s in seeds):
            seeds.append(cand[k])
        if len(seeds) == config.refine_top:
            break
    refined = [_refine_axis(points, a) for a in seeds]
    refined_ms = np.array([_trimmed_ms(_track_rms(points, a) * focal) for a in refined])
    order = np.argsort(refined_ms)
    axis = refined[order[0]]
    others = [k for k in order[1:]
              if np.arccos(np.clip(refined[k] @ axis, -1, 1)) > config.branch_angle]
    ambiguity = (float(refined_ms[others[0]] / max(refined_ms[order[0]], 1e-300))
                 if others else np.inf)
    line_rms = np.median([_line_rms(obs.tracks[s].pixels) for s in usable])
    circle_rms = float(np.median(_track_rms(points, refined[order[0]]))) * focal
    if line_rms <= config.line_ratio * circle_rms:
        raise DegenerateMotionError(
            f"{LINES_NOT_ELLIPSES}: straight lines fit them to {line_rms:.2f} px, "
            f"circles to {circle_rms:.2f} px (the camera lies near the plane of rotation)"
        )
    if ambiguity < config.ambiguity_ratio:
        raise DegenerateMotionError(
            f"axis is ambiguous: another axis fits only {ambiguity:.2f}x worse than the best "
            f"(need {config.ambiguity_ratio}x)"
        )

    grazing = float(np.median(np.abs(points.rays @ axis) / np.linalg.norm(points.rays, axis=1)))
    if grazing < config.min_view_angle:
        raise DegenerateMotionError(
            f"the camera lies in the plane of rotation (rays meet it at {np.degrees(grazing):.2f} deg): "
            f"{LINES_NOT_ELLIPSES}"
        )
    keep = np.arange(len(usable))
    rms = _track_rms(points, axis) * focal
    good = rms <= max(config.track_outlier_px, 3.0 * float(np.median(rms)))
    if np.sum(good) >= config.min_tracks and not np.all(good):
        keep = np.flatnonzero(good)
        points = _gather(rays, deltas, [usable[k] for k in keep])
        axis = _refine_axis(points, axis)
        rms = _track_rms(points, axis) * focal

    circles = _circles(points, axis)
    offset = np.linalg.norm(circles.centres, axis=1) / np.maximum(circles.radii, 1e-300)
    if np.median(offset) < 1e-3:
        raise DegenerateMotionError(
            "the rotation axis passes through the camera centre: the reference plane is undefined"
        )
    rho, line_inliers = fit_reference_plane(circles.centres, axis, np.ones(points.n), rng,
                                            inlier_angle=config.line_inlier_angle)
    n_inliers = int(np.sum(line_inliers))
    need = max(config.min_tracks, int(np.ceil(config.min_inlier_fraction * len(usable))))
    if n_inliers < need:
        raise DegenerateMotionError(
            f"only {n_inliers} of {len(usable)} circle centres lie on one reference line (need {need})"
        )
    centre = centres_3d(circles.centres[line_inliers].mean(axis=0, keepdims=True), axis)[0]
    track_inliers = np.zeros(L, dtype=bool)
    track_inliers[np.asarray(usable)[keep[line_inliers]]] = True
    return MotionGeometry(
        axis_cam=axis,
        reference_cam=centre / np.linalg.norm(centre),
        plane_normal=rho,
        track_inliers=track_inliers,
        score=float(refined_ms[order[0]]),
        ambiguity=ambiguity,
        rms_px=float(np.sqrt(np.mean(rms[line_inliers] ** 2))),
    )
