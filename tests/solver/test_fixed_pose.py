"""Tests of solver/fixed_pose.py: the tracks' points fitted with the pose held fixed."""

from __future__ import annotations

import numpy as np
import pytest

from solver.errors import InvalidInputError
from solver.fixed_pose import fit_points
from solver.frames import perturb
from solver.refinement import build_track_set, refine
from tests.solver.scene import FOCAL
from tests.solver.test_refinement import NOISE_PX, _make_scene

#: Noise-free at the true pose: the triangulation is exact, so the fit moves nothing (float64 rounding).
EXACT_PX = 1e-7
#: With noise at the true pose each track's RMS is noise_px times sqrt(1 - 3 / (2 M)) on average (3 of
#: its 2M residuals absorbed by the point); the median over 24 tracks of 20 frames is within 25 % of it.
NOISE_RTOL = 0.25


def test_noise_free_at_the_true_pose_every_track_fits_exactly():
    scene = _make_scene(3, n_motions=4, n_tracks=6, n_frames=20)
    tracks = build_track_set(scene.motions, FOCAL)
    fit = fit_points(tracks, scene.T_true)
    assert fit.ok.all()
    assert np.nanmax(fit.track_rms_px) < EXACT_PX
    np.testing.assert_allclose(fit.points, scene.points, atol=1e-9)


def test_noise_stays_at_its_level_at_the_true_pose_and_the_fit_matches_the_bundle_adjustment():
    scene = _make_scene(4, n_motions=4, n_tracks=6, n_frames=20, noise_px=NOISE_PX)
    tracks = build_track_set(scene.motions, FOCAL)
    fit = fit_points(tracks, scene.T_true)
    expected = NOISE_PX * np.sqrt(1 - 3 / (2 * 20))
    assert np.median(fit.track_rms_px) == pytest.approx(expected, rel=NOISE_RTOL)
    # At the bundle adjustment's own pose, its points are the fixed-pose optimum: the same RMS.
    refined = refine(tracks, scene.T_true)
    at_refined = fit_points(tracks, refined.T_camera_base)
    assert np.sqrt(np.nanmean(at_refined.residuals**2)) == pytest.approx(refined.rms_px, rel=1e-4)


def test_a_moved_pose_leaves_residuals_the_points_cannot_absorb():
    scene = _make_scene(5, n_motions=4, n_tracks=6, n_frames=20)
    tracks = build_track_set(scene.motions, FOCAL)
    medians = []
    for size in (0.005, 0.02):  # rad and m: 5 mrad / 5 mm, then 20 mrad / 2 cm
        moved = perturb(scene.T_true, np.array([size, 0.0, 0.0, 0.0, size, 0.0]))
        fit = fit_points(tracks, moved)
        assert fit.ok.all()
        medians.append(float(np.median(fit.track_rms_px)))
        # The fitted points are each track's least-squares optimum: no small move of one lowers its cost.
        r0 = np.nansum(fit.residuals**2)
        for step in 1e-6 * np.vstack([np.eye(3), -np.eye(3)]):
            moved_points = fit.points.copy()
            moved_points[0] += step
            assert _cost(tracks, moved, moved_points) >= r0 - 1e-9
    # Measured: 0.39 and 1.49 px (fx 1380); the residual grows with the error, far above rounding.
    assert 1e4 * EXACT_PX < medians[0] < medians[1]


def _cost(tracks, T, points):
    R, t = T[:3, :3], T[:3, 3]
    y = (points - tracks.pivot)[tracks.track]
    p_base = np.einsum("pij,pj->pi", tracks.rot, y) + tracks.pivot[tracks.track]
    pc = p_base @ R.T + t
    return float(np.sum(((pc[:, :2] / pc[:, 2:] - tracks.uv) * tracks.focal) ** 2))


def test_bad_inputs_are_refused():
    scene = _make_scene(3, n_motions=3, n_tracks=2, n_frames=8)
    tracks = build_track_set(scene.motions, FOCAL)
    with pytest.raises(InvalidInputError, match="T_camera_base"):
        fit_points(tracks, np.full((4, 4), np.nan))
    with pytest.raises(InvalidInputError, match="iterations"):
        fit_points(tracks, scene.T_true, iterations=0)
