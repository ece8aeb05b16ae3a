"""Simulated lens distortion: pinhole renders resampled into the images of a camera with OpenCV distortion."""

from __future__ import annotations

import cv2
import numpy as np

from solver.arrays import FloatArray, ImageArray
from solver.camera import normalized_from_pixels
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics


class Distorter:
    """Turns pinhole renders into images of a camera with OpenCV distortion.

    The simulator renders only symmetric pinhole cameras. For a target camera (K, dist) this picks a
    pinhole camera ``pinhole`` (same principal point, a focal length small enough that every pixel of
    the distorted image maps inside the render) and a per-pixel map: the distorted image's pixel p
    shows the render at ``pinhole.K @ undistort(p)`` (cv2.undistortPoints, the inverse of what
    initUndistortRectifyMap builds), resampled with cv2.remap.

    Args:
        target: the camera to simulate (any K and distortion).
    """

    def __init__(self, target: CameraIntrinsics):
        self.target = target
        w, h = target.width, target.height
        xs, ys = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        grid = np.column_stack([xs.ravel(), ys.ravel()])

        uv = normalized_from_pixels(grid, target)
        half = np.array([(w - 1) / 2, (h - 1) / 2])
        reach = np.max(np.abs(uv), axis=0)  # largest |normalized coordinate| per axis
        fx = float(min(target.K[0, 0], target.K[1, 1], *((half - 0.5) / reach)))  # half a pixel inside
        self.pinhole = CameraIntrinsics.from_fov(fx, w, h)
        K = self.pinhole.K
        self.map_x = (K[0, 0] * uv[:, 0] + K[0, 2]).reshape(h, w).astype(np.float32)
        self.map_y = (K[1, 1] * uv[:, 1] + K[1, 2]).reshape(h, w).astype(np.float32)

    def __call__(self, image: ImageArray) -> ImageArray:
        """The target camera's image (H, W, 3) uint8 from a render (H, W, 3) uint8 by ``self.pinhole``."""
        return cv2.remap(image, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def parse_dist(text: str) -> FloatArray:
    """'k1,k2,p1,p2[,k3...]' (commas or spaces) -> (k,) float64; InvalidInputError when it is not."""
    try:
        values = np.array([float(v) for v in text.replace(",", " ").split()])
    except ValueError as exc:
        raise InvalidInputError(f"--dist must be numbers 'k1,k2,p1,p2[,k3]', got {text!r}") from exc
    if values.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(values)):
        raise InvalidInputError(f"--dist needs 4, 5, 8, 12 or 14 finite coefficients, got {text!r}")
    return values


