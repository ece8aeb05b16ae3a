"""The rigid front end against an independent construction: points on a body turned by known angles
about a known line, projected by OpenCV through a known camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

import solver.rigid_axis as rigid_axis_module
from solver.camera import normalized_from_pixels
from solver.errors import DegenerateMotionError, InvalidInputError, NonRigidTracksError
from solver.observations import CameraIntrinsics, KeypointTrack, MotionObservation
from solver.rigid_axis import (
    RigidAxisConfig,
    _ArrowSystem,
    _grid_costs,
    _grid_starts,
    _inverse_3x3,
    _refine,
    _residuals,
    _rotations_of,
    _track_rms,
    _Tracks,
    _triangulate,
    _TrustRegionModel,
    _turn,
    geometry_from_rigid_fit,
    rigid_axis_of_motion,
    rms_threshold,
    sphere_directions,
    track_noise_px,
)

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


def _normalized_tracks(obs: MotionObservation):
    uv = [normalized_from_pixels(t.pixels, CAMERA) for t in obs.tracks]
    return _Tracks.of(uv, [t.delta for t in obs.tracks])


def _line_and_points(seed: int, point_noise: float = 0.0):
    """A scene's tracks in normalized coordinates, a line (a, p) a few degrees off and its points.

    The points are triangulated under that line (as the fit starts), moved by ``point_noise`` m."""
    rng = np.random.default_rng(seed)
    point = np.array([0.05, -0.1, 1.1])
    obs, axis = _scene(seed, rng.normal(size=3), point, n_tracks=8, n_frames=9)
    tracks = _normalized_tracks(obs)
    a = Rotation.from_rotvec(rng.normal(0.0, 0.05, 3)).apply(axis)
    p = point - a * (a @ point)
    p /= np.linalg.norm(p)
    X0 = _triangulate(tracks, tracks.rotations(a), p)
    return tracks, a, p, X0 + rng.normal(0.0, point_noise, X0.shape)


def test_the_analytic_jacobian_matches_central_differences():
    tracks, a, p, X0 = _line_and_points(11, point_noise=0.01)
    focal = float(K[0, 0])
    _, J_frame, J_point = _residuals(tracks, tracks.rotations(a), p, X0, focal, jacobian=True)
    step = 1e-6
    for k in range(3):  # the line's frame turned by +-step about each camera axis
        turned = [_turn(sign * step * np.eye(3)[k], a, p) for sign in (1.0, -1.0)]
        r_plus, r_minus = (_residuals(tracks, tracks.rotations(ak), pk, X0, focal) for ak, pk in turned)
        np.testing.assert_allclose(J_frame[:, :, k], (r_plus - r_minus) / (2 * step), rtol=1e-5, atol=1e-3)
    for k in range(3):  # every track's point moved at once: each frame sees only its own track's point
        moved = [X0 + sign * step * np.eye(3)[k] for sign in (1.0, -1.0)]
        r_plus, r_minus = (_residuals(tracks, tracks.rotations(a), p, X, focal) for X in moved)
        np.testing.assert_allclose(J_point[:, :, k], (r_plus - r_minus) / (2 * step), rtol=1e-5, atol=1e-3)


@pytest.mark.parametrize(("x_scale", "unit_scale", "seed", "point_noise"),
                         [("jac", False, 12, 0.0), (1.0, True, 14, 0.005)])
def test_the_block_trust_region_reaches_the_dense_ones_minimum(x_scale, unit_scale, seed, point_noise):
    """The Schur-complement trust region against scipy's (exact solver, dense Jacobian, same settings): the
    variables scaled by the Jacobian's column norms, or (``unit_scale``) not at all."""
    tracks, a0, p0, X0 = _line_and_points(seed, point_noise)
    focal, config = float(K[0, 0]), RigidAxisConfig()

    def residuals(x):
        a, p = _turn(x[:3], a0, p0)
        return _residuals(tracks, tracks.rotations(a), p, x[3:].reshape(-1, 3), focal).ravel()

    dense = least_squares(residuals, np.concatenate([np.zeros(3), X0.ravel()]), tr_solver="exact",
                          loss="cauchy", f_scale=config.loss_scale_px, x_scale=x_scale, max_nfev=100)
    a_dense, _ = _turn(dense.x[:3], a0, p0)
    a, p, X, rms = _refine(tracks, a0, p0, X0, focal, config, unit_scale=unit_scale)
    r = _residuals(tracks, tracks.rotations(a), p, X, focal)
    cost = 0.5 * config.loss_scale_px ** 2 * np.sum(np.log1p(r ** 2 / config.loss_scale_px ** 2))
    assert _angle(a0, a_dense) > np.radians(1.0)  # the start is off: both moved
    assert cost == pytest.approx(dense.cost, rel=1e-6)
    assert _angle(a, a_dense) < 1e-5
    squares = np.sum(r ** 2, axis=1)
    np.testing.assert_allclose(rms, [np.sqrt(np.mean(squares[tracks.track == t])) for t in range(len(X))],
                               rtol=1e-9)


@pytest.mark.parametrize("lower", [True, False])
def test_the_polished_fit_is_kept_only_when_its_cost_is_lower(monkeypatch, lower):
    """The chosen start's fit is fitted again unscaled, from where it ended; the lower truncated cost wins."""
    obs, axis = _scene(4, np.array([0.3, -1.0, 0.4]), np.array([0.1, 0.05, 1.2]))
    real = rigid_axis_module._fit_from_start
    calls = []

    def spy(uv, deltas, a, p, focal, config, noise_px, unit_scale=False):
        cost, a_fit, p_fit, tracks, X, n = real(uv, deltas, a, p, focal, config, noise_px, unit_scale)
        calls.append((unit_scale, a.copy(), a_fit.copy()))
        if unit_scale:  # a polished line turned by 2 degrees, at a cost below or above the searched one
            a_turned = _tilted(a_fit, np.radians(2.0))
            p_turned = p_fit - a_turned * (a_turned @ p_fit)
            p_turned /= np.linalg.norm(p_turned)
            X_turned = _triangulate(tracks, tracks.rotations(a_turned), p_turned)
            return cost + (-1.0 if lower else 1.0), a_turned, p_turned, tracks, X_turned, n
        return cost, a_fit, p_fit, tracks, X, n

    monkeypatch.setattr(rigid_axis_module, "_fit_from_start", spy)
    fit = rigid_axis_of_motion(obs, CAMERA, RigidAxisConfig(polish=True))
    searched = [c for c in calls if not c[0]]
    assert [c[0] for c in calls] == [False] * len(searched) + [True]  # once, after the search
    chosen = min(searched, key=lambda c: _angle(c[2], calls[-1][1]))[2]
    np.testing.assert_array_equal(calls[-1][1], chosen)  # it starts where the chosen fit ended
    assert _angle(fit.axis_cam, chosen) == pytest.approx(np.radians(2.0) if lower else 0.0, abs=1e-9)
    calls.clear()
    unpolished = rigid_axis_of_motion(obs, CAMERA)  # (off by default)
    assert not any(c[0] for c in calls)
    np.testing.assert_array_equal(unpolished.axis_cam, chosen)
    assert _angle(unpolished.axis_cam, axis) < np.radians(0.5)


def test_the_batched_track_check_matches_one_track_at_a_time():
    tracks, a, p, _ = _line_and_points(13)
    focal = float(K[0, 0])
    rms = _track_rms(tracks, a, p, focal)
    Rs = tracks.rotations(a)
    for t in range(len(rms)):
        rows = tracks.track == t
        one = _Tracks.of([tracks.uv[rows]], [tracks.delta[rows]])

        def residuals(X, one=one, rows=rows):
            return _residuals(one, Rs[rows], p, X[None], focal).ravel()

        alone = least_squares(residuals, np.array([0.0, 0.0, 1.0]) + p, method="lm", xtol=1e-14, ftol=1e-14)
        assert rms[t] == pytest.approx(np.sqrt(2.0 * np.mean(alone.fun ** 2)), rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("alpha", [0.0, 0.5])
def test_the_arrow_system_solves_the_assembled_normal_equations(alpha):
    rng = np.random.default_rng(14)
    n_tracks = 5
    J = rng.normal(size=(40, 3 + 3 * n_tracks))
    for t in range(n_tracks):  # each track's point touches its own 8 rows only
        rows = np.ones(40, dtype=bool)
        rows[8 * t:8 * t + 8] = False
        J[rows, 3 + 3 * t:6 + 3 * t] = 0.0
    H = J.T @ J
    blocks = [H[3 + 3 * t:6 + 3 * t, 3 + 3 * t:6 + 3 * t] for t in range(n_tracks)]
    system = _ArrowSystem(H[:3, :3], np.stack([H[:3, 3 + 3 * t:6 + 3 * t] for t in range(n_tracks)]),
                          np.stack(blocks), J.shape[0])
    assert system.full_rank
    b = rng.normal(size=3 + 3 * n_tracks)
    b_p = b[3:].reshape(-1, 3)
    b_y = system.to_eigen(b_p)
    assert np.linalg.norm(b_y) == pytest.approx(np.linalg.norm(b_p), rel=1e-12)  # the eigenbases keep lengths
    np.testing.assert_allclose(system.from_eigen(b_y), b_p, rtol=0, atol=1e-12)
    x_g, x_y = system.solve(system.factor(alpha), b[:3], b_y)
    np.testing.assert_allclose(np.concatenate([x_g, system.from_eigen(x_y).ravel()]),
                               np.linalg.solve(H + alpha * np.eye(H.shape[0]), b), rtol=1e-9, atol=1e-12)


#: Relative accuracy of the closed-form 3 x 3 inverse and of the trust region's steps against dense solves.
DENSE_RTOL = 1e-9


def _arrow_problem(seed: int, n_tracks: int = 5):
    """A random arrow-shaped normal matrix H (3 + 3T square, each track's point touching its own rows only), a
    gradient g, and the ``_ArrowSystem`` of H."""
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(8 * n_tracks, 3 + 3 * n_tracks))
    for t in range(n_tracks):
        rows = np.ones(J.shape[0], dtype=bool)
        rows[8 * t:8 * t + 8] = False
        J[rows, 3 + 3 * t:6 + 3 * t] = 0.0
    H = J.T @ J
    system = _ArrowSystem(H[:3, :3], np.stack([H[:3, 3 + 3 * t:6 + 3 * t] for t in range(n_tracks)]),
                          np.stack([H[3 + 3 * t:6 + 3 * t, 3 + 3 * t:6 + 3 * t] for t in range(n_tracks)]), J.shape[0])
    return H, rng.normal(size=H.shape[0]), system


def test_the_closed_form_inverse_matches_lapack():
    rng = np.random.default_rng(15)
    for scale in (1.0, 1e-6, 1e8):
        S = rng.normal(size=(3, 3)) * scale
        np.testing.assert_allclose(_inverse_3x3(S) @ S, np.eye(3), rtol=0, atol=DENSE_RTOL)
    near = np.diag([1.0, 1.0, 1e-10]) + 1e-12 * rng.normal(size=(3, 3))  # ill-conditioned, not singular
    np.testing.assert_allclose(_inverse_3x3(near), np.linalg.inv(near), rtol=1e-5)
    with pytest.raises(np.linalg.LinAlgError):
        _inverse_3x3(np.zeros((3, 3)))  # singular: LAPACK's verdict


@pytest.mark.parametrize("radius", [1e-3, 0.3, 1e6])
def test_the_trust_region_step_solves_the_damped_dense_system(radius):
    """The step of each radius against dense solves: (H + alpha I) h = -g for the alpha it reports, of length
    ``radius`` within More's 1 % when alpha > 0 (else the Gauss-Newton step, inside the radius); the model's
    predicted decrease against -(0.5 h^T H h + g^T h) assembled densely."""
    H, g, system = _arrow_problem(16)
    model = _TrustRegionModel(system, g[:3], g[3:].reshape(-1, 3))
    h_g, h_y, alpha = model.step(radius, 0.0)
    h = np.concatenate([h_g, system.from_eigen(h_y).ravel()])
    dense = np.linalg.solve(H + alpha * np.eye(H.shape[0]), -g)
    if alpha > 0:
        assert np.linalg.norm(h) == pytest.approx(radius, rel=1e-12)  # scaled to the radius exactly ...
        assert np.linalg.norm(dense) == pytest.approx(radius, rel=0.01)  # ... from More's solution within 1 %
        np.testing.assert_allclose(h, dense * radius / np.linalg.norm(dense), rtol=DENSE_RTOL, atol=1e-12)
    else:
        assert np.linalg.norm(dense) <= radius
        np.testing.assert_allclose(h, dense, rtol=DENSE_RTOL, atol=1e-12)
    assert model.decrease(h_g, h_y) == pytest.approx(-(0.5 * h @ H @ h + g @ h), rel=DENSE_RTOL)


def test_a_retried_radius_gives_the_same_step_as_a_fresh_model():
    """The Gauss-Newton step kept from the first radius does not leak into the next one's step."""
    _, g, system = _arrow_problem(17)
    model = _TrustRegionModel(system, g[:3], g[3:].reshape(-1, 3))
    model.step(1e6, 0.0)  # the Gauss-Newton step, kept
    retried = model.step(0.01, 0.0)
    fresh = _TrustRegionModel(system, g[:3], g[3:].reshape(-1, 3)).step(0.01, 0.0)
    for a, b in zip(retried, fresh, strict=True):
        np.testing.assert_array_equal(a, b)


def test_rotations_and_the_line_turn_match_scipy():
    """Rodrigues written out (``_rotations_of``, ``_turn``) against scipy's rotation vectors."""
    rng = np.random.default_rng(18)
    a = rng.normal(size=3)
    a /= np.linalg.norm(a)
    delta = rng.uniform(-1.0, 1.0, 7)
    turns = np.column_stack([np.cos(delta), np.sin(delta), np.ones_like(delta)])
    np.testing.assert_allclose(_rotations_of(turns, a), Rotation.from_rotvec(delta[:, None] * a).as_matrix(),
                               rtol=0, atol=1e-15 * 8)
    p = np.cross(a, rng.normal(size=3))
    p /= np.linalg.norm(p)
    w = rng.normal(0.0, 0.2, 3)
    a_turned, p_turned = _turn(w, a, p)
    K = Rotation.from_rotvec(w)
    np.testing.assert_allclose(a_turned, K.apply(a), rtol=0, atol=1e-14)
    np.testing.assert_allclose(p_turned, K.apply(p), rtol=0, atol=1e-14)
    np.testing.assert_array_equal(_turn(np.zeros(3), a, p)[0], a / np.linalg.norm(a))


def test_the_search_over_starts_is_checked():
    with pytest.raises(InvalidInputError, match="enough_inlier_fraction"):
        RigidAxisConfig(enough_inlier_fraction=0.0)
    with pytest.raises(InvalidInputError, match="enough_inlier_fraction"):
        RigidAxisConfig(enough_inlier_fraction=1.5)


def _far_scene(seed: int):
    """The camera 1.9-2.4 m away, half the tracks sliding, tracks spanning 1/3 to all of a 0.9 rad turn."""
    rng = np.random.default_rng(100 + seed)
    axis = rng.normal(size=3)
    point = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(1.9, 2.4)])
    return _scene(seed, axis, point, n_tracks=20, sliding=20, turn=0.9, noise_px=0.4)


def test_sphere_directions_cover_the_sphere_evenly():
    d = sphere_directions(2000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # every direction of a dense random set is within 4 degrees of a grid direction
    probe = np.random.default_rng(0).normal(size=(5000, 3))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip((probe @ d.T).max(axis=1), -1, 1))).max() < 4.0
    np.testing.assert_allclose(d.mean(axis=0), 0.0, atol=2e-3)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_the_grid_search_starts_near_the_axis_with_half_the_tracks_sliding(seed):
    obs, axis = _far_scene(seed)
    uv = [normalized_from_pixels(t.pixels, CAMERA) for t in obs.tracks]
    starts = _grid_starts(uv, [t.delta for t in obs.tracks], 1380.0, RigidAxisConfig())
    assert 1 <= len(starts) <= RigidAxisConfig().grid_starts
    # one of the starts within the grid's spacing (plus noise) of the true axis, the others 15 deg apart
    assert min(_angle(a, axis) for a, _ in starts) < np.radians(8.0)
    for i, (a, p) in enumerate(starts):
        assert abs(a @ p) < 1e-9 and abs(np.linalg.norm(p) - 1.0) < 1e-9
        assert all(_angle(a, b) > np.radians(15.0) for b, _ in starts[:i])


def _sampson_by_essential_matrix(x, y, R, t):
    """Sampson distance (normalized units^2) of the rays x -> y (3,) under E = [t]x R, written out."""
    t_cross = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    E = t_cross @ R
    Ex, Ety = E @ x, E.T @ y
    return float((y @ E @ x) ** 2 / (Ex[0] ** 2 + Ex[1] ** 2 + Ety[0] ** 2 + Ety[1] ** 2))


def test_the_grid_costs_match_essential_matrices_built_track_by_track():
    """Each trial axis's cost against the definition: every track's p from the null space of [a; its epipolar
    row], every proposal scored by explicit essential matrices of every track, truncated, the best kept."""
    obs, axis = _far_scene(0)
    uv = [normalized_from_pixels(t.pixels, CAMERA) for t in obs.tracks]
    x = np.array([np.append(u[0], 1.0) for u in uv])
    y = np.array([np.append(u[-1], 1.0) for u in uv])
    theta = np.array([t.delta[-1] - t.delta[0] for t in obs.tracks])
    config = RigidAxisConfig(ransac_px=2.0)
    threshold = (config.ransac_px / 1380.0) ** 2
    directions = np.vstack([axis, sphere_directions(300)[::37]])  # the true axis and 9 others
    costs, points = _grid_costs(x, y, theta, directions, 1380.0, config)
    for a, cost, point in zip(directions, costs, points, strict=True):
        Rs = [Rotation.from_rotvec(th * a).as_matrix() for th in theta]
        proposals = []
        for R, xl, yl in zip(Rs, x, y, strict=True):
            row = (np.eye(3) - R).T @ np.cross(R @ xl, yl)  # (I - R) p . (R x cross y) = 0
            proposals.append(np.linalg.svd(np.array([a, row]))[2][-1])
        totals = [sum(min(_sampson_by_essential_matrix(xl, yl, R, (np.eye(3) - R) @ p), threshold)
                      for R, xl, yl in zip(Rs, x, y, strict=True)) for p in proposals]
        assert cost == pytest.approx(min(totals), rel=1e-9)
        # the kept proposal is a best one (up to sign: p and -p give the same costs)
        best = [p for p, total in zip(proposals, totals, strict=True) if total <= min(totals) * (1 + 1e-9)]
        assert min(min(np.linalg.norm(point - p), np.linalg.norm(point + p)) for p in best) < 1e-9
    # not a comparison of truncation constants: the true axis explains the rigid half of the tracks
    assert np.argmin(costs) == 0 and costs[0] < 0.7 * np.min(costs[1:])


def test_the_grid_costs_do_not_depend_on_the_batching(monkeypatch):
    """Every trial axis's cost and proposal are the same whether the axes go in one batch or in batches of 7."""
    obs, _ = _far_scene(1)
    uv = [normalized_from_pixels(t.pixels, CAMERA) for t in obs.tracks]
    x = np.array([np.append(u[0], 1.0) for u in uv])
    y = np.array([np.append(u[-1], 1.0) for u in uv])
    theta = np.array([t.delta[-1] - t.delta[0] for t in obs.tracks])
    directions = sphere_directions(50)
    monkeypatch.setattr(rigid_axis_module, "_GRID_CHUNK", 50)
    whole = _grid_costs(x, y, theta, directions, 1380.0, RigidAxisConfig())
    monkeypatch.setattr(rigid_axis_module, "_GRID_CHUNK", 7)
    batched = _grid_costs(x, y, theta, directions, 1380.0, RigidAxisConfig())
    for a, b in zip(whole, batched, strict=True):
        np.testing.assert_array_equal(a, b)


def test_a_far_camera_with_sliding_tracks_still_gives_the_axis():
    """Seed 1: no frame pair's essential matrix finds the rigid motion; the grid search's start does."""
    obs, axis = _far_scene(1)
    fit = rigid_axis_of_motion(obs, CAMERA)
    assert _angle(fit.axis_cam, axis) < np.radians(1.0)
    assert fit.track_inliers[:20].sum() >= 18 and fit.track_inliers[20:].sum() <= 2
    assert RigidAxisConfig(grid_directions=0).grid_directions == 0
    with pytest.raises(InvalidInputError, match="grid_directions"):
        RigidAxisConfig(grid_directions=-1)


def _count_searches(monkeypatch) -> dict[str, int]:
    """Count the calls of both start searches (they still run)."""
    calls = {"grid": 0, "relative": 0}
    for name, key in (("_grid_starts", "grid"), ("_relative_pose", "relative")):
        original = getattr(rigid_axis_module, name)

        def counted(*args, _original=original, _key=key):
            calls[_key] += 1
            return _original(*args)

        monkeypatch.setattr(rigid_axis_module, name, counted)
    return calls


def _tilted(axis: np.ndarray, angle: float) -> np.ndarray:
    """``axis`` (3,) unit turned by ``angle`` rad about a perpendicular direction."""
    return Rotation.from_rotvec(angle * np.cross(axis, [0.0, 0.0, 1.0]) / np.linalg.norm(np.cross(axis, [0, 0, 1.0])))\
        .apply(axis)


def test_a_right_predicted_start_is_fitted_and_no_search_runs(monkeypatch):
    """Half the tracks slide; the prediction is 1.5 deg and 1.4 cm off: the tracks' own fit from it is taken."""
    obs, axis = _far_scene(0)
    calls = _count_searches(monkeypatch)
    searched = rigid_axis_of_motion(obs, CAMERA)
    assert calls["grid"] == 1 and not searched.from_prediction
    searched_relative = calls["relative"]
    point = searched.point_cam * 2.1  # the searched line at about the scene's depth, m
    predicted = (_tilted(axis, np.radians(1.5)), point + np.array([0.01, -0.01, 0.0]))
    fit = rigid_axis_of_motion(obs, CAMERA, predicted=predicted)
    assert fit.from_prediction and calls["grid"] == 1  # no search ran this time
    assert calls["relative"] == searched_relative
    assert _angle(fit.axis_cam, axis) < np.radians(1.0)
    assert _angle(fit.axis_cam, searched.axis_cam) < np.radians(0.3)
    # the rigid tracks kept, the sliding ones dropped, as the search's fit does (borderline ones aside)
    assert fit.track_inliers[:20].sum() >= 18 and np.sum(fit.track_inliers != searched.track_inliers) <= 2


@pytest.mark.parametrize("wrong_by", [np.radians(60.0), np.pi])  # a turned axis; the opposite one
def test_a_wrong_predicted_start_falls_back_to_the_search(monkeypatch, wrong_by):
    obs, axis = _far_scene(1)  # seed 1: only the grid search finds the rigid motion
    calls = _count_searches(monkeypatch)
    predicted = (_tilted(axis, wrong_by), np.array([0.1, 0.0, 2.0]))
    fit = rigid_axis_of_motion(obs, CAMERA, predicted=predicted)
    assert not fit.from_prediction and calls["grid"] == 1
    assert _angle(fit.axis_cam, axis) < np.radians(1.0)
    assert fit.track_inliers[:20].sum() >= 18 and fit.track_inliers[20:].sum() <= 2
    # the search decides as without a prediction: the same fit
    plain = rigid_axis_of_motion(obs, CAMERA)
    np.testing.assert_array_equal(fit.axis_cam, plain.axis_cam)
    np.testing.assert_array_equal(fit.track_inliers, plain.track_inliers)


def test_starts_given_as_a_function_are_asked_for_only_when_tried():
    """A right prediction is taken without calling it; a wrong one calls it once, and its starts fit as a list's."""
    obs, axis = _far_scene(0)
    searched = rigid_axis_of_motion(obs, CAMERA)
    asked = []

    def starts():
        asked.append(1)
        return [(searched.axis_cam, searched.point_cam)]

    right = (_tilted(axis, np.radians(1.5)), searched.point_cam * 2.1)
    assert rigid_axis_of_motion(obs, CAMERA, starts=starts, predicted=right).from_prediction and not asked
    wrong = (_tilted(axis, np.radians(60.0)), np.array([0.1, 0.0, 2.0]))
    lazy = rigid_axis_of_motion(obs, CAMERA, starts=starts, predicted=wrong)
    eager = rigid_axis_of_motion(obs, CAMERA, starts=[(searched.axis_cam, searched.point_cam)], predicted=wrong)
    assert len(asked) == 1 and not lazy.from_prediction
    np.testing.assert_array_equal(lazy.axis_cam, eager.axis_cam)
    np.testing.assert_array_equal(lazy.track_inliers, eager.track_inliers)


def test_the_relative_poses_are_tried_only_when_no_earlier_fit_is_usable(monkeypatch):
    """With ``relative_pose_if_needed``, the grid's fit keeps the rigid half of the tracks: no essential matrix is
    computed (by default they are, and the same fit wins); when no fit can keep enough tracks
    (min_inlier_fraction 0.9), they are tried."""
    obs, axis = _far_scene(0)
    calls = _count_searches(monkeypatch)
    if_needed = RigidAxisConfig(relative_pose_if_needed=True)
    fit = rigid_axis_of_motion(obs, CAMERA, if_needed)
    assert calls == {"grid": 1, "relative": 0}
    always = rigid_axis_of_motion(obs, CAMERA)
    assert calls == {"grid": 2, "relative": 1}
    assert _angle(fit.axis_cam, axis) < np.radians(1.0) and _angle(always.axis_cam, fit.axis_cam) < 1e-6
    with pytest.raises(NonRigidTracksError, match="move rigidly together"):
        rigid_axis_of_motion(obs, CAMERA, RigidAxisConfig(relative_pose_if_needed=True, min_inlier_fraction=0.9))
    assert calls == {"grid": 3, "relative": 2}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_too_few_rigid_tracks_raise_with_the_fit_they_follow(seed):
    """12 of 40 tracks turn rigidly and the front end is made to need half: no axis, but the error carries the fit
    the 12 follow (and a few short sliding tracks that slid too little to tell), near the true axis; when
    ``min_tracks`` is more than follow it, it carries none."""
    rng = np.random.default_rng(200 + seed)
    axis = rng.normal(size=3)
    point = np.array([rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), rng.uniform(0.9, 1.4)])
    obs, axis = _scene(seed, axis, point, n_tracks=12, sliding=28)
    half = RigidAxisConfig(min_inlier_fraction=0.5)
    with pytest.raises(NonRigidTracksError, match="tracks move rigidly together") as caught:
        rigid_axis_of_motion(obs, CAMERA, half)
    fit = caught.value.fit
    assert fit is not None and _angle(fit.axis_cam, axis) < np.radians(2.0)
    assert fit.track_inliers[:12].all() and 12 <= fit.track_inliers.sum() < 20 and fit.rms_px < 1.0
    with pytest.raises(NonRigidTracksError) as caught:
        rigid_axis_of_motion(obs, CAMERA, RigidAxisConfig(min_inlier_fraction=0.5, min_tracks=25))
    assert caught.value.fit is None


def test_the_predicted_angle_is_checked():
    with pytest.raises(InvalidInputError, match="predicted_angle"):
        RigidAxisConfig(predicted_angle=0.0)


def test_the_track_threshold_follows_the_tracks_noise():
    assert rms_threshold(np.full(20, 5.0), RigidAxisConfig(), 3.0) == RigidAxisConfig().max_track_rms_px  # off
    config = RigidAxisConfig(noise_factor=2.0)
    quiet = np.full(20, 0.3)
    assert rms_threshold(quiet, config, 0.2) == config.max_track_rms_px
    noisy = np.concatenate([np.full(15, 1.4), np.full(5, 30.0), [np.inf]])  # 1 px noise, 5 sliding, 1 not fitted
    assert rms_threshold(noisy, config, 1.0) == pytest.approx(2.8)
    # the same residuals from jitter-free tracks are a misfit of the model, not noise: at most the
    # tracker's smooth error
    assert rms_threshold(noisy, config, 0.0) == pytest.approx(1.5)
    assert rms_threshold(np.full(20, 0.6), config, 0.0) == pytest.approx(1.2)
    assert rms_threshold(np.full(3, np.inf), config, 1.0) == config.max_track_rms_px


def test_the_jitter_estimate_reads_the_noise_not_the_path():
    rng = np.random.default_rng(3)
    s = np.linspace(0.0, 1.0, 40)[:, None]
    arcs = [np.column_stack([np.cos(s[:, 0] + k), np.sin(s[:, 0] + k)]) * 0.1 for k in range(30)]  # smooth curves
    assert track_noise_px(arcs, 1000.0) < 0.05
    noisy = [a + rng.normal(0.0, 0.7 / 1000.0, a.shape) for a in arcs]  # 0.7 px per coordinate
    assert track_noise_px(noisy, 1000.0) == pytest.approx(0.7, rel=0.1)
    assert track_noise_px([np.zeros((2, 2))], 1000.0) == 0.0


def test_one_pixel_of_noise_still_gives_the_axis():
    """A fixed 1 px threshold dropped every track at this noise (RMS about 1.4 px); the adaptive one keeps them."""
    point = np.array([0.05, -0.1, 1.1])
    obs, axis = _scene(4, np.array([0.3, 1.0, 0.4]), point, n_tracks=30, sliding=8, noise_px=1.0)
    with pytest.raises(DegenerateMotionError, match="move rigidly together"):
        rigid_axis_of_motion(obs, CAMERA)  # the fixed 1 px threshold (the default)
    fit = rigid_axis_of_motion(obs, CAMERA, RigidAxisConfig(noise_factor=2.0))
    assert _angle(fit.axis_cam, axis) < np.radians(1.0)
    assert fit.track_inliers[:30].sum() >= 27
    # the limit: at this noise a slow slide (25 px/rad) partly hides in another depth, and some pass
    assert fit.track_inliers[30:].sum() <= 5


def _singular_first(monkeypatch, fails: int) -> None:
    """The first ``fails`` starts' fits raise numpy's LinAlgError, as a singular Schur complement does."""
    original = rigid_axis_module._fit_from_start
    calls = {"n": 0}

    def flaky(*args):
        calls["n"] += 1
        if calls["n"] <= fails:
            raise np.linalg.LinAlgError("Singular matrix")
        return original(*args)

    monkeypatch.setattr(rigid_axis_module, "_fit_from_start", flaky)


def test_a_start_whose_fit_goes_singular_is_skipped(monkeypatch):
    # Seen 2026-11-29 on a realistic Panda sweep: LinAlgError escaped Calibrator.add_motion from one start.
    point = np.array([0.05, -0.1, 1.1])
    obs, axis = _scene(3, np.array([0.3, 1.0, 0.2]), point)
    _singular_first(monkeypatch, 1)
    fit = rigid_axis_of_motion(obs, CAMERA, predicted=(axis, point / np.linalg.norm(point)))
    assert _angle(fit.axis_cam, axis) < np.radians(0.5)
    assert not fit.from_prediction  # the predicted start was the singular one; another start gave the fit


def test_every_start_singular_is_a_degenerate_motion(monkeypatch):
    obs, _ = _scene(3, np.array([0.3, 1.0, 0.2]), np.array([0.05, -0.1, 1.1]))
    _singular_first(monkeypatch, 10**6)
    with pytest.raises(DegenerateMotionError, match="singular"):
        rigid_axis_of_motion(obs, CAMERA)
