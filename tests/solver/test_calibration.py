"""Tests of solver/calibration.py: linear, minimal and robust T_camera_base from axis pairs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver.calibration import (
    MIN_OBSERVABILITY,
    AxisCorrespondence,
    _rows,
    check_observable,
    consistency_errors,
    family_offsets,
    pose_family,
    pose_observability,
    solve_consensus,
    solve_linear,
    solve_minimal,
)
from solver.errors import InsufficientMotionsError, UnobservablePoseError
from solver.frames import skew
from solver.kinematics import PANDA
from tests.solver.scene import perpendicular, random_pose, random_unit, unit

#: Noise-free recovery: SVDs of O(10) well-conditioned rows, float64 rounding only.
POSE_TOL = 1e-9

#: Thresholds of the robust solve: far above exact data, far below the injected corruptions.
MAX_EPS_A = 0.01  # rad
MAX_EPS_D = 0.005  # m


def _correspondence(T: np.ndarray, axis_base: np.ndarray, point_base: np.ndarray,
                    ) -> AxisCorrespondence:
    """The camera's view of a joint axis, built directly from the true pose."""
    R, t = T[:3, :3], T[:3, 3]
    axis_cam = R @ axis_base
    normal = unit(np.cross(R @ point_base + t, axis_cam))
    return AxisCorrespondence(axis_base, point_base, axis_cam, normal)


def _random_correspondences(T: np.ndarray, rng: np.random.Generator, n: int,
                            ) -> list[AxisCorrespondence]:
    return [_correspondence(T, random_unit(rng), rng.uniform(-0.4, 0.4, 3)) for _ in range(n)]


def _assert_pose_close(T_est: np.ndarray, T_true: np.ndarray, tol: float = POSE_TOL) -> None:
    np.testing.assert_allclose(T_est, T_true, rtol=0, atol=tol)


@pytest.fixture
def T_true(rng) -> np.ndarray:
    return random_pose(rng)


@pytest.mark.parametrize("n", [4, 5, 10])
def test_solve_linear_recovers_pose(T_true, rng, n):
    _assert_pose_close(solve_linear(_random_correspondences(T_true, rng, n)), T_true)


@pytest.mark.parametrize("n", [3, 4, 10])
def test_solve_minimal_recovers_pose(T_true, rng, n):
    _assert_pose_close(solve_minimal(_random_correspondences(T_true, rng, n)), T_true)


def test_solve_linear_with_three_motions_uses_the_minimal_solver(T_true, rng):
    motions = _random_correspondences(T_true, rng, 3)
    _assert_pose_close(solve_linear(motions), T_true)
    np.testing.assert_array_equal(solve_linear(motions), solve_minimal(motions))


def test_plane_normal_sign_does_not_matter(T_true, rng):
    motions = _random_correspondences(T_true, rng, 6)
    flipped = [AxisCorrespondence(c.axis_base, c.point_base, c.axis_cam, -c.plane_normal)
               if k % 2 else c for k, c in enumerate(motions)]
    _assert_pose_close(solve_linear(flipped), T_true)
    _assert_pose_close(solve_minimal(flipped), T_true)


def test_point_anywhere_on_the_axis_gives_the_same_pose(T_true, rng):
    motions = _random_correspondences(T_true, rng, 5)
    slid = [AxisCorrespondence(c.axis_base, c.point_base + rng.uniform(-1, 1) * c.axis_base,
                               c.axis_cam, c.plane_normal) for c in motions]
    _assert_pose_close(solve_linear(slid), T_true)


def test_solve_linear_recovers_panda_pose(T_true, rng):
    motions = []
    for _ in range(3):
        q = PANDA.clip(rng.uniform(PANDA.lower, PANDA.upper))
        motions += [_correspondence(T_true, *PANDA.axis_and_point(q, j)) for j in range(7)]
    _assert_pose_close(solve_linear(motions), T_true)


def test_consistency_errors_vanish_at_truth(T_true, rng):
    for c in _random_correspondences(T_true, rng, 10):
        eps_a, eps_d = consistency_errors(c, T_true)
        assert eps_a == pytest.approx(0.0, abs=1e-7)  # arccos near 1: ~sqrt(machine eps)
        assert eps_d == pytest.approx(0.0, abs=1e-12)


def test_consistency_errors_measure_known_offsets(T_true, rng):
    c = _random_correspondences(T_true, rng, 1)[0]
    tilt = perpendicular(c.axis_cam)  # a rotation about it tilts the axis by its full angle
    T_rot = T_true.copy()
    T_rot[:3, :3] = Rotation.from_rotvec(0.05 * tilt).as_matrix() @ T_true[:3, :3]
    assert consistency_errors(c, T_rot)[0] == pytest.approx(0.05, abs=1e-9)
    T_shift = T_true.copy()
    T_shift[:3, 3] += 0.02 * c.plane_normal + 0.3 * c.axis_cam  # along the plane it is free
    eps_a, eps_d = consistency_errors(c, T_shift)
    assert eps_d == pytest.approx(0.02, abs=1e-12)
    assert eps_a == pytest.approx(0.0, abs=1e-7)


def _corrupt(c: AxisCorrespondence, T: np.ndarray, kind: str) -> AxisCorrespondence:
    if kind == "axis":  # the camera picked the wrong axis candidate
        axis_cam = Rotation.from_rotvec(0.3 * perpendicular(c.axis_cam)).apply(c.axis_cam)
        return AxisCorrespondence(c.axis_base, c.point_base, axis_cam, c.plane_normal)
    # the reference line went through the wrong centres: plane of a point 20 cm off the axis
    wrong = T[:3, :3] @ (c.point_base + 0.2 * perpendicular(c.axis_base)) + T[:3, 3]
    return AxisCorrespondence(c.axis_base, c.point_base, c.axis_cam,
                              unit(np.cross(wrong, c.axis_cam)))


def test_solve_consensus_rejects_corrupted_motions(T_true, rng):
    motions = _random_correspondences(T_true, rng, 10)
    motions[2] = _corrupt(motions[2], T_true, "axis")
    motions[7] = _corrupt(motions[7], T_true, "plane")
    expected = np.ones(10, dtype=bool)
    expected[[2, 7]] = False
    result = solve_consensus(motions, MAX_EPS_A, MAX_EPS_D, np.random.default_rng(0))
    np.testing.assert_array_equal(result.inliers, expected)
    _assert_pose_close(result.T_camera_base, T_true)
    assert np.all(result.eps_a[expected] < 1e-6)
    assert np.all(result.eps_d[expected] < 1e-9)
    assert result.eps_a[2] > MAX_EPS_A
    assert result.eps_d[7] > MAX_EPS_D
    # Guard: the corrupted motions really do spoil a plain linear solve.
    assert np.max(np.abs(solve_linear(motions) - T_true)) > 1e3 * POSE_TOL


def _tilt(c: AxisCorrespondence, angle: float, rng: np.random.Generator) -> AxisCorrespondence:
    """The camera axis turned by ``angle`` rad about a random perpendicular (plane kept through it)."""
    axis_cam = Rotation.from_rotvec(angle * unit(np.cross(c.axis_cam, random_unit(rng)))).apply(c.axis_cam)
    normal = unit(np.cross(np.cross(c.plane_normal, c.axis_cam), axis_cam))
    return AxisCorrespondence(c.axis_base, c.point_base, axis_cam, normal)


def test_solve_consensus_fits_on_motions_within_the_tighter_bounds(T_true, rng):
    # Three motions' axes off by 0.03 rad: inside the pruning bound 0.1, outside the fit bound 0.01
    motions = _random_correspondences(T_true, rng, 10)
    for k in (1, 4, 8):
        motions[k] = _tilt(motions[k], 0.03, rng)
    assert all(abs(consistency_errors(motions[k], T_true)[0] - 0.03) < 1e-9 for k in (1, 4, 8))
    loose = solve_consensus(motions, 0.1, 0.05, np.random.default_rng(0))
    tight = solve_consensus(motions, 0.1, 0.05, np.random.default_rng(0), fit_eps=(0.01, 0.05))
    assert loose.inliers.all() and tight.inliers.all() and loose.used.all()
    expected = np.ones(10, dtype=bool)
    expected[[1, 4, 8]] = False
    np.testing.assert_array_equal(tight.used, expected)
    _assert_pose_close(tight.T_camera_base, T_true)
    assert np.max(np.abs(loose.T_camera_base - T_true)) > 1e-4  # the tilted axes pull the plain fit
    # too few within the fit bounds (three of five): the fit on all inliers stands
    few = solve_consensus(motions[:5], 0.1, 0.05, np.random.default_rng(0), fit_eps=(0.01, 0.05))
    plain = solve_consensus(motions[:5], 0.1, 0.05, np.random.default_rng(0))
    np.testing.assert_array_equal(few.used, np.ones(5, dtype=bool))
    _assert_pose_close(few.T_camera_base, plain.T_camera_base)


@pytest.mark.parametrize("n", [0, 1, 2])
def test_fewer_than_three_motions(T_true, rng, n):
    motions = _random_correspondences(T_true, rng, n)
    match = f"{n} (usable )?motion\\(s\\).*at least 3"
    with pytest.raises(InsufficientMotionsError, match=match):
        solve_minimal(motions)
    with pytest.raises(InsufficientMotionsError, match=match):
        solve_linear(motions)
    with pytest.raises(InsufficientMotionsError, match=match):
        solve_consensus(motions, MAX_EPS_A, MAX_EPS_D, np.random.default_rng(0))


def _parallel_axes(T: np.ndarray, rng: np.random.Generator, n: int) -> list[AxisCorrespondence]:
    axis = random_unit(rng)
    return [_correspondence(T, axis, rng.uniform(-0.4, 0.4, 3)) for _ in range(n)]


def test_parallel_axes_minimal(T_true, rng):
    with pytest.raises(UnobservablePoseError, match="their axes are parallel"):
        solve_minimal(_parallel_axes(T_true, rng, 5))


def test_parallel_axes_linear(T_true, rng):
    # With parallel axes every reference plane contains the axis direction: t along it is free.
    with pytest.raises(UnobservablePoseError, match="reference planes do not span 3-D space"):
        solve_linear(_parallel_axes(T_true, rng, 5))


def _shoulder_motions(T: np.ndarray, rng: np.random.Generator) -> list[AxisCorrespondence]:
    """Panda joints 0, 1, 2 at several configurations: every axis passes through the shoulder."""
    motions = []
    for _ in range(6):
        q = PANDA.clip(rng.uniform(PANDA.lower, PANDA.upper))
        motions += [_correspondence(T, *PANDA.axis_and_point(q, j)) for j in range(3)]
    return motions


def test_shoulder_axes_meet_in_one_point(T_true, rng):
    # Guards the scenario: all axes pass through the shoulder (0, 0, 0.333) in the base frame.
    shoulder = np.array([0.0, 0.0, 0.333])
    for c in _shoulder_motions(T_true, rng):
        assert np.linalg.norm(np.cross(shoulder - c.point_base, c.axis_base)) < 1e-12


def test_check_observable_rejects_shoulder_axes(T_true, rng):
    motions = _shoulder_motions(T_true, rng)
    ratio, direction = pose_observability(motions, T_true)
    assert ratio < MIN_OBSERVABILITY
    # The free direction is a translation along the line of sight to the shoulder.
    shoulder_cam = T_true[:3, :3] @ [0.0, 0.0, 0.333] + T_true[:3, 3]
    assert np.linalg.norm(direction[:3]) < 1e-9
    assert abs(direction[3:] @ unit(shoulder_cam)) == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(UnobservablePoseError, match="translation along .* is free"):
        check_observable(motions, T_true)


def test_solve_linear_rejects_shoulder_axes(T_true, rng):
    with pytest.raises(UnobservablePoseError, match="reference planes do not span 3-D space"):
        solve_linear(_shoulder_motions(T_true, rng))


@pytest.mark.parametrize("scenario", ["shoulder-axes", "parallel-axes"])
def test_solve_consensus_reports_unobservable_pose(T_true, rng, scenario):
    motions = (_shoulder_motions(T_true, rng) if scenario == "shoulder-axes"
               else _parallel_axes(T_true, rng, 8))
    with pytest.raises(UnobservablePoseError):
        solve_consensus(motions, MAX_EPS_A, MAX_EPS_D, np.random.default_rng(0))


def test_shoulder_axes_plus_a_distal_joint_are_observable(T_true, rng):
    motions = _shoulder_motions(T_true, rng)
    q = PANDA.clip(np.array([0.3, -0.5, 0.2, -2.0, 0.1, 1.8, 0.4]))
    motions += [_correspondence(T_true, *PANDA.axis_and_point(q, j)) for j in (3, 5)]
    assert pose_observability(motions, T_true)[0] > MIN_OBSERVABILITY
    check_observable(motions, T_true)
    result = solve_consensus(motions, MAX_EPS_A, MAX_EPS_D, np.random.default_rng(0))
    assert np.all(result.inliers)
    _assert_pose_close(result.T_camera_base, T_true)


def test_random_motions_are_observable(T_true, rng):
    ratio, _ = pose_observability(_random_correspondences(T_true, rng, 6), T_true)
    assert ratio > MIN_OBSERVABILITY


def test_pose_family_of_two_motions_contains_the_pose_and_fixes_rotation(T_true, rng):
    motions = _random_correspondences(T_true, rng, 2)
    R, t0, u = pose_family(motions)
    np.testing.assert_allclose(R, T_true[:3, :3], atol=POSE_TOL)
    offset = T_true[:3, 3] - t0
    np.testing.assert_allclose(offset - (offset @ u) * u, 0.0, atol=POSE_TOL)  # T_true is a member
    assert abs(t0 @ u) < POSE_TOL  # least norm
    for s in (-1.0, 0.5, 3.0):  # every member satisfies both motions exactly
        T = T_true.copy()
        T[:3, 3] = t0 + s * u
        for c in motions:
            assert consistency_errors(c, T)[1] < POSE_TOL
    # and the free direction is real: the two planes both contain the ray along u
    for c in motions:
        assert abs(c.plane_normal @ u) < POSE_TOL


def test_pose_family_with_three_motions_is_the_pose(T_true, rng):
    R, t0, _ = pose_family(_random_correspondences(T_true, rng, 3))
    np.testing.assert_allclose(R, T_true[:3, :3], atol=POSE_TOL)
    np.testing.assert_allclose(t0, T_true[:3, 3], atol=POSE_TOL)


def test_pose_family_needs_two_non_parallel_axes(T_true, rng):
    with pytest.raises(InsufficientMotionsError):
        pose_family(_random_correspondences(T_true, rng, 1))
    a = random_unit(rng)
    parallel = [_correspondence(T_true, a, rng.uniform(-0.4, 0.4, 3)) for _ in range(2)]
    with pytest.raises(UnobservablePoseError):
        pose_family(parallel)


def test_family_offsets_place_the_robot_at_the_distances_in_front(T_true, rng):
    motions = _random_correspondences(T_true, rng, 2)
    R, t0, u = pose_family(motions)
    points = rng.uniform(-0.4, 0.4, (5, 3))
    centre_cam = T_true[:3, :3] @ points.mean(axis=0) + T_true[:3, 3]
    true_distance = float(np.linalg.norm(centre_cam))
    distances = np.array([0.5, true_distance, 3.0, 5.0])
    s = family_offsets(R, t0, u, points, distances)
    assert np.all(np.diff(s) > 0)
    members = R @ points.mean(axis=0) + t0 + np.outer(s, u)  # the centroid in the camera frame per member
    assert np.all(members[:, 2] > 0)
    reached = np.linalg.norm(members, axis=1)
    assert np.all(np.min(np.abs(reached[:, None] - distances[None]), axis=1) < POSE_TOL)
    s_true = (T_true[:3, 3] - t0) @ u
    assert np.min(np.abs(s - s_true)) < POSE_TOL  # the true pose is a member
    # nearer than the line p0 + s u passes to the camera centre: no member
    line_distance = np.linalg.norm(members[0] - (members[0] @ u) * u)
    assert family_offsets(R, t0, u, points, np.array([0.5 * line_distance])).size == 0


def test_the_linear_rows_of_all_motions_match_the_papers_per_motion_blocks():
    """H's collinearity rows [A^c]x (a_b^T kron I) and coplanarity row (d_b kron rho) / depth, K's rho / depth."""
    rng = np.random.default_rng(5)
    units = [v / np.linalg.norm(v) for v in rng.normal(size=(15, 3))]
    cors = [AxisCorrespondence(units[i], rng.normal(size=3), units[i + 5], units[i + 10]) for i in range(5)]
    depths = rng.uniform(0.5, 2.0, 5)
    H, K = _rows(cors, depths)
    assert H.shape == (20, 9) and K.shape == (20, 3)
    for i, (c, d) in enumerate(zip(cors, depths, strict=True)):
        np.testing.assert_allclose(H[4 * i:4 * i + 3], skew(c.axis_cam) @ np.kron(c.axis_base[None, :], np.eye(3)),
                                   rtol=0, atol=1e-15)
        np.testing.assert_allclose(H[4 * i + 3], np.kron(c.point_base, c.plane_normal) / d, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(K[4 * i:4 * i + 3], 0.0)
        np.testing.assert_allclose(K[4 * i + 3], c.plane_normal / d, rtol=0, atol=1e-15)
