"""The rigid front end against an independent construction: points on a body turned by known angles
about a known line, projected by OpenCV through a known camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from solver.errors import DegenerateMotionError, InvalidInputError
from solver.observations import CameraIntrinsics, KeypointTrack, MotionObservation
from solver.rigid_axis import RigidAxisConfig, geometry_from_rigid_fit, rigid_axis_of_motion

K = np.array([[1380.0, 0.0, 960.0], [0.0, 1380.0, 540.0], [0.0, 0.0, 1.0]])
CAMERA = CameraIntrinsics(K=K, dist=np.zeros(5), width=1920, height=1080)


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0)))


def _scene(seed: int, axis: np.ndarray, point: np.ndarray, n_tracks: int = 30, turn: float = 0.8,
           n_frames: int = 25, noise_px: float = 0.2, sliding: int = 0):
    """Tracks of points within 0.15 m of the axis point (camera frame), turned by 0..turn rad.

    ``sliding`` more tracks drift 25 px per rad of turn along a random image direction besides (a
    point on a silhouette or a highlight, which slides over the surface)."""
    rng = np.random.default_rng(seed)
    axis = axis / np.linalg.norm(axis)
    delta = np.linspace(0.0, turn, n_frames)
    tracks = []
    for k in range(n_tracks + sliding):
        X0 = point + rng.uniform(-0.15, 0.15, 3)
        first = rng.integers(0, n_frames // 3)  # tracks start and end at different frames
        last = n_frames - rng.integers(0, n_frames // 3)
        d = delta[first:last]
        X = Rotation.from_rotvec(d[:, None] * axis).apply(X0 - point) + point
        px, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, None)
        px = px.reshape(-1, 2) + rng.normal(0.0, noise_px, (len(d), 2))
        if k >= n_tracks:
            direction = rng.normal(size=2)
            px += 25.0 * (d - d[0])[:, None] * direction / np.linalg.norm(direction)
        tracks.append(KeypointTrack(px, d))
    return MotionObservation(q_start=np.zeros(7), joint=2, tracks=tuple(tracks)), axis


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_the_axis_and_its_line(seed):
    rng = np.random.default_rng(100 + seed)
    axis = rng.normal(size=3)
    point = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.9, 1.4)])
    obs, axis = _scene(seed, axis, point)
    fit = rigid_axis_of_motion(obs, CAMERA)
    assert _angle(fit.axis_cam, axis) < np.radians(0.5)
    # the line: the closest point to the camera centre, up to the scene's scale
    closest = point - axis * (axis @ point)
    assert _angle(fit.point_cam, closest) < np.radians(0.5)
    assert abs(np.linalg.norm(fit.point_cam) - 1.0) < 1e-9 and abs(fit.point_cam @ fit.axis_cam) < 1e-9
    assert fit.track_inliers.all() and fit.rms_px < 0.5
    # the geometry the linear stage takes: the plane through the camera centre holding the axis
    geometry = geometry_from_rigid_fit(fit)
    assert abs(geometry.plane_normal @ axis) < 0.01
    assert abs(geometry.plane_normal @ point) / np.linalg.norm(point) < 0.01


def test_an_edge_on_view_still_gives_the_axis():
    """The camera in the plane of rotation: trajectories are lines to the conics, not to this fit."""
    point = np.array([0.0, 0.0, 1.2])
    axis = np.array([1.0, 0.0, 0.02])  # rotation plane nearly holds the camera centre's ray
    obs, axis = _scene(5, axis, point, turn=1.0)
    fit = rigid_axis_of_motion(obs, CAMERA)
    assert _angle(fit.axis_cam, axis) < np.radians(1.0)


def test_sliding_tracks_are_dropped():
    """Drifts of ~10-20 px over a track are found; a few px can be absorbed by another depth (a limit)."""
    point = np.array([0.05, -0.1, 1.1])
    obs, axis = _scene(7, np.array([0.3, 1.0, 0.4]), point, n_tracks=30, sliding=10)
    fit = rigid_axis_of_motion(obs, CAMERA)
    assert _angle(fit.axis_cam, axis) < np.radians(0.5)
    assert fit.track_inliers[:30].sum() >= 28 and fit.track_inliers[30:].sum() <= 2


def test_a_sign_flip_of_delta_flips_the_axis():
    point = np.array([0.0, 0.1, 1.0])
    obs, axis = _scene(3, np.array([0.2, 0.9, -0.3]), point)
    flipped = MotionObservation(obs.q_start, obs.joint,
                                tuple(KeypointTrack(t.pixels, -t.delta) for t in obs.tracks))
    assert _angle(rigid_axis_of_motion(flipped, CAMERA).axis_cam, -axis) < np.radians(0.5)


def test_degenerate_motions_raise_with_a_reason():
    point = np.array([0.0, 0.0, 1.0])
    few, _ = _scene(1, np.array([0.0, 1.0, 0.0]), point, n_tracks=4)
    with pytest.raises(DegenerateMotionError, match="4 tracks"):
        rigid_axis_of_motion(few, CAMERA)
    small, _ = _scene(1, np.array([0.0, 1.0, 0.0]), point, turn=0.05)
    with pytest.raises(DegenerateMotionError, match="rigid front end"):
        rigid_axis_of_motion(small, CAMERA)
    noise, _ = _scene(2, np.array([0.0, 1.0, 0.0]), point, noise_px=8.0)
    with pytest.raises(DegenerateMotionError, match="rigid front end"):
        rigid_axis_of_motion(noise, CAMERA)


def test_config_is_checked():
    with pytest.raises(InvalidInputError):
        RigidAxisConfig(min_tracks=3)
    with pytest.raises(InvalidInputError):
        RigidAxisConfig(max_track_rms_px=0.0)
