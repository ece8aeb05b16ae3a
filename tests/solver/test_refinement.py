"""Tests of solver/refinement.py: the bundle adjustment of T_camera_base and the keypoints."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp
import scipy.stats
from scipy.spatial.transform import Rotation

from solver.errors import InsufficientMotionsError, InvalidInputError, TimeOffsetError
from solver.frames import perturb, pose_difference, pose_errors
from solver.refinement import (
    MotionSummary,
    RefinementConfig,
    RefinementResult,
    _BlockOperator,
    _Problem,
    _solve,
    _symmetric_inverse,
    _trf_subspace,
    _Whitened,
    build_track_set,
    clustered_pose_covariance,
    conservative_covariance,
    few_clusters_factor,
    lagging_tracks,
    motion_jackknife_covariance,
    motion_overdispersion,
    newest_motion_leverage,
    pose_covariance,
    pose_information,
    refine,
    reprojection_residuals,
    screen_start,
    split_half_residuals,
    track_observability,
    triangulate_tracks,
)
from solver.schur import track_starts
from tests.solver.scene import FOCAL, FX, project_normalized, random_pose, random_unit

#: Central differences with step 1e-6 on residuals of ~100 px: truncation ~1e-12 and rounding
#: ~1e-8 against Jacobian entries of ~1e3 px per unit, far inside 1e-5 relative.
JACOBIAN_RTOL = 1e-5
FD_STEP = 1e-6

#: Noise-free triangulation at the true pose: a 3x3 solve per track, float64 rounding only.
POINT_TOL = 1e-9

#: Noise-free refinement converges to the truth up to the solver's xtol/ftol (1e-12 / 1e-10).
NOISE_FREE_POSE_TOL = 1e-8

#: Pixel noise of the noisy test, px per coordinate.
NOISE_PX = 0.5

#: The start of the refinement: 0.02 rad and 2 cm away from the truth.
START_ROT, START_TRANS = 0.02, 0.02

#: 99.9% quantile of chi-square with 6 degrees of freedom: the squared Mahalanobis distance of the
#: pose error under the reported covariance exceeds it once in a thousand noisy scenes.
CHI2_6_999 = 22.46

#: A richer scene for the noisy tests (6 motions x 6 tracks x 30 frames): the depth of a 0.6 m
#: workspace seen from 1.5 m is still its weakest direction (~1-5 mm at 0.5 px).
NOISY_SCENE = {"n_motions": 6, "n_tracks": 6, "n_frames": 30, "noise_px": NOISE_PX}


@dataclass
class Scene:
    T_true: np.ndarray
    motions: list  # (axis_base, point_base, [(uv, delta), ...]) per motion
    points: np.ndarray  # (T, 3) true p0 of each track, base frame, m


def _make_scene(seed: int, n_motions: int = 4, n_tracks: int = 5, n_frames: int = 20,
                noise_px: float = 0.0, pivot: np.ndarray | None = None) -> Scene:
    """Keypoints fixed on links turned about known axes, projected by a plain pinhole.

    With ``pivot`` (3,) m every axis passes through that base-frame point (else each its own).
    """
    rng = np.random.default_rng(seed)
    T = random_pose(rng)
    R, t = T[:3, :3], T[:3, 3]
    motions, points = [], []
    common = pivot
    for _ in range(n_motions):
        axis, pivot = random_unit(rng), rng.uniform(-0.3, 0.3, 3)
        pivot = pivot if common is None else np.asarray(common, dtype=np.float64)
        delta = np.linspace(0.0, rng.uniform(0.8, 1.5), n_frames)
        turns = Rotation.from_rotvec(np.outer(delta, axis))
        tracks = []
        for _ in range(n_tracks):
            p0 = pivot + random_unit(rng) * rng.uniform(0.05, 0.25)
            p_base = turns.apply(p0 - pivot) + pivot
            uv = project_normalized(p_base @ R.T + t)
            uv = uv + rng.normal(0.0, noise_px, uv.shape) / FOCAL
            tracks.append((uv, delta))
            points.append(p0)
        motions.append((axis, pivot, tracks))
    return Scene(T, motions, np.array(points))


def _start_pose(T_true: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xi = np.concatenate([START_ROT * random_unit(rng), START_TRANS * random_unit(rng)])
    return perturb(T_true, xi)


def _finite_difference_jacobian(problem: _Problem | _Whitened, x: np.ndarray) -> np.ndarray:
    J = np.empty((problem.residuals(x).size, x.size))
    for k in range(x.size):
        step = np.zeros_like(x)
        step[k] = FD_STEP
        J[:, k] = (problem.residuals(x + step) - problem.residuals(x - step)) / (2 * FD_STEP)
    return J


@pytest.mark.parametrize("omega_scale", [0.0, 0.02, 0.5], ids=["omega-zero", "omega-small",
                                                              "omega-large"])
def test_jacobian_matches_finite_differences(omega_scale):
    scene = _make_scene(1, n_motions=3, n_tracks=2, n_frames=8)
    tracks = build_track_set(scene.motions, FOCAL)
    rng = np.random.default_rng(2)
    T0 = _start_pose(scene.T_true, 3)
    x = np.concatenate([omega_scale * random_unit(rng), rng.normal(0, 0.02, 3),
                        (scene.points + rng.normal(0, 0.01, scene.points.shape)).ravel()])
    problem = _Problem(tracks, T0)
    J = problem.jacobian(x)
    assert sp.issparse(J)
    assert J.shape == problem.shape == (2 * tracks.uv.shape[0], 6 + 3 * tracks.n_tracks)
    J = J.toarray()
    J_fd = _finite_difference_jacobian(problem, x)
    np.testing.assert_allclose(J, J_fd, rtol=JACOBIAN_RTOL, atol=JACOBIAN_RTOL * np.abs(J).max())


def test_whitened_jacobian_matches_finite_differences_and_whitens():
    scene = _make_scene(5, n_motions=3, n_tracks=3, n_frames=10)
    tracks = build_track_set(scene.motions, FOCAL)
    rng = np.random.default_rng(6)
    T0 = _start_pose(scene.T_true, 7)
    x0 = np.concatenate([np.zeros(6), (_camera_points(scene) + rng.normal(0, 0.01, (len(scene.points), 3))).ravel()])
    white = _Whitened(_Problem(tracks, T0), x0)
    n = x0.size
    assert np.array_equal(white.native(np.zeros(n)), x0)
    z = rng.normal(0, 0.5, n)
    # z -> x is affine: x(z) - x0 is the sum of x(e_k) - x0 over z's components
    cols = np.stack([white.native(np.eye(n)[k]) - x0 for k in range(n)], axis=1)
    np.testing.assert_allclose(white.native(z) - x0, cols @ z, rtol=1e-12, atol=1e-15)
    J = white.jacobian(z).toarray()
    J_fd = _finite_difference_jacobian(white, z)
    np.testing.assert_allclose(J, J_fd, rtol=JACOBIAN_RTOL, atol=JACOBIAN_RTOL * np.abs(J).max())
    # at z = 0 the normal matrix has identity blocks on the pose and on every track's point
    N = white.jacobian(np.zeros(n)).toarray()
    N = N.T @ N
    np.testing.assert_allclose(N[:6, :6], np.eye(6), atol=1e-6)
    for k in range(tracks.n_tracks):
        b = slice(6 + 3 * k, 9 + 3 * k)
        np.testing.assert_allclose(N[b, b], np.eye(3), atol=1e-6)


def _camera_points(scene):
    """The problem's point unknowns: each track's point in the camera frame at delta = 0."""
    return scene.points @ scene.T_true[:3, :3].T + scene.T_true[:3, 3]


def test_residuals_vanish_at_truth():
    scene = _make_scene(4)
    tracks = build_track_set(scene.motions, FOCAL)
    problem = _Problem(tracks, scene.T_true)
    x = np.concatenate([np.zeros(6), _camera_points(scene).ravel()])
    assert np.max(np.abs(problem.residuals(x))) < 1e-9  # px


def test_build_track_set_flattens_and_skips_short_tracks():
    scene = _make_scene(5, n_motions=2, n_tracks=2, n_frames=10)
    axis, pivot, tracks = scene.motions[1]
    short = (tracks[0][0][:3], tracks[0][1][:3])
    motions = [scene.motions[0], (axis, pivot, [short, *tracks])]
    ts = build_track_set(motions, FOCAL, min_frames=4)
    assert ts.n_tracks == 4
    np.testing.assert_array_equal(ts.motion, [0, 0, 1, 1])
    np.testing.assert_array_equal(np.bincount(ts.track), [10, 10, 10, 10])
    np.testing.assert_array_equal(ts.pivot[2], pivot)
    last_turn = Rotation.from_rotvec(tracks[1][1][-1] * axis).as_matrix()
    np.testing.assert_allclose(ts.rot[-1], last_turn, atol=1e-12)


def test_build_track_set_without_long_tracks_raises():
    scene = _make_scene(5, n_motions=1, n_tracks=2, n_frames=3)
    with pytest.raises(InsufficientMotionsError, match="no track long enough to refine"):
        build_track_set(scene.motions, FOCAL, min_frames=4)


def test_triangulate_tracks_recovers_true_points():
    scene = _make_scene(6)
    points, ok = triangulate_tracks(build_track_set(scene.motions, FOCAL), scene.T_true)
    assert np.all(ok)
    np.testing.assert_allclose(points, scene.points, atol=POINT_TOL)


def test_triangulate_tracks_flags_a_static_track():
    scene = _make_scene(6, n_motions=2, n_tracks=2)
    uv, delta = scene.motions[0][2][0]
    static = (np.repeat(uv[:1], uv.shape[0], axis=0), np.zeros_like(delta))  # one ray, no parallax
    axis, pivot, tracks = scene.motions[0]
    motions = [(axis, pivot, [static, *tracks[1:]]), scene.motions[1]]
    points, ok = triangulate_tracks(build_track_set(motions, FOCAL), scene.T_true)
    np.testing.assert_array_equal(ok, [False, True, True, True])
    np.testing.assert_allclose(points[1:], scene.points[1:], atol=POINT_TOL)


def test_refine_recovers_pose_noise_free():
    scene = _make_scene(7)
    T_init = _start_pose(scene.T_true, 8)
    assert pose_errors(T_init, scene.T_true) == pytest.approx((START_ROT, START_TRANS))
    result = refine(build_track_set(scene.motions, FOCAL), T_init)
    rot_err, trans_err = pose_errors(result.T_camera_base, scene.T_true)
    assert rot_err < NOISE_FREE_POSE_TOL
    assert trans_err < NOISE_FREE_POSE_TOL
    assert np.all(result.track_inliers)
    np.testing.assert_allclose(result.points_base, scene.points, atol=1e-6)
    assert result.rms_px < 1e-6


def test_refine_with_pixel_noise_improves_on_start():
    scene = _make_scene(9, **NOISY_SCENE)
    T_init = _start_pose(scene.T_true, 10)
    result = refine(build_track_set(scene.motions, FOCAL), T_init)
    _assert_closer_than_start_and_consistent(result, scene.T_true)
    assert np.all(result.track_inliers)
    # 1080 observations: the estimated noise is within ~5% of the truth, allow 20%.
    assert result.sigma_px == pytest.approx(NOISE_PX, rel=0.2)
    cov = result.covariance
    np.testing.assert_allclose(cov, cov.T, rtol=1e-9, atol=0)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def _assert_closer_than_start_and_consistent(result, T_true: np.ndarray) -> None:
    rot_err, trans_err = pose_errors(result.T_camera_base, T_true)
    assert rot_err < START_ROT / 5
    assert trans_err < START_TRANS / 2
    xi = pose_difference(result.T_camera_base, T_true)
    assert xi @ np.linalg.solve(result.covariance, xi) < CHI2_6_999


def test_refine_drops_a_jumping_track():
    scene = _make_scene(11, **NOISY_SCENE)
    axis, pivot, tracks = scene.motions[2]
    uv, delta = tracks[3]
    jumped = uv.copy()
    jumped[15:] += np.array([25.0, -15.0]) / FOCAL  # the tracker jumped to another feature
    scene.motions[2] = (axis, pivot, [*tracks[:3], (jumped, delta), *tracks[4:]])
    result = refine(build_track_set(scene.motions, FOCAL), _start_pose(scene.T_true, 12))
    expected = np.ones(36, dtype=bool)
    expected[2 * 6 + 3] = False
    np.testing.assert_array_equal(result.track_inliers, expected)
    assert np.all(np.isnan(result.points_base[~expected]))
    _assert_closer_than_start_and_consistent(result, scene.T_true)


def _slide(scene: Scene, motion: int, k: int, distance: float) -> int:
    """Make track k of a motion slide ``distance`` m over its link during the sweep, against the turn (its noise
    kept): a corner that follows an outline or a highlight. Returns the track's index in the scene."""
    axis, pivot, tracks = scene.motions[motion]
    uv, delta = tracks[k]
    index = motion * len(tracks) + k
    p0 = scene.points[index]
    along = np.cross(axis, p0 - pivot)
    along /= np.linalg.norm(along)
    turns = Rotation.from_rotvec(np.outer(delta, axis))
    R, t = scene.T_true[:3, :3], scene.T_true[:3, 3]
    fixed = project_normalized((turns.apply(p0 - pivot) + pivot) @ R.T + t)
    sliding = p0 + np.outer(np.linspace(0.0, 1.0, delta.size), along) * distance
    moved = project_normalized((turns.apply(sliding - pivot) + pivot) @ R.T + t)
    scene.motions[motion] = (axis, pivot, [*tracks[:k], (moved + (uv - fixed), delta), *tracks[k + 1:]])
    return index


def test_split_half_residuals_vanish_for_fixed_points_and_grow_with_a_slide():
    for distance in (0.01, 0.02):
        scene = _make_scene(13)
        slider = _slide(scene, 1, 2, distance)
        split = split_half_residuals(build_track_set(scene.motions, FOCAL), scene.T_true)
        assert np.max(np.delete(split, slider)) < 1e-8  # noise-free fixed points: one point fits both halves
        # 1 cm of slide over a 20-frame sweep misses the other half by ~2 px (measured 2.08), twice that for 2 cm.
        assert split[slider] == pytest.approx(2.08 * distance / 0.01, rel=0.1)


def test_split_half_residuals_leave_short_tracks_untested():
    scene = _make_scene(13, n_frames=7)  # halves of 3 and 4 frames: fewer than SPLIT_MIN_FRAMES in one
    assert np.all(np.isnan(split_half_residuals(build_track_set(scene.motions, FOCAL), scene.T_true)))


def test_refine_with_max_split_drops_a_slow_slide_the_outlier_bound_keeps():
    scene = _make_scene(11, **NOISY_SCENE)
    slider = _slide(scene, 2, 3, 0.005)
    tracks = build_track_set(scene.motions, FOCAL)
    T_init = _start_pose(scene.T_true, 12)
    assert np.all(refine(tracks, T_init).track_inliers)  # 5 mm over the sweep is within the residual bound
    split = split_half_residuals(tracks, scene.T_true)
    assert split[slider] > 2.0 and np.max(np.delete(split, slider)) < 1.5  # at 0.5 px noise
    result = refine(tracks, T_init, RefinementConfig(max_split_px=1.8))
    expected = np.ones(tracks.n_tracks, dtype=bool)
    expected[slider] = False
    np.testing.assert_array_equal(result.track_inliers, expected)
    _assert_closer_than_start_and_consistent(result, scene.T_true)
    with pytest.raises(InvalidInputError, match="max_split_px"):
        RefinementConfig(max_split_px=0.0)


def test_reprojection_residuals_vanish_at_truth_and_show_a_jump():
    scene = _make_scene(11, **NOISY_SCENE | {"noise_px": 0.0})
    axis, pivot, tracks = scene.motions[2]
    uv, delta = tracks[3]
    jumped = uv.copy()
    jumped[15:] += np.array([25.0, -15.0]) / FOCAL
    scene.motions[2] = (axis, pivot, [*tracks[:3], (jumped, delta), *tracks[4:]])
    track_set = build_track_set(scene.motions, FOCAL)
    truth = RefinementResult(scene.T_true, np.eye(6), scene.points, np.ones(36, dtype=bool), 0.0, 0.0)
    res = reprojection_residuals(track_set, truth)
    on_jumped = track_set.track == 2 * 6 + 3
    assert res.shape == (track_set.uv.shape[0], 2) and np.max(np.abs(res[~on_jumped])) < 1e-9
    np.testing.assert_allclose(res[on_jumped][15:], np.tile([-25.0, 15.0], (len(uv) - 15, 1)), atol=1e-6)
    # a refinement's own residuals: NaN on the track it dropped, its RMS over the rest
    result = refine(track_set, _start_pose(scene.T_true, 12))
    res = reprojection_residuals(track_set, result)
    kept = result.track_inliers[track_set.track]
    assert not result.track_inliers[2 * 6 + 3] and np.all(np.isnan(res[~kept]))
    assert np.sqrt(np.mean(res[kept] ** 2)) == pytest.approx(result.rms_px, rel=1e-9)


def test_pose_covariance_is_the_pose_block_of_the_full_inverse():
    scene = _make_scene(13, n_motions=3, n_tracks=3, n_frames=10)
    tracks = build_track_set(scene.motions, FOCAL)
    problem = _Problem(tracks, scene.T_true)
    x = np.concatenate([np.zeros(6), _camera_points(scene).ravel()])
    J = problem.jacobian(x)
    sigma2 = 0.25
    full = sigma2 * np.linalg.inv((J.T @ J).toarray())
    np.testing.assert_allclose(pose_covariance(problem, x, sigma2), full[:6, :6], rtol=1e-6)


def test_clustered_covariance_is_the_pose_block_of_the_dense_sandwich():
    # Independent construction: the full dense Jacobian, H = J^T J, and the sandwich
    # H^-1 (sum over tracks of J_t^T r_t r_t^T J_t) H^-1 over all unknowns; its pose block.
    scene = _make_scene(17, n_motions=3, n_tracks=4, n_frames=10)
    tracks = build_track_set(scene.motions, FOCAL)
    problem = _Problem(tracks, scene.T_true)
    rng = np.random.default_rng(3)
    points = _camera_points(scene) + rng.normal(0, 2e-3, (len(scene.points), 3))
    x = np.concatenate([rng.normal(0, 1e-3, 6), points.ravel()])
    J = problem.jacobian(x).toarray()
    r = problem.residuals(x)
    H_inv = np.linalg.inv(J.T @ J)
    rows = np.repeat(tracks.track, 2)
    meat = sum(np.outer(J[rows == t].T @ r[rows == t], J[rows == t].T @ r[rows == t]) for t in range(tracks.n_tracks))
    T, m, n = tracks.n_tracks, r.size, x.size
    expected = (H_inv @ meat @ H_inv)[:6, :6] * T / (T - 1) * m / (m - n)
    # at a non-optimal x the point scores are not zero: the marginalized score keeps their effect
    np.testing.assert_allclose(clustered_pose_covariance(problem, x), expected, rtol=1e-6,
                               atol=1e-9 * np.abs(expected).max())


def test_conservative_covariance_is_the_larger_in_every_direction():
    rng = np.random.default_rng(4)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    model, other = A @ A.T + np.eye(6), B @ B.T + 0.1 * np.eye(6)
    out = conservative_covariance(model, other)
    np.testing.assert_allclose(out, out.T)
    assert np.linalg.eigvalsh(out - model).min() > -1e-9 * np.abs(out).max()
    assert np.linalg.eigvalsh(out - other).min() > -1e-9 * np.abs(out).max()
    np.testing.assert_allclose(conservative_covariance(model, 0.5 * model), model, rtol=1e-9)
    np.testing.assert_allclose(conservative_covariance(model, 3.0 * model), 3.0 * model, rtol=1e-9)


def test_conservative_covariance_reads_both_triangles():
    """Inputs asymmetric by rounding (an LU inverse) give the result of their symmetric parts: eigh alone reads one
    triangle, so a lower triangle 1e-3 off moved the result by that much (a model that lost definiteness there
    failed its Cholesky)."""
    rng = np.random.default_rng(7)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    model, other = A @ A.T + np.eye(6), B @ B.T + 0.1 * np.eye(6)
    skew = np.tril(rng.normal(size=(6, 6)), -1) * 1e-3
    expected = conservative_covariance(model, other)
    out = conservative_covariance(model + skew - skew.T, other - skew + skew.T)
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    # the one-triangle reading it replaces differs by about the skew
    lower_only = scipy.linalg.eigh(np.tril(other - skew) + np.tril(other - skew, -1).T,
                                   np.tril(model + skew) + np.tril(model + skew, -1).T)
    assert not np.allclose(lower_only[0], scipy.linalg.eigh(other, model)[0], rtol=1e-6)


@pytest.mark.parametrize("clusters", [3, 5])
def test_few_clusters_factor_brings_an_interval_from_few_clusters_to_its_level(clusters):
    """Simulated: G cluster means, the mean's variance estimated from their scatter (s^2 / G). The normal's 95 %
    interval covers the truth far less often (81 % at G = 3, 88 % at 5); taken the factor times wider, 95 %."""
    rng = np.random.default_rng(clusters)
    trials = 40_000
    means = rng.normal(0.3, 2.0, size=(trials, clusters))
    variance = means.var(axis=1, ddof=1) / clusters
    error = np.abs(means.mean(axis=1) - 0.3)
    z = scipy.stats.norm.ppf(0.975)
    plain = float(np.mean(error <= z * np.sqrt(variance)))
    widened = float(np.mean(error <= z * np.sqrt(few_clusters_factor(clusters) * variance)))
    assert abs(widened - 0.95) < 0.006  # 3.5 standard errors of 40 000 trials
    assert plain < 0.9


def test_few_clusters_factor_falls_to_one_and_refuses_bad_input():
    factors = [few_clusters_factor(g) for g in (2, 3, 4, 6, 30, 1000)]
    assert all(np.diff(factors) < 0)
    assert factors[-1] == pytest.approx(1.0, abs=0.01)
    assert few_clusters_factor(3, 0.99) > few_clusters_factor(3)
    for clusters, level in [(1, 0.95), (3, 0.0), (3, 1.0), (3, float("nan"))]:
        with pytest.raises(InvalidInputError):
            few_clusters_factor(clusters, level)


def test_pose_information_is_the_inverse_pose_block_from_finite_differences():
    # Independent construction: the full Fisher matrix from a finite-difference Jacobian of the
    # residuals at the truth, inverted, pose block, inverted back (= the Schur complement).
    scene = _make_scene(14, n_motions=3, n_tracks=3, n_frames=10)
    tracks = build_track_set(scene.motions, FOCAL)
    problem = _Problem(tracks, scene.T_true)
    J = _finite_difference_jacobian(problem, np.concatenate([np.zeros(6), _camera_points(scene).ravel()]))
    expected = np.linalg.inv(np.linalg.inv(J.T @ J)[:6, :6])
    info = pose_information(tracks, scene.T_true)
    np.testing.assert_allclose(info, expected, rtol=1e-4, atol=1e-6 * np.abs(expected).max())
    np.testing.assert_allclose(info, info.T, rtol=0, atol=1e-9 * np.abs(info).max())


def test_pose_information_adds_over_motions_and_ignores_static_tracks():
    scene = _make_scene(15, n_motions=4, n_tracks=4, n_frames=12)
    whole = pose_information(build_track_set(scene.motions, FOCAL), scene.T_true)
    parts = sum(pose_information(build_track_set(scene.motions[i:i + 2], FOCAL), scene.T_true)
                for i in (0, 2))
    np.testing.assert_allclose(whole, parts, rtol=1e-8, atol=1e-8 * np.abs(whole).max())
    axis, pivot, tracks = scene.motions[0]
    static = (tracks[0][0][:1].repeat(12, axis=0), np.zeros(12))  # a point that never moves
    with_static = pose_information(build_track_set([*scene.motions, (axis, pivot, [static])], FOCAL),
                                   scene.T_true)
    np.testing.assert_allclose(with_static, whole, rtol=1e-8, atol=1e-8 * np.abs(whole).max())


#: Truncation of the screening score in the tests, px.
CAP_PX = 3.0


def test_screen_start_scores_the_true_pose_best_and_counts_tracks_behind_the_camera():
    scene = _make_scene(16, n_motions=3, n_tracks=4, noise_px=NOISE_PX)
    tracks = build_track_set(scene.motions, FOCAL)
    config = RefinementConfig()
    T_true = scene.T_true
    _, at_truth = screen_start(tracks, T_true, config, 10, CAP_PX)
    assert at_truth < 2 * NOISE_PX**2  # residual variance per coordinate, ~NOISE_PX^2 minus the fitted points
    deeper = T_true.copy()
    deeper[:3, 3] *= 1.5  # the scene half as far again along the camera's rays
    _, at_deeper = screen_start(tracks, deeper, config, 10, CAP_PX)
    assert at_deeper > 4 * at_truth
    away = T_true.copy()
    turn = Rotation.from_rotvec([0.0, np.pi, 0.0])
    away[:3, :3] = turn.as_matrix() @ T_true[:3, :3]
    away[:3, 3] = turn.apply(T_true[:3, 3])  # the camera turned to look away from the scene
    _, ok = triangulate_tracks(tracks, away)
    assert 0 < ok.sum() < ok.size  # the rays meet a mirrored scene for some tracks only
    left_out = float(np.mean(~ok[tracks.track]))
    _, at_away = screen_start(tracks, away, config, 10, CAP_PX)
    assert left_out * CAP_PX**2 <= at_away <= CAP_PX**2  # every observation of a left-out track costs the cap
    # with only the tracks that cannot be triangulated, nothing is scored
    flat = [(m, track) for m, (_, _, ts) in enumerate(scene.motions) for track in ts]
    behind = [(axis, pivot, [track for (m, track), k in zip(flat, ~ok, strict=True) if k and m == i])
              for i, (axis, pivot, _) in enumerate(scene.motions)]
    T_end, score = screen_start(build_track_set(behind, FOCAL), away, config, 10, CAP_PX)
    assert score == np.inf and np.array_equal(T_end, away)


def test_track_observability_finds_the_free_depth_of_axes_through_one_point():
    pivot = np.array([0.1, -0.05, 0.2])
    scene = _make_scene(17, n_motions=4, n_tracks=4, pivot=pivot)
    ratio, direction = track_observability(build_track_set(scene.motions, FOCAL), scene.T_true)
    assert ratio < 1e-6  # noise-free: only rounding
    # the free direction scales the scene about the camera centre: tau along the pivot's ray, omega zero
    ray = scene.T_true[:3, :3] @ pivot + scene.T_true[:3, 3]
    assert abs(direction[3:] @ ray) / (np.linalg.norm(direction) * np.linalg.norm(ray)) > 1 - 1e-6
    free = _make_scene(17, n_motions=4, n_tracks=4)
    ratio, _ = track_observability(build_track_set(free.motions, FOCAL), free.T_true)
    assert ratio > 1e-2
    keep = np.zeros(16, dtype=bool)
    keep[:4] = True  # one motion's tracks alone: its own axis's depth is free
    assert track_observability(build_track_set(free.motions, FOCAL), free.T_true, keep)[0] < 1e-6


def test_symmetric_inverse_is_symmetric_and_positive_definite_however_ill_conditioned():
    """Eigenvalues 1e-2 (a weak prior on free directions) beside 1e6-6e7 (what the tracks fix), 50 random
    orientations: the inverse is symmetric, its lower triangle alone positive definite (what a Cholesky reads,
    as scipy's generalized eigh in ``conservative_covariance`` does) and each direction's variance 1 / its
    eigenvalue (built from the known rotation). An LU inverse (``np.linalg.inv``) fails the Cholesky on most."""
    lam = np.array([1e-2, 1e-2, 1e-2, 1e6, 1.5e6, 6e7])
    lu_fails = 0
    for seed in range(50):
        V = np.linalg.qr(np.random.default_rng(seed).normal(size=(6, 6)))[0]
        S = (V * lam) @ V.T
        S_inv = _symmetric_inverse(S)
        assert np.abs(S_inv - S_inv.T).max() <= 1e-12 * np.abs(S_inv).max()
        np.linalg.cholesky(S_inv)
        assert np.allclose(np.einsum("ij,jk,ki->i", V.T, S_inv, V), 1.0 / lam, rtol=1e-5, atol=0.0)
        try:
            np.linalg.cholesky(np.linalg.inv(S))
        except np.linalg.LinAlgError:
            lu_fails += 1
    assert lu_fails > 25  # measured: 157 of 200 orientations
    V = np.linalg.qr(np.random.default_rng(0).normal(size=(6, 6)))[0]
    with pytest.raises(np.linalg.LinAlgError):
        _symmetric_inverse((V * np.array([-1e-3, 1, 1, 1, 1, 1])) @ V.T)
    # a null direction left at rounding's size (seen: 9.4e-16 of the largest)
    with pytest.raises(np.linalg.LinAlgError):
        _symmetric_inverse((V * np.array([1.4e-8, 1.0, 1e3, 1e5, 1e6, 1.4e7])) @ V.T)


def test_refine_held_in_every_direction_frees_only_what_the_tracks_leave_free():
    """Axes through one point leave the depth free: held weakly in every direction (the identity), the adjustment
    exists, says the line is free and fixes the rest as when held along the line alone; dependent directions are
    refused."""
    pivot = np.array([0.1, -0.05, 0.2])
    scene = _make_scene(17, n_motions=4, n_tracks=6, n_frames=30, noise_px=NOISE_PX, pivot=pivot)
    tracks = build_track_set(scene.motions, FOCAL)
    ray = scene.T_true[:3, :3] @ pivot + scene.T_true[:3, 3]
    ray /= np.linalg.norm(ray)
    start = perturb(scene.T_true, np.array([0.002, -0.001, 0.001, 0.001, 0.002, -0.001]))
    w = np.concatenate([np.zeros(3), ray])
    line = refine(tracks, start, free_direction=w)
    every = refine(tracks, start, free_direction=np.eye(6))
    assert np.sqrt(w @ every.covariance @ w) > 0.5  # free along the line (metres)
    Q = np.eye(6) - np.outer(w, w)
    e = Q @ pose_difference(every.T_camera_base, scene.T_true)
    assert e @ np.linalg.pinv(Q @ every.covariance @ Q, rcond=1e-10) @ e < CHI2_6_999
    d = Q @ pose_difference(every.T_camera_base, line.T_camera_base)  # the rest as held along the line alone
    assert np.linalg.norm(d[:3]) < 1e-4 and np.linalg.norm(d[3:]) < 1e-4
    sd_line, sd_every = (np.sqrt(np.diag(Q @ r.covariance @ Q)) for r in (line, every))
    assert np.allclose(sd_every, sd_line, rtol=0.05, atol=1e-6)
    with pytest.raises(InvalidInputError, match="independent"):
        refine(tracks, start, free_direction=np.stack([w, 2 * w]))
    with pytest.raises(InvalidInputError, match="free directions"):
        refine(tracks, start, free_direction=np.eye(7)[:, :6])


def test_refine_held_along_a_free_direction_fixes_the_rest():
    """Axes through one point leave the depth free: held there, the adjustment fixes the rest and says so."""
    pivot = np.array([0.1, -0.05, 0.2])
    scene = _make_scene(17, n_motions=4, n_tracks=6, n_frames=30, noise_px=NOISE_PX, pivot=pivot)
    tracks = build_track_set(scene.motions, FOCAL)
    ray = scene.T_true[:3, :3] @ pivot + scene.T_true[:3, 3]
    ray /= np.linalg.norm(ray)
    moved = scene.T_true.copy()
    moved[:3, 3] += 0.2 * ray  # 20 cm along the free line: the tracks fit it as well
    start = perturb(moved, np.array([0.002, -0.001, 0.001, 0.001, 0.002, -0.001]))
    with pytest.raises(np.linalg.LinAlgError):  # not held, its covariance does not exist
        refine(tracks, start)
    ratio, weakest = track_observability(tracks, moved)
    assert ratio < 1e-6  # the pose Jacobian's null vector whatever the noise (measured: 0.0)
    assert abs(weakest[3:] @ ray) > 0.99  # the weakest direction is the line
    w = np.concatenate([np.zeros(3), ray])
    held = refine(tracks, start, free_direction=w)
    err = pose_difference(held.T_camera_base, moved)
    assert abs(err[3:] @ ray) < 0.01  # held where it started along the line (measured: 0.8 mm from it)
    assert np.sqrt(w @ held.covariance @ w) > 0.5  # and says it is free there (metres)
    Q = np.eye(6) - np.outer(w, w)  # elsewhere the honest covariance holds the error
    e = Q @ err
    assert e @ np.linalg.pinv(Q @ held.covariance @ Q, rcond=1e-10) @ e < CHI2_6_999
    assert np.linalg.norm(e[:3]) < 5e-3 and np.linalg.norm(e[3:]) < 5e-3
    with pytest.raises(InvalidInputError, match="schur"):
        refine(tracks, start, RefinementConfig(backend="scipy"), free_direction=w)
    with pytest.raises(InvalidInputError, match="free direction"):
        refine(tracks, start, free_direction=np.zeros(6))


def test_refine_rejects_non_finite_start():
    scene = _make_scene(14, n_motions=2, n_tracks=2)
    T = scene.T_true.copy()
    T[0, 3] = np.nan
    with pytest.raises(InvalidInputError, match="T_init contains NaN"):
        refine(build_track_set(scene.motions, FOCAL), T)


def test_refine_needs_two_tracks():
    scene = _make_scene(15, n_motions=1, n_tracks=1)
    with pytest.raises(InsufficientMotionsError, match="fewer than two tracks"):
        refine(build_track_set(scene.motions, FOCAL), scene.T_true)


def test_motion_jackknife_is_the_spread_of_leave_one_motion_out_refits():
    """Linear least squares with M clusters of rows: the one-step jackknife is exact (independent refits)."""
    rng = np.random.default_rng(11)
    n, M = 6, 9
    A = [rng.normal(size=(int(rng.integers(8, 20)), n)) for _ in range(M)]
    y = [a @ rng.normal(size=n) + rng.normal(size=len(a)) for a in A]
    A_all, y_all = np.vstack(A), np.concatenate(y)
    x_hat = np.linalg.lstsq(A_all, y_all, rcond=None)[0]
    H = np.array([a.T @ a for a in A])
    g = np.array([a.T @ (a @ x_hat - b) for a, b in zip(A, y, strict=True)])  # each motion's score J^T r
    refits = np.array([np.linalg.lstsq(np.vstack(A[:m] + A[m + 1:]), np.concatenate(y[:m] + y[m + 1:]),
                                       rcond=None)[0] for m in range(M)])
    d = refits - refits.mean(axis=0)
    expected = (M - 1) / M * d.T @ d
    got = motion_jackknife_covariance(H, g, H.sum(axis=0), max_leverage=0.999)  # no leverage reaches the cap here
    np.testing.assert_allclose(got, expected, rtol=1e-8, atol=1e-12 * np.abs(expected).max())


def test_motion_jackknife_caps_a_motion_that_alone_fixes_a_direction():
    """One motion alone informs the last parameter: left out, it is undetermined; capped, its shift is bounded."""
    rng = np.random.default_rng(12)
    n, M = 3, 6
    A = [np.hstack([rng.normal(size=(10, n - 1)), np.zeros((10, 1))]) for _ in range(M - 1)]
    A.append(rng.normal(size=(10, n)))  # the only rows that see the last parameter
    y = [a @ np.ones(n) + rng.normal(size=10) for a in A]
    x_hat = np.linalg.lstsq(np.vstack(A), np.concatenate(y), rcond=None)[0]
    H = np.array([a.T @ a for a in A])
    g = np.array([a.T @ (a @ x_hat - b) for a, b in zip(A, y, strict=True)])
    out = motion_jackknife_covariance(H, g, H.sum(axis=0), max_leverage=0.9)
    assert np.all(np.isfinite(out)) and np.linalg.eigvalsh(out).min() > -1e-12 * np.abs(out).max()
    wider = motion_jackknife_covariance(H, g, H.sum(axis=0), max_leverage=0.99)
    assert wider[-1, -1] > out[-1, -1]  # the closer to 1 the cap, the larger the unverifiable direction's variance
    with pytest.raises(InvalidInputError):
        motion_jackknife_covariance(H, g, H.sum(axis=0), max_leverage=1.0)


def _summary(information):
    n = len(information)
    return MotionSummary(0, np.eye(4), None, information, np.zeros(n), np.zeros((n, n)), 0.0, 2, 1)


def test_newest_motion_leverage_is_the_largest_share_of_variance_it_removes():
    """Independent construction: the pose variance without the last motion, (S - H_m)^-1, against with it, S^-1;
    the largest share it removes along any direction is 1 - min_u (u^T S^-1 u) / (u^T (S - H_m)^-1 u)."""
    rng = np.random.default_rng(13)
    for n_motions in (2, 5, 20):
        informations = []
        for _ in range(n_motions):
            A = rng.normal(size=(int(rng.integers(8, 30)), 6)) * rng.uniform(0.1, 10.0, size=6)
            informations.append(A.T @ A)
        S = sum(informations)
        ratios = scipy.linalg.eigh(np.linalg.inv(S), np.linalg.inv(S - informations[-1]), eigvals_only=True)
        assert newest_motion_leverage([_summary(h) for h in informations]) == pytest.approx(1 - ratios.min(), rel=1e-9)
    # a motion that alone informs a direction carries all of it; a copy of the others' total, half of each
    others = np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 0.0])
    assert newest_motion_leverage([_summary(others), _summary(np.eye(6))]) == pytest.approx(1.0)
    assert newest_motion_leverage([_summary(np.eye(6)), _summary(np.eye(6))]) == pytest.approx(0.5)
    with pytest.raises(InvalidInputError):
        newest_motion_leverage([])
    with pytest.raises(InvalidInputError):
        newest_motion_leverage([_summary(others)])  # singular in total


def test_refinement_config_defaults():
    config = RefinementConfig()
    assert config.outlier_px == 0.5
    assert config.min_track_frames == 4


def test_residuals_are_in_pixels():
    scene = _make_scene(16, n_motions=1, n_tracks=2)
    tracks = build_track_set(scene.motions, FOCAL)
    problem = _Problem(tracks, scene.T_true)
    points = _camera_points(scene)
    x = np.concatenate([np.zeros(6), points.ravel()])
    shifted = x.copy()
    shifted[6] += 1e-4  # move the first point 0.1 mm along camera x: u changes by exactly 1e-4 / z
    z = points[0, 2]  # frame 0 has delta = 0
    assert problem.residuals(shifted)[0] == pytest.approx(FX * 1e-4 / z, rel=1e-6)
    assert problem.residuals(shifted)[1] == pytest.approx(0.0, abs=1e-9)


# -- the time offset between the joint clock and the camera clock -------------------------------------------------

#: Frame rate of the timed scenes, Hz, and their joint log's latency, s (stamped late: d = +20 ms).
FPS, LATENCY_S = 30.0, 0.020


def _timed_scene(seed: int, latency_s: float, n_motions: int = 6, n_tracks: int = 6, noise_px: float = NOISE_PX,
                 turn_s: float = 1.2, rest_s: float = 0.1) -> Scene:
    """Sweeps timed as a robot makes them: rest, a cosine speed profile over turn_s, rest; frames at FPS.

    The pixels follow the true turn at each exposure; each track's delta and velocity are read from a joint
    log stamped ``latency_s`` late (the joint value at exposure t is the true one at t - latency_s), as a
    recording without ``--time-offset`` gives them. Same seed, same pixels and noise whatever the latency.
    """
    rng = np.random.default_rng(seed)
    T = random_pose(rng)
    R, t = T[:3, :3], T[:3, 3]
    times = np.arange(0.0, turn_s + 2 * rest_s, 1.0 / FPS)
    motions, points = [], []
    for _ in range(n_motions):
        axis, pivot = random_unit(rng), rng.uniform(-0.3, 0.3, 3)
        turn = rng.uniform(0.8, 1.5) * rng.choice([-1.0, 1.0])
        phase = lambda s: np.clip((s - rest_s) / turn_s, 0.0, 1.0)  # noqa: E731
        angle = lambda s: turn * (1 - np.cos(np.pi * phase(s))) / 2  # noqa: E731, B023
        speed = lambda s: turn * np.pi / (2 * turn_s) * np.sin(np.pi * phase(s))  # noqa: E731, B023
        turns = Rotation.from_rotvec(np.outer(angle(times), axis))
        logged, velocity = angle(times - latency_s), speed(times - latency_s)
        tracks = []
        for _ in range(n_tracks):
            p0 = pivot + random_unit(rng) * rng.uniform(0.05, 0.25)
            uv = project_normalized((turns.apply(p0 - pivot) + pivot) @ R.T + t)
            uv = uv + rng.normal(0.0, noise_px, uv.shape) / FOCAL
            tracks.append((uv, logged - logged[0], velocity))
            points.append(p0)
        motions.append((axis, pivot, tracks))
    return Scene(T, motions, np.array(points))


def _without_velocity(motions: list) -> list:
    return [(axis, pivot, [(uv, delta) for uv, delta, _ in tracks]) for axis, pivot, tracks in motions]


def test_jacobian_with_time_offset_matches_finite_differences():
    scene = _timed_scene(1, LATENCY_S, n_motions=3, n_tracks=2)
    tracks = build_track_set(scene.motions, FOCAL)
    rng = np.random.default_rng(2)
    x = np.concatenate([0.02 * random_unit(rng), rng.normal(0, 0.02, 3), [0.013],
                        (_camera_points(scene) + rng.normal(0, 0.01, scene.points.shape)).ravel()])
    problem = _Problem(tracks, _start_pose(scene.T_true, 3), prior_weight=5.0)
    J = problem.jacobian(x)
    assert J.shape == problem.shape == (2 * tracks.uv.shape[0] + 1, 7 + 3 * tracks.n_tracks)
    J = J.toarray()
    np.testing.assert_allclose(J, _finite_difference_jacobian(problem, x), rtol=JACOBIAN_RTOL,
                               atol=JACOBIAN_RTOL * np.abs(J).max())
    assert problem.residuals(x)[-1] == pytest.approx(5.0 * 0.013)  # the prior's residual, px
    white = _Whitened(problem, x)
    z = rng.normal(0, 0.5, x.size)
    Jz = white.jacobian(z).toarray()
    np.testing.assert_allclose(Jz, _finite_difference_jacobian(white, z), rtol=JACOBIAN_RTOL,
                               atol=JACOBIAN_RTOL * np.abs(Jz).max())


#: The estimate is within this many of its reported 1-sigma of the latency (a 4-sigma miss: 6e-5 if Gaussian) ...
OFFSET_SIGMAS = 4.0
#: ... and that 1-sigma is small enough to be useful, s (measured 0.20-0.32 ms on seeds 20-31 at 0.5 px, the
#: estimates 0.2-2.6 sigma from 20 ms: the first-order model leaves the joint's acceleration times latency^2 / 2).
USEFUL_OFFSET_STD_S = 1e-3
#: Median of chi-square with 6 degrees of freedom: the pose with the latency estimated differs from the pose an
#: on-time joint log gives (the same pixels) by less than half the noise's spread (measured 0.3-2.2 on seeds
#: 20-31; with the latency left alone 2.2-193).
CHI2_6_50 = 5.35


@pytest.mark.parametrize("seed", [21, 24])
def test_refine_recovers_a_joint_log_latency_and_the_pose(seed):
    lagging = _timed_scene(seed, LATENCY_S)
    exact = _timed_scene(seed, 0.0)  # the same pixels, a joint log on time
    T_init = _start_pose(lagging.T_true, seed)
    estimated = refine(build_track_set(lagging.motions, FOCAL), T_init)  # velocities given: on by default
    assert estimated.time_offset_std_s < USEFUL_OFFSET_STD_S
    assert abs(estimated.time_offset_s - LATENCY_S) < OFFSET_SIGMAS * estimated.time_offset_std_s
    assert estimated.time_offset_correlation.shape == (6,)
    assert np.all(np.abs(estimated.time_offset_correlation) < 1)
    reference = refine(build_track_set(_without_velocity(exact.motions), FOCAL), T_init)
    fixed = refine(build_track_set(_without_velocity(lagging.motions), FOCAL), T_init)
    # with the latency estimated the pose is about where the on-time log puts it (the same noise); left alone
    # the latency moves it far out (these seeds: beyond the 99.9% region)
    xi = pose_difference(estimated.T_camera_base, reference.T_camera_base)
    assert xi @ np.linalg.solve(reference.covariance, xi) < CHI2_6_50
    xi = pose_difference(fixed.T_camera_base, reference.T_camera_base)
    assert xi @ np.linalg.solve(reference.covariance, xi) > CHI2_6_999
    _assert_closer_than_start_and_consistent(estimated, lagging.T_true)


def test_time_offset_estimation_off_changes_nothing():
    scene = _timed_scene(23, LATENCY_S)
    T_init = _start_pose(scene.T_true, 23)
    off = refine(build_track_set(scene.motions, FOCAL), T_init, RefinementConfig(estimate_time_offset=False))
    plain = refine(build_track_set(_without_velocity(scene.motions), FOCAL), T_init)  # today's tracks: off
    assert plain.time_offset_s is None and plain.time_offset_std_s is None and off.time_offset_s is None
    for a, b in ((off.T_camera_base, plain.T_camera_base), (off.covariance, plain.covariance),
                 (off.points_base, plain.points_base)):
        assert np.array_equal(a, b, equal_nan=True)
    assert (off.rms_px, off.sigma_px) == (plain.rms_px, plain.sigma_px)


def test_time_offset_estimate_needs_velocities_and_stays_within_its_bound():
    scene = _timed_scene(24, LATENCY_S, n_motions=4, n_tracks=4)
    T_init = _start_pose(scene.T_true, 24)
    some = list(scene.motions)
    some[0] = _without_velocity(some[:1])[0]  # one motion without joint velocities: off by default
    assert build_track_set(some, FOCAL).velocity is None
    assert refine(build_track_set(some, FOCAL), T_init).time_offset_s is None
    with pytest.raises(InvalidInputError, match="not every track carries the joint's velocity"):
        refine(build_track_set(some, FOCAL), T_init, RefinementConfig(estimate_time_offset=True))
    with pytest.raises(TimeOffsetError, match=r"\+20\.\d ms .* beyond the \+-10 ms"):
        refine(build_track_set(scene.motions, FOCAL), T_init, RefinementConfig(time_offset_bound_s=0.01))
    with pytest.raises(InvalidInputError, match="time_offset_bound_s must be > 0"):
        RefinementConfig(time_offset_bound_s=0.0)


def test_motion_overdispersion_is_chi_square_with_independent_noise_and_large_with_shared_errors():
    """Linear least squares, M clusters: scores follow the model's spread unless a cluster shares an error."""
    rng = np.random.default_rng(13)
    n, M, sigma = 6, 12, 0.5
    A = [rng.normal(size=(40, n)) for _ in range(M)]
    H = np.array([a.T @ a for a in A])
    S = H.sum(axis=0)

    def q_over_dof(shared: float) -> float:
        values = []
        for _ in range(200):
            y = [a @ np.ones(n) + rng.normal(0, sigma, len(a)) + rng.normal(0, shared) * a[:, 0] for a in A]
            x_hat = np.linalg.solve(S, sum(a.T @ b for a, b in zip(A, y, strict=True)))
            g = np.array([a.T @ (a @ x_hat - b) for a, b in zip(A, y, strict=True)])
            q, dof = motion_overdispersion(H, g, S, sigma**2)
            values.append(q / dof)
        return float(np.mean(values))

    assert q_over_dof(0.0) == pytest.approx(1.0, abs=0.1)  # chi-square: its mean is its degrees of freedom
    assert q_over_dof(0.5) > 3.0  # each cluster's own error along one regressor: far more spread


def test_motion_overdispersion_without_noise_has_no_terms():
    H = np.array([np.eye(3), 2 * np.eye(3)])
    assert motion_overdispersion(H, np.zeros((2, 3)), H.sum(axis=0), 0.0) == (0.0, 0)


def test_the_block_operator_solves_the_damped_least_squares_problem():
    """Against the dense Jacobian assembled entry by entry and numpy's least squares of [J; damp I] x = [f; 0]."""
    rng = np.random.default_rng(21)
    n_obs = np.array([3, 1, 4, 2])  # observations per track
    track = np.repeat(np.arange(n_obs.size), n_obs)
    blocks = rng.normal(size=(track.size, 2, 9))
    f = rng.normal(size=2 * track.size)
    J = np.zeros((2 * track.size, 6 + 3 * n_obs.size))
    for p, t in enumerate(track):
        J[2 * p:2 * p + 2, :6] = blocks[p, :, :6]
        J[2 * p:2 * p + 2, 6 + 3 * t:9 + 3 * t] = blocks[p, :, 6:]
    op = _BlockOperator(blocks, track, track_starts(track))
    v = rng.normal(size=J.shape[1])
    np.testing.assert_allclose(op.dot(v), J @ v, rtol=1e-12, atol=1e-12)
    for damp in (0.3, 2.0):
        expected = np.linalg.lstsq(np.vstack([J, damp * np.eye(J.shape[1])]),
                                   np.concatenate([f, np.zeros(J.shape[1])]), rcond=None)[0]
        np.testing.assert_allclose(op.damped_solution(f, damp), expected, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("unseen", ["pose", "point"])
def test_the_block_operator_solves_a_rank_deficient_problem_without_damping(unseen):
    """A pose direction, or one track's point, that no observation moves: no "Singular matrix", a least-squares
    solution (its residual is numpy's least-squares residual of the dense J)."""
    rng = np.random.default_rng(22)
    n_obs = np.array([3, 2, 4, 2])
    track = np.repeat(np.arange(n_obs.size), n_obs)
    blocks = rng.normal(size=(track.size, 2, 9))
    if unseen == "pose":
        blocks[:, :, 2] = 0.0  # the third pose parameter moves nothing
    else:
        blocks[track == 1, :, 6:] = 0.0  # track 1's point moves nothing
    f = rng.normal(size=2 * track.size)
    J = np.zeros((2 * track.size, 6 + 3 * n_obs.size))
    for p, t in enumerate(track):
        J[2 * p:2 * p + 2, :6] = blocks[p, :, :6]
        J[2 * p:2 * p + 2, 6 + 3 * t:9 + 3 * t] = blocks[p, :, 6:]
    x = _BlockOperator(blocks, track, track_starts(track)).damped_solution(f, 0.0)
    best = np.linalg.lstsq(J, f, rcond=None)[0]
    assert np.all(np.isfinite(x))
    assert np.linalg.norm(J @ x - f) == pytest.approx(np.linalg.norm(J @ best - f), rel=1e-9)


@pytest.mark.parametrize("seed", [16, 17, 18])
@pytest.mark.parametrize("max_nfev", [5, 10, 50])
def test_the_subspace_pass_follows_scipys_trf(seed, max_nfev):
    """``_trf_subspace`` against scipy's least_squares (trf, cauchy, lsmr) from a start 3 cm and 0.03 rad off."""
    scene = _make_scene(seed, **NOISY_SCENE)
    tracks = build_track_set(scene.motions, FOCAL)
    config = RefinementConfig()
    start = perturb(scene.T_true, np.array([0.03, -0.02, 0.01, 0.03, 0.01, -0.02]))
    points, _ = triangulate_tracks(tracks, start)
    T_scipy, _, _, _, sol = _solve(tracks, start, points, "cauchy", config.cauchy_scale_px, max_nfev,
                                   ftol=config.robust_ftol, backend="scipy")
    q0 = points @ start[:3, :3].T + start[:3, 3]
    white = _Whitened(_Problem(tracks, start), np.concatenate([np.zeros(6), q0.ravel()]))
    ours = _trf_subspace(white, config.cauchy_scale_px, max_nfev, config.robust_ftol)
    T_ours = perturb(start, white.native(ours.x)[:6])
    moved = np.abs(pose_difference(start, T_scipy)).max()
    assert moved > 0.02  # the passes do move: the comparison is not of two starts
    assert np.abs(pose_difference(T_scipy, T_ours)).max() < SUBSPACE_POSE_FRACTION * moved
    c2 = config.cauchy_scale_px ** 2
    cost_scipy, cost_ours = (0.5 * c2 * np.sum(np.log1p(f ** 2 / c2)) for f in (sol.fun, ours.fun))
    assert abs(cost_ours - cost_scipy) < SUBSPACE_COST_RTOL * cost_scipy


#: The subspace pass and scipy's differ where LSMR's solves (to 1e-12) are inexact: along directions the
#: Gauss-Newton matrix nearly leaves free. Measured on these scenes: poses within 0.4 % of the pass's move
#: (1.2e-4 of 0.031), costs within 2.5e-4 relative. A wrong step (e.g. the damping left out) diverges far more.
SUBSPACE_POSE_FRACTION = 0.01
SUBSPACE_COST_RTOL = 1e-3


def _lagging(scene: Scene, rate: float) -> list:
    """The scene's motions with every other track re-projected as turning by ``rate`` times the joint's turn.

    A corner that follows shading on a smooth link instead of the surface lags it: its arc is about the same
    axis but shorter, while the turns it reports are the joint's.
    """
    R, t = scene.T_true[:3, :3], scene.T_true[:3, 3]
    out, k = [], 0
    for axis, pivot, tracks in scene.motions:
        new = []
        for uv, delta in tracks:
            if k % 2:
                p = Rotation.from_rotvec(np.outer(rate * delta, axis)).apply(scene.points[k] - pivot) + pivot
                uv = project_normalized(p @ R.T + t)
            new.append((uv, delta))
            k += 1
        out.append((axis, pivot, new))
    return out


def test_free_rates_fit_tracks_that_lag_their_surface_and_keep_the_pose_unbiased():
    scene = _make_scene(44, n_motions=6, n_tracks=6, n_frames=20)
    tracks = build_track_set(_lagging(scene, 0.96), FOCAL)  # the median lag of sliding as-shipped tracks
    start = _start_pose(scene.T_true, 45)
    keep_all = {"outlier_px": 1e3, "outlier_sigmas": 1e3, "track_weights": False}
    fixed = refine(tracks, start, RefinementConfig(**keep_all))
    free = refine(tracks, start, RefinementConfig(free_rates="all", **keep_all))
    rot_fixed, trans_fixed = pose_errors(fixed.T_camera_base, scene.T_true)
    rot, trans = pose_errors(free.T_camera_base, scene.T_true)
    assert trans_fixed > 1e-3  # the lag biases the fixed-rate fit by millimetres
    # noise-free: the rate is eliminated to first order about 1 (the rest, (1 - rate)^2 of the turn, is left)
    assert rot < 0.05 * rot_fixed and trans < 0.05 * trans_fixed


def test_free_rates_cost_precision_but_hold_the_truth_when_every_track_turns_with_the_joint():
    scene = _make_scene(46, **NOISY_SCENE)
    tracks, start = build_track_set(scene.motions, FOCAL), _start_pose(scene.T_true, 47)
    fixed = refine(tracks, start, RefinementConfig(track_weights=False))
    free = refine(tracks, start, RefinementConfig(free_rates="all", track_weights=False))
    assert np.all(np.diag(free.covariance) >= np.diag(fixed.covariance) * 0.99)  # less information, never more
    xi = pose_difference(free.T_camera_base, scene.T_true)
    assert xi @ np.linalg.solve(free.covariance, xi) < CHI2_6_999
    assert free.sigma_px == pytest.approx(NOISE_PX, rel=0.15)  # one degree of freedom fewer per track, counted


def test_tested_rates_free_the_lagging_tracks_only():
    scene = _make_scene(48, n_motions=6, n_tracks=8, n_frames=30)
    rng = np.random.default_rng(49)
    noisy = [(axis, pivot, [(uv + rng.normal(0, NOISE_PX, uv.shape) / FOCAL, d) for uv, d in tracks])
             for axis, pivot, tracks in _lagging(scene, 0.96)]
    tracks, start = build_track_set(noisy, FOCAL), _start_pose(scene.T_true, 50)
    keep_all = {"outlier_px": 1e3, "outlier_sigmas": 1e3, "track_weights": False}
    fixed = refine(tracks, start, RefinementConfig(**keep_all))
    # the rate test at the fixed-rate fit: most lagging (odd) tracks flagged, none of the others
    T = fixed.T_camera_base
    problem = _Problem(tracks, T)
    x = np.concatenate([np.zeros(6), (fixed.points_base @ T[:3, :3].T + T[:3, 3]).ravel()])
    flagged = lagging_tracks(problem, x, problem.residuals(x).reshape(-1, 2))
    odd = np.arange(tracks.n_tracks) % 2 == 1
    assert flagged[odd].mean() > 0.6 and not flagged[~odd].any()
    tested = refine(tracks, start, RefinementConfig(free_rates="tested", **keep_all))
    every = refine(tracks, start, RefinementConfig(free_rates="all", **keep_all))
    assert pose_errors(tested.T_camera_base, scene.T_true)[1] < 0.5 * pose_errors(fixed.T_camera_base, scene.T_true)[1]
    xi = pose_difference(tested.T_camera_base, scene.T_true)
    assert xi @ np.linalg.solve(tested.covariance, xi) < CHI2_6_999
    assert np.linalg.det(tested.covariance) < np.linalg.det(every.covariance)  # the others keep their phase
