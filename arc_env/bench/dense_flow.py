"""Dense optical flow as tracks: OpenCV's DIS flow chained through a sweep, a benchmark's alternative to corners.

The realism issue names dense flow "a fair tool where sparse corners are too few": on smooth castings the corner
tracker keeps a few dozen tracks per motion. Here every point of a regular grid inside the sweep's moving region
(``arc_env.robot.tracking.moving_mask``) in the first frame is carried from frame to frame by DIS flow
(``cv2.DISOpticalFlow``, sampled bilinearly at the point), with the flow back from the next frame as a
forward-backward check: a point whose round trip misses by more than ``DenseFlowConfig.fb_max_px`` ends its track
there. Tracks long enough and moving far enough are kept, like the corner tracker's.

Where the surface has no texture the flow is interpolated from what is around it (the variational refinement:
shading, highlights, the silhouette against the background), so points there need not follow the surface; the
corner tracker's checks (patch fit, dissimilarity) do not apply to them. ``scripts/bench_tracking_truth.py
--settings dense-flow,default`` scores them against the simulator's surface points. Benchmark-only: no product
path uses it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from arc_env.robot.tracking import TrackerConfig, _grey_frames, _moving_mask_u8
from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError
from solver.observations import KeypointTrack

__all__ = ["DenseFlowConfig", "dense_flow_tracks"]

#: OpenCV's DIS presets by name.
PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
           "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


@dataclass(frozen=True)
class DenseFlowConfig:
    """Settings of ``dense_flow_tracks``.

    Attributes:
        grid_px: spacing of the seeded points in the first frame; pixels, >= 1.
        fb_max_px: a point carried to the next frame and back by the flows must land within this of where it
            was, or its track ends; pixels, > 0.
        min_eigenvalue: seed only grid points whose smaller structure-tensor eigenvalue
            (``cv2.cornerMinEigenVal``, 5 px block) is at least this (0: every point in the moving region).
        min_track_frames: tracks with fewer frames are dropped; frames, >= 2.
        min_displacement_px: tracks whose last point lies within this of their first are dropped; pixels.
        preset: the DIS preset, one of ``PRESETS``.
        margin_px: the flow is computed in the moving region's bounding box grown by this; pixels.
    """

    grid_px: int = 8
    fb_max_px: float = 0.5
    min_eigenvalue: float = 0.0
    min_track_frames: int = 6
    min_displacement_px: float = 3.0
    preset: str = "medium"
    margin_px: int = 16

    def __post_init__(self) -> None:
        checks = [(self.grid_px >= 1, "grid_px must be >= 1"), (self.fb_max_px > 0, "fb_max_px must be > 0"),
                  (self.min_eigenvalue >= 0, "min_eigenvalue must be >= 0"),
                  (self.min_track_frames >= 2, "min_track_frames must be >= 2"),
                  (self.min_displacement_px >= 0, "min_displacement_px must be >= 0"),
                  (self.preset in PRESETS, f"preset must be one of {sorted(PRESETS)}"),
                  (self.margin_px >= 0, "margin_px must be >= 0")]
        for ok, message in checks:
            if not ok:
                raise InvalidInputError(f"DenseFlowConfig: {message}, got {self}")


def dense_flow_tracks(frames: Sequence[ImageArray], delta: FloatArray,
                      config: DenseFlowConfig | None = None) -> list[KeypointTrack]:
    """Grid points of the sweep's moving region carried through it by DIS flow (module doc).

    Args:
        frames: F >= 2 images of one sweep, each (H, W) uint8 grey or (H, W, 3) uint8 RGB.
        delta: (F,) float64, rad: the joint's offset from its start in each frame.
        config: settings; ``DenseFlowConfig()`` if None.

    Returns:
        The kept tracks (pixels (M, 2) float64 over the first M frames, delta (M,) rad); none when nothing moves.

    Raises:
        InvalidInputError: fewer than 2 frames, frames of different shapes or not uint8, a delta that is not (F,)
            or not finite.
    """
    config = config or DenseFlowConfig()
    delta = np.asarray(delta, dtype=np.float64).reshape(-1)
    greys = _grey_frames(frames)  # validated, grey, as the corner tracker takes them
    if delta.shape != (len(frames),) or not np.all(np.isfinite(delta)):
        raise InvalidInputError(f"delta must be ({len(frames)},) finite, got shape {delta.shape}")
    mask = _moving_mask_u8(greys, TrackerConfig()) > 0  # ``moving_mask`` of the same greys
    if not mask.any():
        return []
    x, y, w, h = cv2.boundingRect(mask.astype(np.uint8))
    x0, y0 = max(0, x - config.margin_px), max(0, y - config.margin_px)
    x1, y1 = min(mask.shape[1], x + w + config.margin_px), min(mask.shape[0], y + h + config.margin_px)
    crops = [np.ascontiguousarray(g[y0:y1, x0:x1]) for g in greys]
    ys, xs = np.mgrid[0:y1 - y0:config.grid_px, 0:x1 - x0:config.grid_px]
    seeds = np.stack([xs.ravel(), ys.ravel()], axis=1)
    keep = mask[seeds[:, 1] + y0, seeds[:, 0] + x0]
    if config.min_eigenvalue > 0:
        eigen = cv2.cornerMinEigenVal(crops[0], 5)
        keep &= eigen[seeds[:, 1], seeds[:, 0]] >= config.min_eigenvalue
    points = seeds[keep].astype(np.float32)
    if not len(points):
        return []
    flow = cv2.DISOpticalFlow_create(PRESETS[config.preset])
    path = np.full((len(frames), len(points), 2), np.nan)  # crop pixels; NaN once a track has ended
    path[0] = points
    alive = np.arange(len(points))
    limit = np.array([crops[0].shape[1] - 1, crops[0].shape[0] - 1], np.float32)
    for k in range(len(crops) - 1):
        if not len(alive):
            break
        forward = flow.calc(crops[k], crops[k + 1], None)
        backward = flow.calc(crops[k + 1], crops[k], None)
        here = path[k, alive].astype(np.float32)
        there = here + _sample(forward, here)
        back = there + _sample(backward, there)
        ok = (np.linalg.norm(back - here, axis=1) <= config.fb_max_px) & np.all((there >= 0) & (there <= limit), axis=1)
        alive = alive[ok]
        path[k + 1, alive] = there[ok]
    tracks = []
    for i in range(len(points)):
        n = int(np.sum(np.isfinite(path[:, i, 0])))
        pixels = path[:n, i] + (x0, y0)
        if n >= config.min_track_frames and np.linalg.norm(pixels[-1] - pixels[0]) > config.min_displacement_px:
            tracks.append(KeypointTrack(pixels, delta[:n].copy()))
    return tracks


def _sample(flow: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) float32: the flow field (H, W, 2) float32 at the points (N, 2) float32 px, bilinear."""
    return cv2.remap(flow, points[:, None, 0], points[:, None, 1], cv2.INTER_LINEAR).reshape(-1, 2)
