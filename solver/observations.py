"""Observations the solver consumes: camera intrinsics, keypoint tracks and exploratory motions.

Joint indices are 0-based in code (the paper's J = 1 is ``joint=0``). Angles are radians, lengths
metres, pixels are (x right, y down) with the origin at the centre of the top-left pixel (OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver.arrays import FloatArray
from solver.errors import InvalidInputError

#: Largest image side accepted, px (16K sensors exist; beyond this a size is a corrupt file).
MAX_IMAGE_SIDE = 16384
#: Focal lengths must lie in this range of multiples of the image width (a 0.05x focal length sees
#: almost 180 degrees; 100x is a telescope): outside it the camera file is wrong, not the camera.
FOCAL_RANGE_WIDTHS = (0.05, 100.0)
#: Largest |coefficient| of OpenCV's distortion model accepted (real lenses: |k| below ~10, rational
#: models up to a few hundred).
MAX_DISTORTION_COEFFICIENT = 1000.0
#: Camera models (``CameraIntrinsics.model``) with the numbers of distortion coefficients each takes:
#: "pinhole" is OpenCV's pinhole camera with its radial-tangential distortion (k1, k2, p1, p2[, k3, ...];
#: ``cv2.projectPoints``); "fisheye" is OpenCV's fisheye (equidistant) model, r = f * theta_d with
#: theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) (``cv2.fisheye``).
CAMERA_MODELS: dict[str, tuple[int, ...]] = {"pinhole": (0, 4, 5, 8, 12, 14), "fisheye": (4,)}
#: Largest |pixel coordinate| of a keypoint, px: far beyond any image; larger values are corrupt data.
MAX_PIXEL_MAGNITUDE = 1e6


def _finite(name: str, array: FloatArray) -> None:
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(f"{name} contains NaN or infinite values")


def _check_camera(K: FloatArray, dist: FloatArray, width: object, height: object) -> None:
    """Magnitude checks of intrinsics (messages name the field, as K[row][column] or dist[i])."""
    for name, side in (("width", width), ("height", height)):
        if isinstance(side, bool) or not isinstance(side, int | np.integer) or not 1 <= side <= MAX_IMAGE_SIDE:
            raise InvalidInputError(f"{name} must be an integer in 1..{MAX_IMAGE_SIDE}, got {side!r}")
    lo, hi = FOCAL_RANGE_WIDTHS
    for field_name, value in (("K[0][0] (fx)", K[0, 0]), ("K[1][1] (fy)", K[1, 1])):
        if not lo * width <= value <= hi * width:
            raise InvalidInputError(f"{field_name} = {value:g} px is not a focal length for a {width} px wide image "
                                    f"(expected {lo * width:g}..{hi * width:g} px)")
    for field_name, value, side in (("K[0][2] (cx)", K[0, 2], width), ("K[1][2] (cy)", K[1, 2], height)):
        if not -side <= value <= 2 * side:
            raise InvalidInputError(f"{field_name} = {value:g} px: the principal point must lie within the image "
                                    f"give or take its size ({-side}..{2 * side} px)")
    if abs(K[0, 1]) > hi * width or K[1, 0] != 0:
        raise InvalidInputError(f"K[0][1] (skew) = {K[0, 1]:g} and K[1][0] = {K[1, 0]:g}: expected a small skew "
                                "and K[1][0] = 0")
    big = np.nonzero(np.abs(dist) > MAX_DISTORTION_COEFFICIENT)[0]
    if big.size:
        k = int(big[0])
        raise InvalidInputError(f"dist[{k}] = {dist[k]:g} is not a distortion coefficient "
                                f"(|value| <= {MAX_DISTORTION_COEFFICIENT:g})")


@dataclass(frozen=True)
class CameraIntrinsics:
    """A camera: K, its lens distortion under one of OpenCV's two models, and the image size.

    Attributes:
        K: (3, 3) float64, pixels: the intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]; fx and fy
            within ``FOCAL_RANGE_WIDTHS`` times the width, (cx, cy) within the image give or take its size.
        dist: (k,) float64: the distortion coefficients of ``model``; every |coefficient| at most
            ``MAX_DISTORTION_COEFFICIENT``. Pinhole: OpenCV's (k1, k2, p1, p2[, k3, ...]), empty means none.
            Fisheye: exactly (k1, k2, k3, k4); zeros are the ideal equidistant lens (r = f * theta), not none.
        width: image width in pixels, 1..``MAX_IMAGE_SIDE``.
        height: image height in pixels, 1..``MAX_IMAGE_SIDE``.
        model: "pinhole" or "fisheye" (``CAMERA_MODELS``). OpenCV's fisheye functions ignore K's skew, so
            a fisheye K must have none.
    """

    K: FloatArray
    dist: FloatArray = field(default_factory=lambda: np.zeros(0))
    width: int = 1920
    height: int = 1080
    model: str = "pinhole"

    def __post_init__(self) -> None:
        if self.model not in CAMERA_MODELS:
            raise InvalidInputError(f"camera model {self.model!r} is not one of {sorted(CAMERA_MODELS)}")
        K = np.asarray(self.K, dtype=np.float64)
        dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if K.shape != (3, 3):
            raise InvalidInputError(f"K must be 3x3, got shape {K.shape}")
        _finite("K", K)
        _finite("dist", dist)
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
            raise InvalidInputError(f"K must have positive focal lengths and last row [0, 0, 1], got {K}")
        if self.model == "fisheye":
            if dist.size != 4:
                raise InvalidInputError(f"the fisheye model takes exactly 4 distortion coefficients (k1, k2, k3, k4), "
                                        f"got {dist.size}")
            if K[0, 1] != 0:
                raise InvalidInputError(f"K[0][1] (skew) = {K[0, 1]:g}: the fisheye model (OpenCV's cv2.fisheye) "
                                        "takes a K without skew")
        elif dist.size not in CAMERA_MODELS["pinhole"]:
            raise InvalidInputError(f"dist must have 0, 4, 5, 8, 12 or 14 coefficients, got {dist.size}")
        _check_camera(K, dist, self.width, self.height)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)

    @property
    def is_fisheye(self) -> bool:
        """Whether the camera follows OpenCV's fisheye model."""
        return self.model == "fisheye"

    @property
    def has_distortion(self) -> bool:
        """Whether pixels differ from the distortion-free camera's (a fisheye lens always does)."""
        return self.is_fisheye or bool(np.any(self.dist))

    @property
    def focal(self) -> FloatArray:
        """(2,) float64, pixels: (fx, fy)."""
        return np.array([self.K[0, 0], self.K[1, 1]])

    @classmethod
    def from_fov(cls, fx: float, width: int, height: int, fy: float | None = None) -> CameraIntrinsics:
        """A distortion-free camera with the principal point at the image centre."""
        fy = fx if fy is None else fy
        K = np.array([[fx, 0.0, (width - 1) / 2], [0.0, fy, (height - 1) / 2], [0.0, 0.0, 1.0]])
        return cls(K=K, width=width, height=height)


@dataclass(frozen=True)
class KeypointTrack:
    """One keypoint followed through frames of a motion (in frame order; a track may skip frames).

    Attributes:
        pixels: (M, 2) float64, pixels: the keypoint's image position in each frame (finite, within
            ``MAX_PIXEL_MAGNITUDE``).
        delta: (M,) float64, radians: how far the moving joint had turned from its start value
            at each of those frames (the paper's delta_{i,j,k}).
        velocity: (M,) float64, rad/s: the moving joint's velocity at each of those frames (finite),
            or None when unknown. The bundle adjustment uses it to estimate a time offset tau between
            the joint clock and the camera clock: the turn at a frame is delta + velocity * tau
            (``solver.refinement``).
    """

    pixels: FloatArray
    delta: FloatArray
    velocity: FloatArray | None = None

    def __post_init__(self) -> None:
        pixels = np.asarray(self.pixels, dtype=np.float64)
        delta = np.asarray(self.delta, dtype=np.float64).reshape(-1)
        if pixels.ndim != 2 or pixels.shape[1] != 2:
            raise InvalidInputError(f"track pixels must be (M, 2), got shape {pixels.shape}")
        if delta.shape[0] != pixels.shape[0]:
            raise InvalidInputError(
                f"track has {pixels.shape[0]} pixel rows but {delta.shape[0]} delta values"
            )
        _finite("track pixels", pixels)
        _finite("track delta", delta)
        if self.velocity is not None:
            velocity = np.asarray(self.velocity, dtype=np.float64).reshape(-1)
            if velocity.shape[0] != pixels.shape[0]:
                raise InvalidInputError(
                    f"track has {pixels.shape[0]} pixel rows but {velocity.shape[0]} velocity values"
                )
            _finite("track velocity", velocity)
            object.__setattr__(self, "velocity", velocity)
        if pixels.size and np.max(np.abs(pixels)) > MAX_PIXEL_MAGNITUDE:
            raise InvalidInputError(f"track pixels reach {np.max(np.abs(pixels)):g} px: beyond any image "
                                    f"(|pixel| <= {MAX_PIXEL_MAGNITUDE:g})")
        object.__setattr__(self, "pixels", pixels)
        object.__setattr__(self, "delta", delta)

    def __len__(self) -> int:
        return int(self.pixels.shape[0])


@dataclass(frozen=True)
class MotionObservation:
    """What one exploratory motion U = (Q, J, Delta) produced.

    Attributes:
        q_start: (N,) float64, radians: the start configuration Q.
        joint: index of the joint that turned (0-based; an integer, never truncated from a float).
        tracks: the keypoint tracks on the moving links.
    """

    q_start: FloatArray
    joint: int
    tracks: tuple[KeypointTrack, ...]

    def __post_init__(self) -> None:
        q = np.asarray(self.q_start, dtype=np.float64).reshape(-1)
        _finite("q_start", q)
        if isinstance(self.joint, bool) or not isinstance(self.joint, int | np.integer):
            raise InvalidInputError(f"joint must be an integer index, got {self.joint!r}")
        if not 0 <= int(self.joint) < q.size:
            raise InvalidInputError(
                f"joint index {self.joint} out of range for a {q.size}-joint configuration "
                f"(valid: 0..{q.size - 1})"
            )
        object.__setattr__(self, "q_start", q)
        object.__setattr__(self, "joint", int(self.joint))
        object.__setattr__(self, "tracks", tuple(self.tracks))

    @property
    def delta_span(self) -> float:
        """Largest |delta| reached by any track, radians."""
        if not self.tracks:
            return 0.0
        return float(max(np.max(np.abs(t.delta)) for t in self.tracks))
