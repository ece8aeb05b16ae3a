"""Tests of solver/schur.py and the incremental bundle adjustment (solver/refinement.py, solver/pipeline.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import eigh

from solver import PANDA, Calibrator, SyntheticConfig, SyntheticScene, d415_intrinsics, sample_camera_pose
from solver.frames import perturb, pose_difference, pose_errors
from solver.pipeline import CalibratorConfig
from solver.refinement import (
    RefinementConfig,
    _motion_summaries,
    _Problem,
    _with_unweighted,
    build_track_set,
    refine,
    refine_increment,
    start_points,
    summaries_covariance,
    weighted_covariance_bound,
    weights_disagree,
)
from solver.schur import PosePrior, normal_blocks, pose_step_sigmas, solve_schur, track_starts
from tests.solver.scene import FOCAL
from tests.solver.test_refinement import (
    NOISE_FREE_POSE_TOL,
    NOISY_SCENE,
    _camera_points,
    _make_scene,
    _slide,
    _start_pose,
    _timed_scene,
)

#: The incremental estimate must equal the batch one within this fraction of its 1-sigma (issue 18) ...
AGREEMENT_SIGMA = 0.1
#: ... and its 1-sigma the batch one's within this fraction.
STD_RTOL = 0.05


def _std(cov: np.ndarray) -> np.ndarray:
    return np.sqrt(np.diag(cov))


def _largest_ratio(a: np.ndarray, b: np.ndarray) -> float:
    """The largest v^T a v / v^T b v over directions v: how much larger covariance a is than b somewhere."""
    return float(eigh(a, b, eigvals_only=True).max())


def test_normal_blocks_are_the_dense_weighted_normal_equations():
    scene = _make_scene(31, n_motions=3, n_tracks=3, n_frames=9, noise_px=0.5)
    tracks = build_track_set(scene.motions, FOCAL)
    problem = _Problem(tracks, _start_pose(scene.T_true, 32))
    x = np.concatenate([np.zeros(6), _camera_points(scene).ravel()])
    rng = np.random.default_rng(33)
    w = rng.uniform(0.2, 2.0, tracks.uv.shape[0])
    J = problem.jacobian(x).toarray()  # the sparse assembly: an independent path to J
    r = problem.residuals(x)
    Wd = np.repeat(w, 2)
    H, g = J.T @ (Wd[:, None] * J), J.T @ (Wd * r)
    blocks, starts = problem.jacobian_blocks(x), track_starts(tracks.track)
    U, W, V, gp, gx = normal_blocks(blocks, r.reshape(-1, 2), w, starts)
    Ut, Wt, Vt, gpt, gxt = normal_blocks(blocks, r.reshape(-1, 2), w, starts, per_track_pose=True)
    np.testing.assert_allclose(U, H[:6, :6], rtol=1e-10)
    np.testing.assert_allclose(Ut.sum(axis=0), U, rtol=1e-10)
    np.testing.assert_allclose(gp, g[:6], rtol=1e-10, atol=1e-9 * np.abs(g).max())
    np.testing.assert_allclose(gpt.sum(axis=0), gp, rtol=1e-10, atol=1e-9 * np.abs(g).max())
    np.testing.assert_array_equal(Wt, W)
    np.testing.assert_array_equal(Vt, V)
    np.testing.assert_array_equal(gxt, gx)
    for t in range(tracks.n_tracks):
        cols = slice(6 + 3 * t, 9 + 3 * t)
        np.testing.assert_allclose(W[t], H[:6, cols], rtol=1e-10, atol=1e-9 * np.abs(H).max())
        np.testing.assert_allclose(V[t], H[cols, cols], rtol=1e-10)
        np.testing.assert_allclose(gx[t], g[cols], rtol=1e-10, atol=1e-9 * np.abs(g).max())


def test_track_starts_refuses_observations_out_of_track_order():
    np.testing.assert_array_equal(track_starts(np.array([0, 0, 1, 2, 2])), [0, 2, 3])
    with pytest.raises(ValueError, match="grouped by track"):
        track_starts(np.array([0, 1, 0]))


def test_schur_backend_finds_the_truth_noise_free():
    scene = _make_scene(7)
    result = refine(build_track_set(scene.motions, FOCAL), _start_pose(scene.T_true, 8),
                    RefinementConfig(backend="schur"))
    assert max(pose_errors(result.T_camera_base, scene.T_true)) < NOISE_FREE_POSE_TOL


@pytest.mark.parametrize("seed", [9, 11])
def test_schur_and_scipy_backends_reach_the_same_optimum(seed):
    scene = _make_scene(seed, **NOISY_SCENE)
    tracks, start = build_track_set(scene.motions, FOCAL), _start_pose(scene.T_true, seed + 1)
    # without track weights: they come from the robust pass, whose Cauchy loss the backends apply differently
    # (per observation / per coordinate), so the weighted problems differ slightly
    schur = refine(tracks, start, RefinementConfig(backend="schur", track_weights=False))
    scipy = refine(tracks, start, RefinementConfig(backend="scipy", track_weights=False))
    np.testing.assert_array_equal(schur.track_inliers, scipy.track_inliers)
    xi = pose_difference(scipy.T_camera_base, schur.T_camera_base)
    assert np.all(np.abs(xi) < 0.01 * _std(scipy.covariance))
    np.testing.assert_allclose(_std(schur.covariance), _std(scipy.covariance), rtol=1e-3)


def test_a_pose_prior_holds_the_pose_where_it_says():
    scene = _make_scene(13, **NOISY_SCENE)
    tracks = build_track_set(scene.motions, FOCAL)
    T0 = scene.T_true
    problem = _Problem(tracks, T0)
    target = np.array([0.01, -0.02, 0.015, 0.03, -0.01, 0.02])  # far from the tracks' optimum
    H = 1e12 * np.eye(6)
    x0 = np.concatenate([np.zeros(6), _camera_points(scene).ravel()])
    sol = solve_schur(problem, x0, prior=PosePrior(H, -H @ target))  # 0.5 p^T H p - p^T H target
    np.testing.assert_allclose(sol.x[:6], target, atol=1e-6)
    free = solve_schur(problem, x0)
    assert np.linalg.norm(free.x[:6] - target) > 0.9 * np.linalg.norm(target)  # without it, near the tracks' optimum


def test_pose_step_sigmas_measures_a_step_against_the_pose_covariance():
    # A linear problem with a known covariance sigma^2 (J^T J)^-1: the step k L e, L its Cholesky factor and e a
    # unit vector, is k standard deviations long whatever the direction.
    rng = np.random.default_rng(41)
    J = rng.normal(size=(200, 6)) * np.array([1.0, 5.0, 0.2, 30.0, 1.0, 3.0])  # scales and correlations
    S = J.T @ J
    sigma = 0.7
    r = np.full((100, 2), sigma / 1.4826) * rng.choice([-1.0, 1.0], (100, 2))  # 1.4826 MAD = sigma exactly
    L = np.linalg.cholesky(sigma**2 * np.linalg.inv(S))
    for k in (0.01, 0.3, 2.0):
        e = rng.normal(size=6)
        dp = k * L @ (e / np.linalg.norm(e))
        assert pose_step_sigmas(dp, S, r) == pytest.approx(k, rel=1e-9)
    assert pose_step_sigmas(np.zeros(6), S, r) == 0.0
    assert pose_step_sigmas(np.ones(6), S, np.zeros((3, 2))) == np.inf  # no noise to measure it by


def test_the_robust_pass_stops_once_the_pose_stands_still():
    # Drifting tracks (a point sliding along an outline) keep their points creeping in the Cauchy pass long after
    # the pose has settled; the pose criterion ends the pass there, within a fraction of a sigma of where the cost
    # criterion alone would end it, and the tracks it keeps and the final estimate are the same.
    scene = _make_scene(43, n_motions=6, n_tracks=10, n_frames=30, noise_px=0.5)
    rng = np.random.default_rng(44)
    motions = []
    for axis, pivot, tracks in scene.motions:
        drifted = [(uv + np.outer(np.linspace(0.0, 1.0, len(uv)), rng.normal(0.0, 15.0, 2)) / FOCAL, d)
                   if j < 3 else (uv, d) for j, (uv, d) in enumerate(tracks)]
        motions.append((axis, pivot, drifted))
    tracks = build_track_set(motions, FOCAL)
    start = _start_pose(scene.T_true, 45)
    points, keep = start_points(tracks, start)
    assert keep.all()
    problem = _Problem(tracks, start)
    x0 = np.concatenate([np.zeros(6), (points @ start[:3, :3].T + start[:3, 3]).ravel()])
    full = solve_schur(problem, x0, "cauchy", 1.0, 200, 1e-12)
    short = solve_schur(problem, x0, "cauchy", 1.0, 200, 1e-12, pose_tol=0.05)
    assert short.iterations < full.iterations
    cov = refine(tracks, start, RefinementConfig(robust_pose_tol=None)).covariance
    assert np.all(np.abs(short.x[:6] - full.x[:6]) < 0.25 * _std(cov))
    assert np.max(np.abs(short.x[6:] - full.x[6:])) > 1e-6  # the points had not settled: a real early stop
    # In refine, warm-started (a relinearization: the last pose and points, these from a first adjustment of half
    # the frames), the criterion changes neither the tracks kept nor the final estimate.
    first = refine(build_track_set([(a, p, [(uv[::2], d[::2]) for uv, d in trs]) for a, p, trs in motions], FOCAL),
                   start)
    assert not first.track_inliers[:3].any()  # the drifting tracks are dropped
    with_tol, without = (refine(tracks, first.T_camera_base, RefinementConfig(robust_pose_tol=tol),
                                points_init=first.points_base) for tol in (0.05, None))
    np.testing.assert_array_equal(with_tol.track_inliers, without.track_inliers)
    assert not with_tol.track_inliers[:3].any()
    xi = pose_difference(without.T_camera_base, with_tol.T_camera_base)
    assert np.all(np.abs(xi) < 0.01 * _std(without.covariance))


def _split(motions: list, n_old: int) -> tuple:
    old, new = motions[:n_old], motions[n_old:]
    return build_track_set(old, FOCAL), build_track_set(new, FOCAL), build_track_set(motions, FOCAL)


@pytest.mark.parametrize("seed", [15, 17])
def test_an_increment_equals_the_batch_adjustment(seed):
    scene = _make_scene(seed, n_motions=7, n_tracks=6, n_frames=30, noise_px=0.5)
    old, new, every = _split(scene.motions, 6)
    start = _start_pose(scene.T_true, seed + 1)
    first = refine(old, start)
    batch = refine(every, first.T_camera_base)
    inc = refine_increment(new, first.T_camera_base, first.summaries, first.robust_sigma_px)
    xi = pose_difference(batch.T_camera_base, inc.T_camera_base)
    assert np.all(np.abs(xi) < AGREEMENT_SIGMA * _std(batch.covariance))
    np.testing.assert_allclose(_std(inc.covariance), _std(batch.covariance), rtol=STD_RTOL)
    assert len(inc.summaries) == 7 and inc.track_inliers.shape == (new.n_tracks,)
    # the summaries of the batch adjustment give its own covariance (with the weights, bounded by their twins)
    own = summaries_covariance(batch.summaries)[0]
    np.testing.assert_allclose(weighted_covariance_bound(own, batch.summaries, None, None, None, RefinementConfig()),
                               batch.covariance, rtol=1e-9)
    # the new motion's information changed the estimate: it is not the old one carried over
    assert np.any(np.abs(pose_difference(first.T_camera_base, batch.T_camera_base)) > AGREEMENT_SIGMA
                  * _std(batch.covariance))


def test_a_weighted_increment_keeps_the_unweighted_bound_and_equals_the_batch_adjustment():
    """Per-track weights on: the increment carries every motion's unweighted twin and agrees with the batch."""
    scene = _make_scene(15, n_motions=7, n_tracks=6, n_frames=30, noise_px=0.5)
    old, new, every = _split(scene.motions, 6)
    config = RefinementConfig(track_weights=True)
    first = refine(old, _start_pose(scene.T_true, 16), config)
    batch = refine(every, first.T_camera_base, config)
    inc = refine_increment(new, first.T_camera_base, first.summaries, first.robust_sigma_px, config)
    assert len(inc.summaries) == 7 and all(m.unweighted is not None for m in inc.summaries)
    xi = pose_difference(batch.T_camera_base, inc.T_camera_base)
    assert np.all(np.abs(xi) < AGREEMENT_SIGMA * _std(batch.covariance))
    np.testing.assert_allclose(_std(inc.covariance), _std(batch.covariance), rtol=STD_RTOL)
    own, _, _ = summaries_covariance(inc.summaries, None, inc.T_camera_base)
    assert np.linalg.eigvalsh(inc.covariance - own).min() > -1e-9 * np.abs(own).max()
    plain = refine(every, first.T_camera_base, replace(config, track_weights=False))
    assert _largest_ratio(plain.covariance, inc.covariance) < 1.1  # twins linearized where last solved


def test_an_increment_with_the_time_offset_equals_the_batch_adjustment():
    scene = _timed_scene(21, 0.020, n_motions=7)
    old, new, every = _split(scene.motions, 6)
    first = refine(old, _start_pose(scene.T_true, 22))
    batch = refine(every, first.T_camera_base)
    inc = refine_increment(new, first.T_camera_base, first.summaries, first.robust_sigma_px,
                           time_offset_s=first.time_offset_s)
    xi = pose_difference(batch.T_camera_base, inc.T_camera_base)
    assert np.all(np.abs(xi) < AGREEMENT_SIGMA * _std(batch.covariance))
    assert abs(inc.time_offset_s - batch.time_offset_s) < AGREEMENT_SIGMA * batch.time_offset_std_s
    assert inc.time_offset_std_s == pytest.approx(batch.time_offset_std_s, rel=STD_RTOL)
    with pytest.raises(ValueError, match="time offset"):
        refine_increment(new, first.T_camera_base, first.summaries, first.robust_sigma_px)


def test_an_increment_drops_a_jumping_track_of_the_new_motion():
    scene = _make_scene(23, n_motions=7, n_tracks=6, n_frames=30, noise_px=0.5)
    axis, pivot, tracks = scene.motions[6]
    uv, delta = tracks[2]
    jumped = uv.copy()
    jumped[15:] += np.array([25.0, -15.0]) / FOCAL
    scene.motions[6] = (axis, pivot, [*tracks[:2], (jumped, delta), *tracks[3:]])
    old, new, _ = _split(scene.motions, 6)
    first = refine(old, _start_pose(scene.T_true, 24))
    inc = refine_increment(new, first.T_camera_base, first.summaries, first.robust_sigma_px)
    np.testing.assert_array_equal(inc.track_inliers, [True, True, False, True, True, True])


def test_an_increment_with_max_split_drops_a_slow_slide_of_the_new_motion():
    scene = _make_scene(23, n_motions=7, n_tracks=6, n_frames=30, noise_px=0.5)
    _slide(scene, 6, 0, 0.01)  # its split-half residual 2.7 px, the others' 0.65-1.21 px at 0.5 px noise
    old, new, _ = _split(scene.motions, 6)
    config = RefinementConfig(max_split_px=1.8)
    first = refine(old, _start_pose(scene.T_true, 24), config)
    assert np.all(refine_increment(new, first.T_camera_base, first.summaries, first.robust_sigma_px).track_inliers)
    inc = refine_increment(new, first.T_camera_base, first.summaries, first.robust_sigma_px, config)
    np.testing.assert_array_equal(inc.track_inliers, [False, True, True, True, True, True])


def _episode(incremental: bool, n: int = 10) -> Calibrator:
    T_true = sample_camera_pose(np.random.default_rng(1003))
    rng = np.random.default_rng(7)
    intrinsics = d415_intrinsics()
    scene = SyntheticScene(PANDA, intrinsics, T_true, SyntheticConfig(noise_px=0.5, outlier_fraction=0.1), rng)
    calibrator = Calibrator(intrinsics, PANDA.axis_and_point, CalibratorConfig(incremental=incremental))
    for _ in range(n):
        calibrator.add_motion(scene.random_motion(rng).observation)
    calibrator.T_true = T_true
    return calibrator


def test_the_calibrator_updates_incrementally_and_agrees_with_solving_every_motion():
    inc, batch = _episode(True), _episode(False)
    assert inc.state.stage == batch.state.stage == "refined"
    assert inc.relinearized < batch.relinearized  # some updates were increments
    xi = pose_difference(batch.state.T_camera_base, inc.state.T_camera_base)
    assert np.all(np.abs(xi) < AGREEMENT_SIGMA * batch.state.std)
    np.testing.assert_allclose(inc.state.std, batch.state.std, rtol=STD_RTOL)
    reference = inc.batch_refinement()
    assert np.all(np.abs(pose_difference(reference.T_camera_base, inc.state.T_camera_base))
                  < AGREEMENT_SIGMA * _std(reference.covariance))
    assert [r.n_inlier_tracks for r in inc.reports] == pytest.approx([r.n_inlier_tracks for r in batch.reports],
                                                                     abs=2)


def test_track_weights_trust_the_quiet_tracks_more_and_report_at_least_the_unweighted_covariance():
    """Half the tracks 6x noisier than the others: the weighted fit is sharper, its reported covariance is bounded."""
    scene = _make_scene(25, n_motions=6, n_tracks=8, n_frames=30, noise_px=0.0)
    rng = np.random.default_rng(26)
    noisy = []
    for axis, pivot, tracks in scene.motions:
        noisy.append((axis, pivot, [(uv + rng.normal(0, 0.3 if k % 2 else 1.8, uv.shape) / FOCAL, d)
                                    for k, (uv, d) in enumerate(tracks)]))
    tracks = build_track_set(noisy, FOCAL)
    start = _start_pose(scene.T_true, 27)
    config = RefinementConfig(outlier_px=5.0, outlier_sigmas=10.0, track_weights=False)  # keep the noisy tracks
    plain = refine(tracks, start, config)
    weighted = refine(tracks, start, replace(config, track_weights=True))
    assert weighted.track_inliers.all() and plain.track_inliers.all()
    assert all(m.unweighted is not None for m in weighted.summaries)
    assert all(m.unweighted is None for m in plain.summaries)
    # the weights' own covariance is smaller in every direction (its information is larger) ...
    own, _, _ = summaries_covariance(weighted.summaries)
    assert np.all(np.linalg.eigvalsh(plain.covariance - own) > 0)
    assert np.prod(_std(own)) < 0.5 * np.prod(_std(plain.covariance))
    # ... and holds the truth (chi-square with 6 dof, 99.9 %) ...
    xi = pose_difference(weighted.T_camera_base, scene.T_true)
    assert xi @ np.linalg.solve(own, xi) < 22.46
    # ... but the reported one is at least that and, within the one Gauss-Newton step to the unweighted
    # optimum, the unweighted fit's: no direction is claimed better known than the plain fit knows it
    assert np.linalg.eigvalsh(weighted.covariance - own).min() > -1e-9 * np.abs(own).max()
    assert _largest_ratio(plain.covariance, weighted.covariance) < 1.1  # a separate robust pass and optimum
    assert weighted.rms_px == pytest.approx(plain.rms_px, rel=0.1)  # reported in px, unweighted


def _plain_and_weighted_fits(rng: np.random.Generator, bias: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A linear model y = A x + e, half its rows 6x noisier: (d, plain cov, weighted cov), d = OLS - WLS.

    ``bias`` is added to every noisy row in proportion to its first regressor: an error their residuals
    cannot show (the fit absorbs it), shared by those rows, which pulls the two estimates apart.
    """
    n, p = 200, 6
    A = rng.normal(size=(n, p))
    sigma = np.where(np.arange(n) % 2 == 1, 1.8, 0.3)
    y = rng.normal(0.0, sigma) + bias * (sigma > 1.0) * A[:, 0]
    AtA_inv = np.linalg.inv(A.T @ A)
    plain_cov = AtA_inv @ (A.T * sigma**2) @ A @ AtA_inv
    weighted_cov = np.linalg.inv((A.T / sigma**2) @ A)
    x_plain = AtA_inv @ A.T @ y
    x_weighted = weighted_cov @ ((A.T / sigma**2) @ y)
    return x_plain - x_weighted, plain_cov, weighted_cov


def test_weights_disagree_rarely_when_the_weights_are_right_and_always_when_a_bias_splits_the_fits():
    rng = np.random.default_rng(40)
    null = [weights_disagree(*_plain_and_weighted_fits(rng, 0.0)) for _ in range(400)]
    assert np.mean(null) < 0.04  # the test's level is 1 %
    biased = [weights_disagree(*_plain_and_weighted_fits(rng, 1.0)) for _ in range(100)]
    assert np.mean(biased) > 0.9


def test_weights_disagree_takes_directions_the_weights_do_not_sharpen_at_the_plain_fits_noise():
    plain, weighted = np.diag([4.0, 1.0]), np.diag([1.0, 1.0])  # the second direction gains nothing
    assert not weights_disagree(np.array([2.0, 0.0]), plain, weighted)  # 2^2 / 3 = 1.3
    assert weights_disagree(np.array([0.0, 1.0]), plain, weighted)  # 1 / 0.01 = 100 > 9.2


def test_weighted_summaries_and_their_twins_match_the_weighted_and_plain_problems_own():
    """One pass gives both summaries: the same as summarizing the weighted problem and the plain one apart."""
    scene = _make_scene(41, **NOISY_SCENE)
    tracks = build_track_set(scene.motions, FOCAL)
    rng = np.random.default_rng(42)
    scale = rng.uniform(0.3, 2.0, tracks.n_tracks)[tracks.track]  # one weight per track
    T = _start_pose(scene.T_true, 43)
    points, ok = start_points(tracks, T)
    assert ok.all()
    x = np.concatenate([np.zeros(6), (points @ T[:3, :3].T + T[:3, 3]).ravel()])
    weighted_problem, plain_problem = _Problem(tracks, T, None, scale), _Problem(tracks, T)
    fun, raw = weighted_problem.residuals(x), plain_problem.residuals(x)
    pairs = _with_unweighted(weighted_problem, x, fun, raw, scale)
    for got, weighted, plain in zip(pairs, _motion_summaries(weighted_problem, x, fun),
                                    _motion_summaries(plain_problem, x, raw), strict=True):
        for a, b in ((got, weighted), (got.unweighted, plain)):
            for name in ("information", "gradient", "meat"):
                np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-9,
                                           atol=1e-12 * np.abs(getattr(b, name)).max())
            assert a.rss == pytest.approx(b.rss, rel=1e-12)
            assert (a.n_residuals, a.n_tracks) == (b.n_residuals, b.n_tracks)


def test_track_weights_change_little_when_every_track_is_alike():
    scene = _make_scene(29, **NOISY_SCENE)
    tracks, start = build_track_set(scene.motions, FOCAL), _start_pose(scene.T_true, 30)
    # the jackknife's and the dispersion's data-driven spread (6 motions) are left out: they move with any
    # reweighting of the same residuals
    spread_off = {"motion_jackknife": False, "motion_dispersion": False}
    plain = refine(tracks, start, RefinementConfig(track_weights=False, **spread_off))
    weighted = refine(tracks, start, RefinementConfig(track_weights=True, **spread_off))
    xi = pose_difference(plain.T_camera_base, weighted.T_camera_base)
    assert np.all(np.abs(xi) < 0.5 * _std(plain.covariance))
    np.testing.assert_allclose(_std(weighted.covariance), _std(plain.covariance), rtol=0.2)


def test_an_increment_needs_the_earlier_summaries():
    scene = _make_scene(7)
    old, new, _ = _split(scene.motions, 3)
    first = refine(old, perturb(scene.T_true, np.zeros(6)))
    with pytest.raises(ValueError, match="summaries"):
        refine_increment(new, first.T_camera_base, (), 0.5)


def test_motion_clusters_widen_the_covariance_when_errors_are_shared_by_a_sweep():
    """Each motion's tracks all shifted by the same 1 px (a sweep's own systematic error, e.g. its timing)."""
    scene = _make_scene(35, n_motions=8, n_tracks=8, n_frames=30, noise_px=0.2)
    rng = np.random.default_rng(36)
    shifted = []
    for axis, pivot, tracks in scene.motions:
        shift = rng.normal(0.0, 1.0, 2) / FOCAL  # one offset for every track of this motion
        shifted.append((axis, pivot, [(uv + shift, d) for uv, d in tracks]))
    tracks, start = build_track_set(shifted, FOCAL), _start_pose(scene.T_true, 37)
    # the shifted tracks are not outliers; unweighted, to see the clusters alone
    loose = RefinementConfig(outlier_px=5.0, outlier_sigmas=10.0, track_weights=False)
    plain = refine(tracks, start, replace(loose, motion_clusters=False))
    clustered = refine(tracks, start, loose)
    np.testing.assert_allclose(clustered.T_camera_base, plain.T_camera_base, atol=1e-12)  # the estimate is the same
    assert np.all(np.linalg.eigvalsh(clustered.covariance - plain.covariance) > -1e-18)  # never smaller ...
    assert np.max(_std(clustered.covariance) / _std(plain.covariance)) > 2.0  # ... and much wider here

    def chi2(result):
        xi = pose_difference(result.T_camera_base, scene.T_true)
        return xi @ np.linalg.solve(result.covariance, xi)

    assert chi2(plain) > 22.46  # the track-level covariance does not hold the truth (chi-square 6, 99.9 %) ...
    sandwich = refine(tracks, start, replace(loose, motion_jackknife=False, motion_dispersion=False))
    assert chi2(sandwich) < chi2(plain) / 3  # ... the motion-clustered sandwich far less so (seen: 430 -> 92) ...
    assert chi2(sandwich) > 22.46  # ... but from 8 motions it is still too small ...
    assert chi2(clustered) < 22.46  # ... and with the leave-one-motion-out jackknife it holds it (seen: 5.9) ...
    jackknifed = refine(tracks, start, replace(loose, motion_dispersion=False))
    dispersed = refine(tracks, start, replace(loose, motion_jackknife=False))
    assert chi2(dispersed) < chi2(sandwich) / 2  # ... as the motions' dispersion widens it everywhere (92 -> 33)
    assert np.all(np.linalg.eigvalsh(clustered.covariance - jackknifed.covariance) > -1e-18)  # never smaller
    assert chi2(clustered) < chi2(jackknifed)  # seen: 10.9 -> 5.9
    # Whether the motions fix the pose is judged without the jackknife: the result carries that covariance too.
    np.testing.assert_allclose(clustered.sandwich_covariance, sandwich.covariance, rtol=1e-9, atol=1e-18)
    np.testing.assert_allclose(sandwich.sandwich_covariance, sandwich.covariance, rtol=1e-12)
