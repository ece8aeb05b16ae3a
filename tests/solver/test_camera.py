"""Tests of solver/camera.py: pixels <-> normalized image coordinates."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from solver.camera import in_image, normalized_from_pixels, pixels_from_camera_points, rays_from_normalized
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics
from tests.solver.scene import CX, CY, FX, FY, HEIGHT, WIDTH, K

#: Distortion-free undistortion is one affine map: only float64 rounding (~1e-16 relative) remains.
PINHOLE_TOL = 1e-12

#: Round trip through OpenCV's iterative undistortion; the brief's accuracy for a usable camera
#: (1e-6 in normalized units is 1.4e-3 px at fx = 1380).
ROUND_TRIP_TOL = 1e-6

#: A RealSense-like mild distortion (k1, k2, p1, p2, k3).
MILD_DIST = np.array([0.1, -0.2, 0.001, -0.001, 0.05])

#: A wide-angle webcam's strong barrel distortion (k1, k2, p1, p2, k3).
STRONG_BARREL_DIST = np.array([-0.3, 0.1, 0.001, 0.001, 0.0])


def _normalized_in_view(rng: np.random.Generator, n: int) -> np.ndarray:
    """Normalized coordinates spread over the whole 1920x1080 field of view."""
    return np.column_stack([rng.uniform(-CX / FX, CX / FX, n), rng.uniform(-CY / FY, CY / FY, n)])


def _camera_points(uv: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    return np.column_stack([uv, np.ones(uv.shape[0])]) * rng.uniform(0.3, 4.0, uv.shape[0])[:, None]


def test_normalized_from_pixels_matches_hand_pinhole(camera, rng):
    pixels = np.column_stack([rng.uniform(0, WIDTH - 1, 200), rng.uniform(0, HEIGHT - 1, 200)])
    expected = np.column_stack([(pixels[:, 0] - CX) / FX, (pixels[:, 1] - CY) / FY])
    np.testing.assert_allclose(normalized_from_pixels(pixels, camera), expected, rtol=0,
                               atol=PINHOLE_TOL)


def test_pixels_from_camera_points_matches_hand_pinhole(camera, rng):
    points = _camera_points(_normalized_in_view(rng, 200), rng)
    expected = np.column_stack([FX * points[:, 0] / points[:, 2] + CX,
                                FY * points[:, 1] / points[:, 2] + CY])
    np.testing.assert_allclose(pixels_from_camera_points(points, camera), expected, rtol=0,
                               atol=PINHOLE_TOL * WIDTH)


def test_principal_point_maps_to_origin(camera):
    np.testing.assert_allclose(normalized_from_pixels(np.array([[CX, CY]]), camera), [[0.0, 0.0]],
                               atol=PINHOLE_TOL)


def test_round_trip_with_mild_distortion(rng):
    camera = CameraIntrinsics(K=K.copy(), dist=MILD_DIST, width=WIDTH, height=HEIGHT)
    uv = _normalized_in_view(rng, 500)
    pixels = pixels_from_camera_points(_camera_points(uv, rng), camera)
    # The distortion must actually move the pixels, or this test would not test undistortion.
    assert np.max(np.abs(pixels - (uv * [FX, FY] + [CX, CY]))) > 10.0
    np.testing.assert_allclose(normalized_from_pixels(pixels, camera), uv, rtol=0,
                               atol=ROUND_TRIP_TOL)


def test_round_trip_with_strong_barrel_distortion_at_corners():
    camera = CameraIntrinsics(K=K.copy(), dist=STRONG_BARREL_DIST, width=WIDTH, height=HEIGHT)
    corners = np.array([[sx * CX / FX, sy * CY / FY] for sx in (-1, 1) for sy in (-1, 1)])
    pixels = pixels_from_camera_points(np.column_stack([corners, np.ones(4)]), camera)
    assert np.all((pixels >= 0) & (pixels <= [WIDTH - 1, HEIGHT - 1]))  # still inside the image
    np.testing.assert_allclose(normalized_from_pixels(pixels, camera), corners, rtol=0,
                               atol=ROUND_TRIP_TOL)


def test_empty_inputs_give_empty_outputs(camera):
    assert normalized_from_pixels(np.zeros((0, 2)), camera).shape == (0, 2)
    assert pixels_from_camera_points(np.zeros((0, 3)), camera).shape == (0, 2)


def test_rays_from_normalized_appends_unit_depth():
    uv = np.array([[0.1, -0.2], [0.0, 0.3]])
    np.testing.assert_array_equal(rays_from_normalized(uv), [[0.1, -0.2, 1.0], [0.0, 0.3, 1.0]])


def test_from_fov_puts_principal_point_at_image_centre():
    camera = CameraIntrinsics.from_fov(FX, WIDTH, HEIGHT)
    np.testing.assert_array_equal(camera.K, K)
    np.testing.assert_array_equal(camera.focal, [FX, FY])
    assert camera.dist.size == 0


def _k_with(row: int, col: int, value: float) -> np.ndarray:
    bad = K.copy()
    bad[row, col] = value
    return bad


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        pytest.param({"K": np.eye(3)[:2]}, r"K must be 3x3, got shape \(2, 3\)", id="K-shape"),
        pytest.param({"K": _k_with(0, 2, np.nan)}, "K contains NaN", id="K-nan"),
        pytest.param({"K": _k_with(1, 1, np.inf)}, "K contains NaN or infinite", id="K-inf"),
        pytest.param({"K": _k_with(0, 0, -FX)}, "positive focal lengths", id="K-negative-focal"),
        pytest.param({"K": _k_with(2, 2, 2.0)}, r"last row \[0, 0, 1\]", id="K-last-row"),
        pytest.param({"K": K, "dist": np.zeros(3)}, "dist must have 0, 4, 5, 8, 12 or 14 "
                     "coefficients, got 3", id="dist-length"),
        pytest.param({"K": K, "dist": np.array([0.1, np.nan, 0, 0])}, "dist contains NaN",
                     id="dist-nan"),
        pytest.param({"K": K, "width": 0}, r"width must be an integer in 1\.\.16384, got 0", id="zero-width"),
        pytest.param({"K": K, "width": 2**31}, r"width must be an integer in 1\.\.16384", id="huge-width"),
        pytest.param({"K": K, "height": 540.5}, r"height must be an integer", id="float-height"),
        pytest.param({"K": _k_with(1, 1, 1e300)}, r"K\[1\]\[1\] \(fy\) = 1e\+300 px is not a focal length",
                     id="K-huge-focal"),
        pytest.param({"K": _k_with(1, 1, 1e-300)}, r"K\[1\]\[1\] \(fy\) = 1e-300 px is not a focal length",
                     id="K-tiny-focal"),
        pytest.param({"K": _k_with(0, 2, 5 * WIDTH)}, r"K\[0\]\[2\] \(cx\) .* principal point", id="K-far-cx"),
        pytest.param({"K": K, "dist": np.array([0.1, 1e9, 0, 0])}, r"dist\[1\] = 1e\+09 is not a distortion",
                     id="dist-huge"),
    ],
)
def test_intrinsics_validation(kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        CameraIntrinsics(**kwargs)


def test_intrinsics_error_is_also_a_value_error():
    with pytest.raises(ValueError, match="K must be 3x3"):
        CameraIntrinsics(K=np.eye(4))


def test_in_image_bounds_are_pixel_centres_with_margin():
    cam = CameraIntrinsics.from_fov(500.0, 640, 480)
    px = np.array([[0.0, 0.0], [639.0, 479.0], [-0.01, 10.0], [639.01, 10.0], [10.0, 479.5], [320.0, 240.0]])
    np.testing.assert_array_equal(in_image(px, cam), [True, True, False, False, False, True])
    np.testing.assert_array_equal(in_image(px, cam, margin_px=5.0), [False, False, False, False, False, True])
    np.testing.assert_array_equal(in_image(np.array([[5.0, 5.0], [634.0, 474.0], [634.5, 10.0]]), cam, 5.0),
                                  [True, True, False])
    assert in_image(np.zeros((3, 4, 2)), cam).shape == (3, 4)


# -- the fisheye model --------------------------------------------------------------------------------------
#: A 1280x800 fisheye: its corners are 77 degrees off the axis (a pinhole of this focal length would put
#: them 4.3x further out); theta_d(theta) is monotonic up to 89 degrees.
FISHEYE_W, FISHEYE_H = 1280, 800
FISHEYE_K = np.array([[520.0, 0.0, 641.3], [0.0, 522.0, 398.2], [0.0, 0.0, 1.0]])
FISHEYE_D = np.array([0.08, -0.03, 0.008, -0.001])


@pytest.fixture
def fisheye() -> CameraIntrinsics:
    return CameraIntrinsics(K=FISHEYE_K, dist=FISHEYE_D, width=FISHEYE_W, height=FISHEYE_H, model="fisheye")


def _directions(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Unit rays at theta off the optical axis and azimuth phi, radians -> (N, 3)."""
    return np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _equidistant_by_hand(points: np.ndarray) -> np.ndarray:
    """OpenCV's fisheye model written out: r_d = theta (1 + k1 theta^2 + ... + k4 theta^8), pixels = K (r_d / r) xy."""
    xy = points[:, :2] / points[:, 2:]
    r = np.hypot(xy[:, 0], xy[:, 1])
    theta = np.arctan(r)
    theta_d = theta * (1 + sum(k * theta ** (2 * i + 2) for i, k in enumerate(FISHEYE_D)))
    scale = np.where(r > 0, theta_d / np.where(r > 0, r, 1.0), 1.0)
    d = xy * scale[:, None]
    return np.column_stack([FISHEYE_K[0, 0] * d[:, 0] + FISHEYE_K[0, 2], FISHEYE_K[1, 1] * d[:, 1] + FISHEYE_K[1, 2]])


def test_fisheye_projection_matches_the_model_by_hand(fisheye, rng):
    points = _directions(rng.uniform(0, np.radians(80), 500), rng.uniform(-np.pi, np.pi, 500))
    points *= rng.uniform(0.3, 4.0, 500)[:, None]
    np.testing.assert_allclose(pixels_from_camera_points(points, fisheye), _equidistant_by_hand(points), rtol=0,
                               atol=PINHOLE_TOL * FISHEYE_W)


def test_fisheye_undistortion_recovers_rays_over_the_whole_image(fisheye, rng):
    # Directions out to 85 degrees, projected by OpenCV itself; those landing in the image cover it to its
    # corners (77 degrees), where a pinhole with these K and D would be off by hundreds of pixels.
    n = 20000
    points = _directions(np.arccos(rng.uniform(np.cos(np.radians(85)), 1.0, n)), rng.uniform(-np.pi, np.pi, n))
    pixels, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), FISHEYE_K, FISHEYE_D)
    pixels = pixels.reshape(-1, 2)
    inside = in_image(pixels, fisheye)
    border = np.minimum(np.minimum(pixels[:, 0], FISHEYE_W - 1 - pixels[:, 0]),
                        np.minimum(pixels[:, 1], FISHEYE_H - 1 - pixels[:, 1]))
    near_border = inside & (border < 3.0)
    corner = inside & (np.hypot(*(pixels - FISHEYE_K[:2, 2]).T) > 0.97 * np.hypot(FISHEYE_W / 2, FISHEYE_H / 2))
    assert inside.sum() > 5000 and near_border.sum() > 50 and corner.sum() >= 4
    uv = normalized_from_pixels(pixels[inside], fisheye)
    truth = points[inside, :2] / points[inside, 2:]
    np.testing.assert_allclose(uv, truth, rtol=0, atol=ROUND_TRIP_TOL)
    # the pinhole model with the same numbers is far off: the test sees the model
    pinhole = CameraIntrinsics(K=FISHEYE_K, dist=FISHEYE_D, width=FISHEYE_W, height=FISHEYE_H)
    assert np.max(np.abs(normalized_from_pixels(pixels[inside], pinhole) - truth)) > 1.0


@settings(max_examples=100, deadline=None)
@given(theta=st.floats(0.0, np.radians(80)), phi=st.floats(-np.pi, np.pi), depth=st.floats(0.05, 20.0))
def test_fisheye_round_trip_property(theta, phi, depth):
    fisheye = CameraIntrinsics(K=FISHEYE_K, dist=FISHEYE_D, width=FISHEYE_W, height=FISHEYE_H, model="fisheye")
    point = _directions(np.array([theta]), np.array([phi])) * depth
    uv = normalized_from_pixels(pixels_from_camera_points(point, fisheye), fisheye)
    np.testing.assert_allclose(uv, point[:, :2] / point[:, 2:], rtol=0, atol=ROUND_TRIP_TOL)


def test_zero_fisheye_coefficients_are_still_equidistant():
    ideal = CameraIntrinsics(K=FISHEYE_K, dist=np.zeros(4), width=FISHEYE_W, height=FISHEYE_H, model="fisheye")
    assert ideal.has_distortion
    theta = np.radians(60)
    px = pixels_from_camera_points(_directions(np.array([theta]), np.array([0.0])), ideal)
    np.testing.assert_allclose(px[0, 0], FISHEYE_K[0, 2] + FISHEYE_K[0, 0] * theta, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        pytest.param({"dist": np.zeros(5)}, r"fisheye model takes exactly 4 distortion coefficients \(k1, k2, k3, "
                     r"k4\), got 5", id="five"),
        pytest.param({"dist": np.zeros(0)}, "exactly 4 distortion coefficients .*got 0", id="none"),
        pytest.param({"K": FISHEYE_K + [[0, 1.5, 0], [0, 0, 0], [0, 0, 0]]}, r"K\[0\]\[1\] \(skew\) = 1.5: the fisheye",
                     id="skew"),
        pytest.param({"model": "kannala"}, r"camera model 'kannala' is not one of \['fisheye', 'pinhole'\]",
                     id="unknown-model"),
    ],
)
def test_fisheye_validation(kwargs, match):
    args = {"K": FISHEYE_K, "dist": FISHEYE_D, "width": FISHEYE_W, "height": FISHEYE_H, "model": "fisheye"}
    with pytest.raises(InvalidInputError, match=match):
        CameraIntrinsics(**{**args, **kwargs})
