"""The one place where pixels become normalized image coordinates, and its inverse.

Normalized image coordinates (u, v) are the OpenCV optical frame's x/z and y/z: the ray through a
pixel is (u, v, 1) in the camera frame (x right, y down, z forward).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray
from solver.observations import CameraIntrinsics


def normalized_from_pixels(pixels: FloatArray, intrinsics: CameraIntrinsics) -> FloatArray:
    """Undistort and normalize pixel coordinates (cv2.undistortPoints).

    Args:
        pixels: (M, 2) float64, pixels.
        intrinsics: the camera.

    Returns:
        (M, 2) float64: normalized image coordinates (x/z, y/z).
    """
    pts = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    if not intrinsics.dist.size:
        return cv2.undistortPoints(pts, intrinsics.K, None).reshape(-1, 2)
    # The default 5 iterations leave ~0.2 px at the corners of strongly distorted images.
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    args = (pts, intrinsics.K, intrinsics.dist, np.eye(3), np.eye(3), criteria)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        return cv2.undistortPointsIter(*args).reshape(-1, 2)
    return cv2.undistortPoints(pts, intrinsics.K, intrinsics.dist, None, np.eye(3), np.eye(3),
                               criteria).reshape(-1, 2)


def pixels_from_camera_points(points_cam: FloatArray, intrinsics: CameraIntrinsics) -> FloatArray:
    """Project camera-frame points to distorted pixels (cv2.projectPoints).

    Args:
        points_cam: (M, 3) float64, metres, in the OpenCV optical frame; z > 0.
        intrinsics: the camera.

    Returns:
        (M, 2) float64, pixels.
    """
    pts = np.ascontiguousarray(points_cam, dtype=np.float64).reshape(-1, 3)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    dist = intrinsics.dist if intrinsics.dist.size else np.zeros(5)
    out, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), intrinsics.K, dist)
    return out.reshape(-1, 2)


def in_image(pixels: FloatArray, intrinsics: CameraIntrinsics, margin_px: float = 0.0) -> NDArray[np.bool_]:
    """Which pixels (..., 2) lie inside the image, at least ``margin_px`` from its border -> (...) bool.

    Pixel centres run from 0 to W - 1 (and H - 1), so inside means m <= x <= W - 1 - m and likewise y.
    """
    pixels = np.asarray(pixels, dtype=np.float64)
    x, y = pixels[..., 0], pixels[..., 1]
    m = margin_px
    return (x >= m) & (x <= intrinsics.width - 1 - m) & (y >= m) & (y <= intrinsics.height - 1 - m)


def rays_from_normalized(uv: FloatArray) -> FloatArray:
    """Homogeneous rays (u, v, 1) from normalized coordinates: (M, 2) -> (M, 3)."""
    return np.column_stack([uv, np.ones(uv.shape[0])])
