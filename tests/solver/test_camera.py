"""Tests of solver/camera.py: pixels <-> normalized image coordinates."""

from __future__ import annotations

import numpy as np
import pytest

from solver.camera import normalized_from_pixels, pixels_from_camera_points, rays_from_normalized
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
    from solver.camera import in_image

    cam = CameraIntrinsics.from_fov(500.0, 640, 480)
    px = np.array([[0.0, 0.0], [639.0, 479.0], [-0.01, 10.0], [639.01, 10.0], [10.0, 479.5], [320.0, 240.0]])
    np.testing.assert_array_equal(in_image(px, cam), [True, True, False, False, False, True])
    np.testing.assert_array_equal(in_image(px, cam, margin_px=5.0), [False, False, False, False, False, True])
    np.testing.assert_array_equal(in_image(np.array([[5.0, 5.0], [634.0, 474.0], [634.5, 10.0]]), cam, 5.0),
                                  [True, True, False])
    assert in_image(np.zeros((3, 4, 2)), cam).shape == (3, 4)
