"""Tests of solver/refinement_ceres.py: the bundle adjustment on Ceres (COLMAP's rig model) against ``refine``."""

from __future__ import annotations

import numpy as np
import pytest

from solver import PANDA, SyntheticConfig, SyntheticScene, d415_intrinsics, sample_camera_pose
from solver.camera import normalized_from_pixels
from solver.errors import InvalidInputError
from solver.frames import perturb, pose_difference, pose_errors
from solver.refinement import RefinementConfig, TrackSet, build_track_set, refine

pytest.importorskip("pycolmap", reason="the Ceres backend needs pycolmap (the 'ceres' extra)")

from solver.refinement_ceres import refine_ceres  # noqa: E402

#: The backends solve the same least-squares problem on the same tracks; they stop on their own
#: tolerances (relative cost change 1e-9), a millionth of a sigma apart in the cost's curvature.
#: Seen: 5e-4 sigma on 1174 tracks; 0.02 leaves room for other machines' rounding.
AGREEMENT_SIGMA = 0.02

#: The covariances come from the same numpy code at (almost) the same solution: entries within 1% of
#: the product of the two sigmas.
COVARIANCE_RTOL = 1e-2

#: 99.9% quantile of chi-square with 6 degrees of freedom (see tests/solver/test_refinement.py).
CHI2_6_999 = 22.46

#: Synthetic Panda episodes (scripts/bench_solver.py's construction) at 5 motions of 30 tracks, 0.5 px,
#: started 17 mrad / 15 mm off: 1-sigma up to 1.4 mrad and 3.6 mm (the depth); the pose lands 1.4 mrad
#: / 4.0 mm off. The test of the truth is the 99.9% region; these bounds only catch a pose that did not move.
MAX_ROT_RAD, MAX_TRANS_M = 3e-3, 1e-2


def _episode(outlier_fraction: float, n_motions: int = 5) -> tuple[np.ndarray, TrackSet, np.ndarray]:
    """T_true (4, 4), the episode's tracks (30 per motion) and which tracks are outliers (T,)."""
    T_true = sample_camera_pose(np.random.default_rng(1000))
    rng = np.random.default_rng(7)
    intrinsics = d415_intrinsics()
    scene = SyntheticScene(PANDA, intrinsics, T_true,
                           SyntheticConfig(noise_px=0.5, outlier_fraction=outlier_fraction, tracks_per_motion=30), rng)
    motions, outliers = [], []
    for _ in range(n_motions):
        m = scene.random_motion(rng)
        axis, point = PANDA.axis_and_point(m.observation.q_start, m.observation.joint)
        motions.append((axis, point, [(normalized_from_pixels(t.pixels, intrinsics), t.delta)
                                      for t in m.observation.tracks]))
        outliers.append(m.outliers)
    return T_true, build_track_set(motions, intrinsics.focal), np.concatenate(outliers)


START = np.array([0.01, -0.01, 0.005, 0.01, 0.005, -0.01])  # rad, m: the start's offset from the truth


def test_agrees_with_refine_without_outliers() -> None:
    T_true, tracks, _ = _episode(0.0)
    T0 = perturb(T_true, START)
    expected = refine(tracks, T0, RefinementConfig(track_weights=False))  # the Ceres trial is unweighted
    got = refine_ceres(tracks, T0)
    np.testing.assert_array_equal(got.track_inliers, expected.track_inliers)
    sigma = np.sqrt(np.diag(expected.covariance))
    assert np.all(np.abs(pose_difference(got.T_camera_base, expected.T_camera_base)) < AGREEMENT_SIGMA * sigma)
    assert np.all(np.abs(got.covariance - expected.covariance) < COVARIANCE_RTOL * np.outer(sigma, sigma))
    assert got.sigma_px == pytest.approx(expected.sigma_px, rel=1e-3)
    kept = got.track_inliers
    np.testing.assert_allclose(got.points_base[kept], expected.points_base[kept], atol=1e-5)
    xi = pose_difference(got.T_camera_base, T_true)
    assert xi @ np.linalg.solve(got.covariance, xi) < CHI2_6_999
    rot, trans = pose_errors(got.T_camera_base, T_true)
    assert rot < MAX_ROT_RAD and trans < MAX_TRANS_M


def test_rejects_outlier_tracks_and_finds_the_truth() -> None:
    T_true, tracks, outliers = _episode(0.3)
    got = refine_ceres(tracks, perturb(T_true, START))
    assert np.mean(got.track_inliers[~outliers]) > 0.95  # good tracks stay
    assert np.mean(~got.track_inliers[outliers]) > 0.5  # the slow drifts that fit stay: they are small
    xi = pose_difference(got.T_camera_base, T_true)  # 4 mrad / 4 mm off, as refine(): within its region
    assert xi @ np.linalg.solve(got.covariance, xi) < CHI2_6_999
    assert np.all(np.isnan(got.points_base[~got.track_inliers]))


def test_time_offset_is_refused() -> None:
    T_true, tracks, _ = _episode(0.0, n_motions=3)
    with pytest.raises(InvalidInputError, match="time offset"):
        refine_ceres(tracks, T_true, RefinementConfig(estimate_time_offset=True))


def test_non_finite_start_is_refused() -> None:
    T_true, tracks, _ = _episode(0.0, n_motions=3)
    with pytest.raises(InvalidInputError, match="finite"):
        refine_ceres(tracks, np.full((4, 4), np.nan))
