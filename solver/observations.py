"""Observations the solver consumes: camera intrinsics, keypoint tracks and exploratory motions.

Joint indices are 0-based in code (the paper's J = 1 is ``joint=0``). Angles are radians, lengths
metres, pixels are (x right, y down) with the origin at the centre of the top-left pixel (OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from solver.arrays import FloatArray
from solver.errors import InvalidInputError


def _finite(name: str, array: FloatArray) -> None:
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(f"{name} contains NaN or infinite values")


@dataclass(frozen=True)
class CameraIntrinsics:
    """A pinhole camera with OpenCV distortion.

    Attributes:
        K: (3, 3) float64, pixels: the intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]].
        dist: (k,) float64: OpenCV distortion (k1, k2, p1, p2[, k3, ...]); empty means none.
        width: image width in pixels.
        height: image height in pixels.
    """

    K: FloatArray
    dist: FloatArray = field(default_factory=lambda: np.zeros(0))
    width: int = 1920
    height: int = 1080

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        dist = np.asarray(self.dist, dtype=np.float64).reshape(-1)
        if K.shape != (3, 3):
            raise InvalidInputError(f"K must be 3x3, got shape {K.shape}")
        _finite("K", K)
        _finite("dist", dist)
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
            raise InvalidInputError(f"K must have positive focal lengths and last row [0, 0, 1], got {K}")
        if dist.size not in (0, 4, 5, 8, 12, 14):
            raise InvalidInputError(f"dist must have 0, 4, 5, 8, 12 or 14 coefficients, got {dist.size}")
        if self.width <= 0 or self.height <= 0:
            raise InvalidInputError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)

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
    """One keypoint followed through consecutive frames of a motion.

    Attributes:
        pixels: (M, 2) float64, pixels: the keypoint's image position in each frame.
        delta: (M,) float64, radians: how far the moving joint had turned from its start value
            at each of those frames (the paper's delta_{i,j,k}).
    """

    pixels: FloatArray
    delta: FloatArray

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
        object.__setattr__(self, "pixels", pixels)
        object.__setattr__(self, "delta", delta)

    def __len__(self) -> int:
        return int(self.pixels.shape[0])


@dataclass(frozen=True)
class MotionObservation:
    """What one exploratory motion U = (Q, J, Delta) produced.

    Attributes:
        q_start: (N,) float64, radians: the start configuration Q.
        joint: index of the joint that turned (0-based).
        tracks: the keypoint tracks on the moving links.
    """

    q_start: FloatArray
    joint: int
    tracks: tuple[KeypointTrack, ...]

    def __post_init__(self) -> None:
        q = np.asarray(self.q_start, dtype=np.float64).reshape(-1)
        _finite("q_start", q)
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
