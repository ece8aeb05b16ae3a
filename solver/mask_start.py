"""A first pose from where the moving links changed the image: no tracks, no axis (ours).

On smooth castings a motion's tracks can all slide: on the as-shipped iiwa at 720p, benchmark pose 5 seed 0, the
tracker kept 17 tracks per motion and none stayed within 1 px of its surface point (median end error 5.3 px), so
neither front end gave an axis and no start existed for the outlines (``solver.outline_fusion``), whose adjustment
reaches the pose from several degrees and tens of millimetres off. What a sweep does show is where it changed the
image: the moving links' own pixels (their shading changes as they turn) and what they cover and uncover.

- ``change_mask``: the cells of the image where a motion's images (the outline stage's, evenly spaced over its
  sweep) differ from its first;
- the robot model says where the links that joint moves are drawn from a pose (``MovingSurface``: their surface
  points at each image's configuration, projected and rasterized on the same cells, ``drawn_cells``);
- ``mask_starts``: poses whose drawn cells cover the masks best (intersection over union summed over the motions,
  ``mask_iou``). Starts: PnP of the masks' centroids on the moving links' mean points (SQPnP on every motion, P3P on
  triples of motions: the centroid of a drawn region is not the image of the links' mean point, so these are rough),
  each scored by the IoU; the best few refined by Nelder-Mead on it (the camera turned about its centre and moved
  in units of the links' extent).

The masks are coarse (cells of ``ChangeMaskConfig.cells_across`` across the image; shadows and reflections change
pixels too): a start lands degrees and centimetres off. It is a start for the outlines' adjustment alone, which the
calibrator takes only on the outlines' own tests (``solver.pipeline.Calibrator``). Measured first on the 30
as-shipped iiwa 720p captures of ``docs/realistic-imaging.md`` (stop 63).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray, ImageArray, MaskArray
from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.frames import pose_errors, transform_from_rt
from solver.observations import CameraIntrinsics

__all__ = ["ChangeMask", "ChangeMaskConfig", "MaskStartConfig", "MaskView", "MovingSurface", "change_mask",
           "changed_pixels", "drawn_cells", "mask_iou", "mask_starts"]


@dataclass(frozen=True)
class ChangeMaskConfig:
    """Settings of ``change_mask``.

    Attributes:
        threshold_grey: a pixel changed where an image differs from the first by more than this; grey levels. The
            tracker's ``motion_threshold``: above the realistic camera's noise (sigma about 3 grey levels).
        open_px: side of the elliptical kernel that opens the changed pixels (removes speckle); px, 0 or 1: none.
        dilate_px: side of the one that then dilates them (fills a casting's uniform interior); px, 0 or 1: none.
        cells_across: the image is cut into square cells, this many across (a cell is width // cells_across px);
            a cell changed where more than half its pixels did.
    """

    threshold_grey: int = 15
    open_px: int = 3
    dilate_px: int = 7
    cells_across: int = 160

    def __post_init__(self) -> None:
        if not (0 <= self.threshold_grey < 255 and self.open_px >= 0 and self.dilate_px >= 0
                and self.cells_across >= 8):
            raise InvalidInputError("ChangeMaskConfig: need threshold_grey in 0..254, open_px and dilate_px >= 0, "
                                    f"cells_across >= 8; got {self}")


@dataclass(frozen=True)
class ChangeMask:
    """Where a motion changed the image, on square cells.

    Attributes:
        cells: (h, w) bool: cell (i, j) covers pixels [j * cell_px, (j + 1) * cell_px) x [i * cell_px, ...).
        cell_px: the cells' side, px.
    """

    cells: MaskArray
    cell_px: int

    def __post_init__(self) -> None:
        cells = np.asarray(self.cells, dtype=bool)
        if cells.ndim != 2 or cells.size == 0 or self.cell_px < 1:
            raise InvalidInputError(f"a change mask needs (h, w) cells and cell_px >= 1, got {cells.shape}, "
                                    f"{self.cell_px}")
        object.__setattr__(self, "cells", cells)

    def union(self, other: ChangeMask) -> ChangeMask:
        """The cells either mask marks (the same grid)."""
        if other.cells.shape != self.cells.shape or other.cell_px != self.cell_px:
            raise InvalidInputError("change masks on different grids cannot be joined")
        return ChangeMask(self.cells | other.cells, self.cell_px)


def _ellipse(size_px: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size_px, size_px))


def changed_pixels(greys: Sequence[ImageArray], threshold_grey: int, min_images: int = 1, open_px: int = 0,
                   dilate_px: int = 0) -> ImageArray:
    """(H, W) uint8: 255 where >= ``min_images`` of greys[1:] differ from greys[0] by more than ``threshold_grey``.

    The pixels then opened by an elliptical kernel of side ``open_px`` (speckle removed) and dilated by one of side
    ``dilate_px`` (0 or 1: neither). One meaning of "the sweep changed this pixel", shared by ``change_mask`` and the
    tracker's moving mask (``arc_env.robot.tracking.moving_mask``). The images are (H, W) uint8 of one shape, checked
    by the callers; ``min_images`` is capped at len(greys) - 1 and 255.
    """
    first = greys[0]
    count = np.zeros_like(first)  # images in which the pixel differs from the first (saturates at 255)
    for grey in greys[1:]:
        _, changed = cv2.threshold(cv2.absdiff(grey, first), threshold_grey, 1, cv2.THRESH_BINARY)
        cv2.add(count, changed, dst=count)
    least = max(1, min(min_images, len(greys) - 1, 255))
    _, mask = cv2.threshold(count, least - 1, 255, cv2.THRESH_BINARY)
    if open_px > 1:
        mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _ellipse(open_px))
    if dilate_px > 1:
        mask = cv2.dilate(mask, _ellipse(dilate_px))
    return mask


def change_mask(greys: Sequence[ImageArray], config: ChangeMaskConfig | None = None) -> ChangeMask:
    """The cells where any of a motion's images differs from its first one.

    Args:
        greys: K >= 2 images (H, W) uint8 grey of one motion, the first taken before the others.
        config: thresholds, kernels and cells; ``ChangeMaskConfig()`` if None.

    Raises:
        InvalidInputError: fewer than 2 images, images that are not (H, W) uint8 or differ in shape, an image
            smaller than the cells.
    """
    cfg = config or ChangeMaskConfig()
    images = [np.asarray(g) for g in greys]
    if len(images) < 2:
        raise InvalidInputError(f"a change mask needs at least 2 images of the motion, got {len(images)}")
    first = images[0]
    if first.ndim != 2 or first.dtype != np.uint8:
        raise InvalidInputError(f"change_mask takes (H, W) uint8 grey images, got {first.shape} {first.dtype}")
    if any(g.shape != first.shape or g.dtype != np.uint8 for g in images):
        raise InvalidInputError("change_mask: every image must be (H, W) uint8 of the first one's shape")
    height, width = first.shape
    cell = width // cfg.cells_across
    if cell < 1 or height < cell:
        raise InvalidInputError(f"a {width}x{height} image is too small for {cfg.cells_across} cells across")
    changed = changed_pixels(images, cfg.threshold_grey, 1, cfg.open_px, cfg.dilate_px)
    h, w = height // cell, width // cell
    share = cv2.resize((changed[:h * cell, :w * cell] > 0).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return ChangeMask(share > 0.5, cell)


@runtime_checkable
class MovingSurface(Protocol):
    """The robot's drawn surface: points on the links a joint moves, at a configuration."""

    def moving_points(self, q: FloatArray, joint: int) -> FloatArray:
        """(P, 3) float64, metres, base frame: points on the drawn surface of the links ``joint`` moves, at q (n,)."""
        ...


@dataclass(frozen=True)
class MaskView:
    """One motion as ``mask_starts`` sees it.

    Attributes:
        change: where the motion changed the image (``change_mask``).
        points: (K, P, 3) float64, metres, base frame: the moving links' surface points at each of the K
            configurations the mask's images were taken at.
    """

    change: ChangeMask
    points: FloatArray

    def __post_init__(self) -> None:
        points = np.asarray(self.points, dtype=np.float64)
        if points.ndim != 3 or points.shape[2] != 3 or points.shape[1] == 0 or not np.all(np.isfinite(points)):
            raise InvalidInputError(f"a mask view's points must be finite (K, P, 3), got {points.shape}")
        object.__setattr__(self, "points", points)


@dataclass(frozen=True)
class MaskStartConfig:
    """Settings of ``mask_starts`` (and of the calibrator's rescue from them).

    Attributes:
        min_motions: fewest motions with a change mask to search from.
        points_per_image: at most this many surface points per image, evenly strided (the mean point and the
            drawn cells); count.
        max_triples: P3P is run on at most this many triples of motions (all when fewer: 10 at five motions;
            else a seeded draw); count.
        refined: the best this many starts (by IoU) are refined ...
        steps: ... by Nelder-Mead rounds, each (rotation rad, move in units of the links' extent) its first
            simplex's steps ...
        evaluations: ... of at most this many IoU evaluations each.
        returned: ``mask_starts`` returns at most this many poses (the calibrator adjusts the outlines from each).
        distinct_rad, distinct_m: a refined start closer than both to a better one is dropped (two starts that
            converged to the same pose: seen on as-shipped iiwa 720p captures, the outlines adjusted twice alike).
    """

    min_motions: int = 3
    points_per_image: int = 1500
    max_triples: int = 20
    refined: int = 4
    steps: tuple[tuple[float, float], ...] = ((0.2, 0.1), (0.07, 0.03), (0.07, 0.03))
    evaluations: int = 600
    returned: int = 3
    distinct_rad: float = 0.01
    distinct_m: float = 0.01

    def __post_init__(self) -> None:
        if not (self.min_motions >= 3 and self.points_per_image >= 10 and self.max_triples >= 0
                and self.refined >= 1 and self.evaluations >= 10 and 1 <= self.returned <= self.refined
                and len(self.steps) >= 1 and all(len(s) == 2 and s[0] > 0 and s[1] > 0 for s in self.steps)
                and self.distinct_rad >= 0 and self.distinct_m >= 0):
            raise InvalidInputError(f"MaskStartConfig: invalid settings {self}")


def drawn_cells(points: FloatArray, T_camera_base: FloatArray, intrinsics: CameraIntrinsics, shape: tuple[int, int],
                cell_px: int) -> MaskArray:
    """(h, w) bool: the cells the points fall in from T_camera_base, grown by one cell.

    ``points``: (..., 3) float64, metres, base frame; projected through the pinhole K (the lens's distortion is left
    out: the cells are coarser); points less than 1 mm in front of the camera are left out.
    """
    cam = np.asarray(points, dtype=np.float64).reshape(-1, 3) @ T_camera_base[:3, :3].T + T_camera_base[:3, 3]
    front = cam[:, 2] > 1e-3
    cam = cam[front]
    K = intrinsics.K
    u = (K[0, 0] * cam[:, 0] + K[0, 1] * cam[:, 1]) / cam[:, 2] + K[0, 2]
    v = K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]
    h, w = shape
    with np.errstate(invalid="ignore"):
        gx, gy = np.floor(u / cell_px), np.floor(v / cell_px)
    inside = (gx >= 0) & (gx < w) & (gy >= 0) & (gy < h)
    cells = np.zeros((h, w), np.uint8)
    cells[gy[inside].astype(np.intp), gx[inside].astype(np.intp)] = 1
    return cv2.dilate(cells, np.ones((3, 3), np.uint8)) > 0


def mask_iou(views: Sequence[MaskView], T_camera_base: FloatArray, intrinsics: CameraIntrinsics) -> float:
    """The cells both drawn and changed over the cells either, summed over the motions; in [0, 1]."""
    both = either = 0
    for view in views:
        drawn = drawn_cells(view.points, T_camera_base, intrinsics, view.change.cells.shape, view.change.cell_px)
        both += int(np.count_nonzero(drawn & view.change.cells))
        either += int(np.count_nonzero(drawn | view.change.cells))
    return both / either if either else 0.0


def _pnp_starts(views: Sequence[MaskView], intrinsics: CameraIntrinsics, max_triples: int) -> list[FloatArray]:
    """Poses putting the moving links' mean points on their masks' centroids: SQPnP on all, P3P on triples."""
    means = np.array([v.points.reshape(-1, 3).mean(axis=0) for v in views])
    centroids = []
    for v in views:
        rows, cols = np.nonzero(v.change.cells)
        centroids.append([(cols.mean() + 0.5) * v.change.cell_px, (rows.mean() + 0.5) * v.change.cell_px])
    pixels = np.asarray(centroids, dtype=np.float64)
    K = np.asarray(intrinsics.K, dtype=np.float64)
    found: list[tuple[FloatArray, FloatArray]] = []
    try:
        ok, rvec, tvec = cv2.solvePnP(means, pixels, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if ok:
            found.append((rvec, tvec))
    except cv2.error:
        pass
    triples = list(itertools.combinations(range(len(views)), 3))
    if len(triples) > max_triples:
        pick = np.random.default_rng(0).choice(len(triples), max_triples, replace=False)
        triples = [triples[i] for i in sorted(pick)]
    for triple in triples:
        idx = list(triple)
        try:
            n, rvecs, tvecs = cv2.solveP3P(means[idx], pixels[idx], K, None, flags=cv2.SOLVEPNP_P3P)
        except cv2.error:
            continue
        found.extend(zip(rvecs[:n], tvecs[:n], strict=True))
    starts = []
    for rvec, tvec in found:
        t = np.asarray(tvec, dtype=np.float64).reshape(3)
        R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3))[0]
        if np.all(np.isfinite(t)) and np.all(np.isfinite(R)):
            starts.append(transform_from_rt(R, t))
    return starts


def _refined(views: Sequence[MaskView], intrinsics: CameraIntrinsics, T: FloatArray, extent: float,
             steps: tuple[float, float], evaluations: int) -> tuple[float, FloatArray]:
    """Nelder-Mead on the IoU from T: the camera turned about its centre and its centre moved (units of extent)."""
    R0, centre0 = T[:3, :3], -T[:3, :3].T @ T[:3, 3]

    def pose(x: FloatArray) -> FloatArray:
        R = Rotation.from_rotvec(x[:3]).as_matrix() @ R0
        return transform_from_rt(R, -R @ (centre0 + x[3:] * extent))

    simplex = np.vstack([np.zeros(6)] + [np.eye(6)[i] * steps[0 if i < 3 else 1] for i in range(6)])
    result = minimize(lambda x: -mask_iou(views, pose(x), intrinsics), np.zeros(6), method="Nelder-Mead",
                      options={"initial_simplex": simplex, "maxfev": evaluations, "xatol": 1e-3, "fatol": 1e-4})
    return -float(result.fun), pose(result.x)


def mask_starts(views: Sequence[MaskView], intrinsics: CameraIntrinsics,
                config: MaskStartConfig | None = None) -> list[tuple[float, FloatArray]]:
    """Camera poses that draw the moving links where the motions changed the image, best first.

    Args:
        views: the motions (their change masks and their moving links' points).
        intrinsics: the camera of the masks' images.
        config: ``MaskStartConfig()`` if None.

    Returns:
        At most ``config.returned`` (IoU, T_camera_base (4, 4) float64), by falling IoU: refined starts, each at
        least ``distinct_rad`` or ``distinct_m`` from every better one, the same for the same views.

    Raises:
        InsufficientMotionsError: fewer than ``config.min_motions`` views with a changed cell, or no PnP start.
    """
    cfg = config or MaskStartConfig()
    used = [v for v in views if v.change.cells.any()]
    if len(used) < cfg.min_motions:
        raise InsufficientMotionsError(f"{len(used)} motion(s) changed the image; the mask start needs "
                                       f"{cfg.min_motions}")
    thinned = [MaskView(v.change, v.points[:, ::max(1, v.points.shape[1] // cfg.points_per_image)]) for v in used]
    starts = _pnp_starts(thinned, intrinsics, cfg.max_triples)
    if not starts:
        raise InsufficientMotionsError("no camera pose puts the moving links on their change masks (PnP failed)")
    everything = np.concatenate([v.points.reshape(-1, 3) for v in thinned])
    extent = float(np.linalg.norm(everything.max(axis=0) - everything.min(axis=0)))
    ranked = sorted(starts, key=lambda T: -mask_iou(thinned, T, intrinsics))[:cfg.refined]
    results = []
    for T in ranked:
        iou = 0.0
        for steps in cfg.steps:
            iou, T = _refined(thinned, intrinsics, T, extent, steps, cfg.evaluations)
        results.append((iou, T))
    results.sort(key=lambda r: -r[0])
    kept: list[tuple[float, FloatArray]] = []
    for iou, T in results:
        if all(np.any(np.array(pose_errors(T, other)) >= (cfg.distinct_rad, cfg.distinct_m)) for _, other in kept):
            kept.append((iou, T))
    return kept[:cfg.returned]
