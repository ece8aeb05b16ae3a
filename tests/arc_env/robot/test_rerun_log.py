"""The geometry a Rerun log draws: ellipses, axis lines, the camera centre's covariance."""


import numpy as np

from arc_env.robot.rerun_log import (
    axis_image_line,
    camera_centre_covariance,
    ellipse_points,
    frame_indices,
)
from solver import d415_intrinsics, sample_camera_pose
from solver.camera import pixels_from_camera_points
from solver.conics import fit_ellipse_direct
from solver.frames import perturb
from solver.observations import KeypointTrack


def test_ellipse_points_lie_on_the_fitted_conic():
    t = np.linspace(0.0, 5.0, 40)
    uv = np.column_stack([0.1 + 0.3 * np.cos(t), -0.2 + 0.1 * np.sin(t)])  # an axis-aligned ellipse
    Q = fit_ellipse_direct(uv).matrix
    pts = ellipse_points(Q, 100)
    assert pts.shape == (101, 2) and np.allclose(pts[0], pts[-1])
    homogeneous = np.column_stack([pts, np.ones(len(pts))])
    assert np.max(np.abs(np.einsum("pi,ij,pj->p", homogeneous, Q, homogeneous))) < 1e-9
    np.testing.assert_allclose(pts.min(axis=0), [-0.2, -0.3], atol=1e-3)
    np.testing.assert_allclose(pts.max(axis=0), [0.4, -0.1], atol=1e-3)
    assert ellipse_points(np.diag([1.0, 1.0, 1.0])) is None  # imaginary: no points


def test_axis_line_is_the_image_of_the_3d_line():
    intrinsics = d415_intrinsics(640, 360)
    point, direction = np.array([0.1, -0.05, 1.5]), np.array([0.3, 1.0, 0.2])
    normal = np.cross(point, direction)
    normal /= np.linalg.norm(normal)
    line = axis_image_line(normal, intrinsics)
    truth = pixels_from_camera_points(point + np.linspace(-0.3, 0.3, 7)[:, None] * direction, intrinsics)
    # every drawn point is on the projected line (no distortion: a straight line through two of its images)
    a, b = truth[0], truth[-1]
    d = (b - a) / np.linalg.norm(b - a)
    offset = (line - a) @ np.array([-d[1], d[0]])
    assert np.max(np.abs(offset)) < 1e-6
    assert np.all((line >= -1.0) & (line <= [640.0, 360.0]))  # clipped to the image
    assert axis_image_line(np.array([0.0, 0.0, 1.0]), intrinsics) is None  # the line at infinity


def test_camera_centre_covariance_matches_first_order_propagation(rng):
    T = sample_camera_pose(rng)
    centre = -T[:3, :3].T @ T[:3, 3]
    J = np.zeros((3, 6))
    for k in range(6):  # d(R_hat c) / d xi, numerically
        xi = np.zeros(6)
        xi[k] = 1e-7
        Tp = perturb(T, xi)
        J[:, k] = T[:3, :3] @ (-Tp[:3, :3].T @ Tp[:3, 3] - centre) / 1e-7
    A = rng.normal(size=(6, 6))
    cov = A @ A.T * 1e-6
    np.testing.assert_allclose(camera_centre_covariance(T, cov), J @ cov @ J.T, rtol=1e-5, atol=1e-14)


def test_frame_indices_find_each_track_point_frame():
    deltas = np.linspace(0.0, -0.9, 10)
    track = KeypointTrack(np.zeros((3, 2)), deltas[[2, 3, 7]])
    assert frame_indices(track, deltas).tolist() == [2, 3, 7]
