"""The one place where pixels become normalized image coordinates, and its inverse.

Normalized image coordinates (u, v) are the OpenCV optical frame's x/z and y/z: the ray through a
pixel is (u, v, 1) in the camera frame (x right, y down, z forward). Both of ``CameraIntrinsics``'s models
are honoured: "pinhole" through ``cv2.undistortPoints``/``cv2.projectPoints``, "fisheye" through
``cv2.fisheye.undistortPoints``/``cv2.fisheye.projectPoints``.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray
from solver.observations import CameraIntrinsics

#: Undistortion's iterations: the default 5 of cv2.undistortPoints leave ~0.2 px at the corners of strongly
#: distorted images. cv2.fisheye.undistortPoints iterates Newton's method on theta until its step is below
#: the epsilon (OpenCV's default 10 iterations, 1e-8 rad); with these its round trip is at 1e-15.
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


def normalized_from_pixels(pixels: FloatArray, intrinsics: CameraIntrinsics) -> FloatArray:
    """Undistort and normalize pixel coordinates (cv2.undistortPoints, or cv2.fisheye.undistortPoints).

    Args:
        pixels: (M, 2) float64, pixels.
        intrinsics: the camera.

    Returns:
        (M, 2) float64: normalized image coordinates (x/z, y/z). For a fisheye, pixels beyond 90 degrees
        off the axis have no such coordinates (as pixels where a pinhole's distortion folds over, they come
        out meaningless).
    """
    pts = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    if intrinsics.is_fisheye:
        return cv2.fisheye.undistortPoints(pts, intrinsics.K, intrinsics.dist, None, np.eye(3), np.eye(3),
                                           UNDISTORT_CRITERIA).reshape(-1, 2)
    if not intrinsics.dist.size:
        return cv2.undistortPoints(pts, intrinsics.K, None).reshape(-1, 2)
    args = (pts, intrinsics.K, intrinsics.dist, np.eye(3), np.eye(3), UNDISTORT_CRITERIA)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        return cv2.undistortPointsIter(*args).reshape(-1, 2)
    return cv2.undistortPoints(pts, intrinsics.K, intrinsics.dist, None, np.eye(3), np.eye(3),
                               UNDISTORT_CRITERIA).reshape(-1, 2)


def pixels_from_camera_points(points_cam: FloatArray, intrinsics: CameraIntrinsics) -> FloatArray:
    """Project camera-frame points to distorted pixels (cv2.projectPoints, or cv2.fisheye.projectPoints).

    Args:
        points_cam: (M, 3) float64, metres, in the OpenCV optical frame; z > 0.
        intrinsics: the camera.

    Returns:
        (M, 2) float64, pixels.
    """
    pts = np.ascontiguousarray(points_cam, dtype=np.float64).reshape(-1, 3)
    if pts.shape[0] == 0:
        return np.zeros((0, 2))
    if intrinsics.is_fisheye:
        out, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), intrinsics.K,
                                           intrinsics.dist)
        return out.reshape(-1, 2)
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
