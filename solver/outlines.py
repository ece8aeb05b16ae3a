"""The camera pose from the robot's outlines (ours): its model's occluding contours against the image's edges.

Tracks are points on the robot's surface; on smooth castings there are few, and their depth is weak. The
robot's outline needs no texture: wherever a link occludes what lies behind it (the floor, another link), the
image has an edge, and the robot's model, posed by its joint readings and seen from a camera pose
``T_camera_base``, says where. So the pose that puts the model's occluding contours on the image's edges is a
measurement of ``T_camera_base`` from every frame, of the links' sizes as much as of their positions.

Two inputs per image: its ``ImageEdges`` (Canny edges refined to sub-pixel along the intensity gradient,
``image_edges``), and a ``ContourModel``, a callable that gives, for a camera pose, the model's contour
points in the base frame with the direction, in the image, from the occluding surface towards what it hides
(``ContourPoints``; the robot side renders it from the robot's meshes). ``fit_outline_pose`` alternates: the
model's contour at the current pose; each contour point paired with the nearest image edge whose normal is
within ``OutlineConfig.max_normal_angle_deg`` of the outward direction; the pose that minimises the pairs'
point-to-line distances (Cauchy loss), re-paired ``OutlineConfig.associations`` times; then the contour again
from the new pose, ``OutlineConfig.renders`` times in all.

Measured on rendered realistic images (``docs/realistic-imaging.md``): the fit's error is a bias along the
optical axis of about a millimetre at 1080p, the edges of shaded castings lying a fraction of a pixel inside
the true outline; the rotation is within a few 1e-4 rad.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from solver.arrays import FloatArray, ImageArray
from solver.camera import pixels_from_camera_points
from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.frames import check_transform, perturb
from solver.observations import CameraIntrinsics

__all__ = ["ContourModel", "ContourPoints", "EdgePairs", "ImageEdges", "OutlineConfig", "OutlineFit",
           "contour_from_depth", "fit_outline_pose", "image_edges", "outline_residuals",
           "outline_residuals_and_jacobian", "pair_contour_points", "project_base_points"]


@dataclass(frozen=True)
class ImageEdges:
    """Sub-pixel edge points of one image (``image_edges``).

    Attributes:
        points: (E, 2) float64, pixels: edge positions.
        normals: (E, 2) float64: unit intensity-gradient directions there (dark towards bright).
        strengths: (E,) float64, grey levels per pixel: the largest difference of neighbouring samples across each
            edge (its contrast; ``image_edges``), or None where the edges were made otherwise.
    """

    points: FloatArray
    normals: FloatArray
    strengths: FloatArray | None = None
    _tree: cKDTree = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        points = np.asarray(self.points, dtype=np.float64).reshape(-1, 2)
        normals = np.asarray(self.normals, dtype=np.float64).reshape(-1, 2)
        if points.shape != normals.shape or not (np.all(np.isfinite(points)) and np.all(np.isfinite(normals))):
            raise InvalidInputError("edge points and normals must be finite (E, 2) arrays of one length")
        object.__setattr__(self, "points", points)
        object.__setattr__(self, "normals", normals)
        if self.strengths is not None:
            strengths = np.asarray(self.strengths, dtype=np.float64).reshape(-1)
            if len(strengths) != len(points) or not np.all(np.isfinite(strengths)):
                raise InvalidInputError("edge strengths must be a finite (E,) array of the points' length")
            object.__setattr__(self, "strengths", strengths)
        # unbalanced, uncompacted: built in half the time, queried as fast for a contour's few thousand points
        object.__setattr__(self, "_tree", cKDTree(points, balanced_tree=False, compact_nodes=False))

    def nearest(self, pixels: FloatArray, max_px: float) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Each pixel's (N, 2) nearest edge point: (N,) indices and (N,) whether one is within ``max_px``."""
        if len(self.points) == 0:
            return np.zeros(len(pixels), np.int64), np.zeros(len(pixels), bool)
        dist, idx = self._tree.query(pixels, distance_upper_bound=max_px)
        found = np.isfinite(dist)
        return np.where(found, idx, 0).astype(np.int64), found

    def matching(self, pixels: FloatArray, outward: FloatArray, max_px: float, max_angle_deg: float
                 ) -> tuple[NDArray[np.int64], NDArray[np.bool_], FloatArray]:
        """Each pixel's (N, 2) nearest edge point, kept if within ``max_px`` and of a matching direction.

        Matching: the edge's normal within ``max_angle_deg`` of the pixel's outward direction (N, 2), either sign.
        Returns (N,) indices, (N,) whether each matches, and (N,) the cosine between normal and outward direction
        (positive where the image is brighter outside).
        """
        idx, found = self.nearest(pixels, max_px)
        if len(self.points) == 0:  # no edge: nothing matches
            return idx, found, np.zeros(len(idx))
        along = np.sum(self.normals[idx] * outward, axis=1)
        return idx, found & (np.abs(along) >= np.cos(np.radians(max_angle_deg))), along


def image_edges(grey: ImageArray, low: float = 15.0, high: float = 40.0, sigma_px: float = 0.0) -> ImageEdges:
    """Canny's edges of a grey image, each moved to sub-pixel along its gradient.

    The image is sampled along each edge pixel's gradient direction (3x3 Sobel) at -2..2 px (bilinear); the edge
    lies where the difference of neighbouring samples peaks (the parabola through the largest of the two
    differences half a pixel either side of the pixel and its neighbours): at most a pixel away. The differences
    of neighbours, not Sobel's magnitude, whose three-pixel reach lets the shading of a surface next to its
    outline (a casting darkens where it turns away from the light) pull the peak towards the brighter side:
    measured at the true pose on realistic Panda, iiwa and xArm 6 frames, the contour-to-edge offset was
    +0.17..+0.48 px (brighter background) / -0.10..-0.39 px (brighter robot) with Sobel's peak, and
    +0.07..+0.30 / -0.08..-0.24 px with the differences' (their scatter 25-50 % smaller; ``docs/realistic-imaging.md``).
    That largest difference is each edge's strength (``ImageEdges.strengths``, grey levels per pixel).

    Args:
        grey: (H, W) uint8 image.
        low: Canny's lower hysteresis threshold on the Sobel gradient's L1 norm.
        high: its upper threshold.
        sigma_px: Gaussian smoothing first, pixels (0: none). Smoothing moves the edges of shaded surfaces
            inwards (measured: 1.2 px gave twice the 0's depth bias), so none by default.
    """
    grey = np.asarray(grey)
    if grey.ndim != 2 or grey.dtype != np.uint8:
        raise InvalidInputError(f"image_edges needs a (H, W) uint8 image, got {grey.dtype} {grey.shape}")
    if not (0.0 <= low <= high) or sigma_px < 0:
        raise InvalidInputError(f"need 0 <= low <= high and sigma_px >= 0, got {low}, {high}, {sigma_px}")
    smooth = cv2.GaussianBlur(grey, (0, 0), sigma_px) if sigma_px > 0 else grey
    edges = cv2.Canny(smooth, low, high)
    found = cv2.findNonZero(edges)  # (E, 1, 2) (u, v), row by row; None: no edge
    uv = np.zeros((0, 2), np.intp) if found is None else found.reshape(-1, 2).astype(np.intp)
    u, v = uv[:, 0], uv[:, 1]
    # 3x3 Sobel of a uint8 image is exact in int16, read only at the edge pixels (the directions in float32)
    gx = cv2.Sobel(smooth, cv2.CV_16S, 1, 0, ksize=3)[v, u].astype(np.float32)
    gy = cv2.Sobel(smooth, cv2.CV_16S, 0, 1, ksize=3)[v, u].astype(np.float32)
    norm = np.maximum(np.hypot(gx, gy), 1e-6)
    nx, ny = gx / norm, gy / norm
    # samples at -2..2 px along the gradient (dark to bright), their differences at -1.5, -0.5, 0.5, 1.5 px
    g = smooth.astype(np.float32)
    samples = np.stack([_bilinear(g, v + t * ny, u + t * nx) for t in (-2.0, -1.0, 0.0, 1.0, 2.0)],
                       axis=1).astype(np.float32)
    rise = np.diff(samples, axis=1)
    j = 1 + (rise[:, 2] > rise[:, 1]).astype(np.int64)  # the larger difference next to the pixel: at -0.5 or +0.5
    rows = np.arange(len(j))
    behind, middle, ahead = rise[rows, j - 1], rise[rows, j], rise[rows, j + 1]
    curvature = behind - 2.0 * middle + ahead
    peaked = curvature < -1e-6
    shift = np.where(peaked, 0.5 * (behind - ahead) / np.where(peaked, curvature, -1.0), 0.0)
    t = (j - 1.5) + np.clip(shift, -0.5, 0.5)
    points = np.stack([u + t * nx, v + t * ny], axis=1)
    return ImageEdges(points, np.stack([nx, ny], axis=1).astype(np.float64), middle.astype(np.float64))


def _bilinear(image: NDArray[np.float32], rows: FloatArray, cols: FloatArray) -> FloatArray:
    """(H, W) image sampled bilinearly at (E,) rows and (E,) cols -> (E,) float64; outside, the nearest border's.

    As ``scipy.ndimage.map_coordinates(image, [rows, cols], order=1, mode="nearest")``.
    """
    h, w = image.shape
    y, x = np.clip(rows, 0.0, h - 1.0), np.clip(cols, 0.0, w - 1.0)
    y0, x0 = y.astype(np.intp), x.astype(np.intp)  # floor: both are >= 0
    y1, x1 = np.minimum(y0 + 1, h - 1), np.minimum(x0 + 1, w - 1)
    fy, fx = y - y0, x - x0
    # each neighbour's value times its row's weight, then its column's, summed in order: map_coordinates' arithmetic
    return (image[y0, x0] * (1.0 - fy) * (1.0 - fx) + image[y0, x1] * (1.0 - fy) * fx
            + image[y1, x0] * fy * (1.0 - fx) + image[y1, x1] * fy * fx)


@dataclass(frozen=True)
class ContourPoints:
    """A model's occluding contour in one image, as seen from one camera pose.

    Attributes:
        points_base: (N, 3) float64, metres: points on the contour, in the robot base frame.
        outward: (N, 2) float64: unit image directions from the occluding surface towards what it hides.
    """

    points_base: FloatArray
    outward: FloatArray

    def __post_init__(self) -> None:
        points = np.asarray(self.points_base, dtype=np.float64).reshape(-1, 3)
        outward = np.asarray(self.outward, dtype=np.float64).reshape(-1, 2)
        if len(points) != len(outward) or not (np.all(np.isfinite(points)) and np.all(np.isfinite(outward))):
            raise InvalidInputError("contour points (N, 3) and outward directions (N, 2) must be finite, one each")
        object.__setattr__(self, "points_base", points)
        object.__setattr__(self, "outward", outward)


def contour_from_depth(depth: FloatArray, mask: NDArray[np.bool_], T_camera_base: FloatArray, K: FloatArray,
                       min_step_m: float = 0.03, stride: int = 1) -> ContourPoints:
    """A model's occluding contour from its depth image rendered at T_camera_base.

    A pixel of the model (``mask``) whose 4-neighbour is at least ``min_step_m`` farther (another part of the
    model, or what lies behind it: the background's depth, +inf or NaN where nothing is) occludes it: its contour
    point lies on the boundary between the two pixel centres, at the near pixel's depth, and its outward
    direction points to the far one. Only model pixels make contour points: a background that is itself near
    (the floor under a robot's foot) makes none.

    Args:
        depth: (H, W) float, metres along the optical axis, as rendered (pinhole ``K``, no distortion); off the
            model, the background's (+inf or NaN: nothing).
        mask: (H, W) bool: the pixels that show the model.
        T_camera_base: (4, 4) float64: the pose it was rendered from.
        K: (3, 3) float64: the rendering's pinhole matrix (pixel centres at integer coordinates).
        min_step_m: the smallest depth step that makes an occluding contour, metres.
        stride: keep every stride-th contour point of each direction (1: all).
    """
    depth = np.asarray(depth, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if depth.ndim != 2 or mask.shape != depth.shape:
        raise InvalidInputError(f"depth and mask must be (H, W) of one shape, got {depth.shape} and {mask.shape}")
    if stride < 1 or min_step_m <= 0:
        raise InvalidInputError(f"need stride >= 1 and min_step_m > 0, got {stride}, {min_step_m}")
    T = check_transform(np.asarray(T_camera_base, dtype=np.float64), "T_camera_base")
    # only the model's bounding box and a pixel around it can hold a contour point or its neighbour; where the box
    # meets the image's border, so does the crop (no neighbour there, as in the whole image)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        return ContourPoints(np.zeros((0, 3)), np.zeros((0, 2)))
    v0, v1 = max(int(rows[0]) - 1, 0), min(int(rows[-1]) + 2, depth.shape[0])
    u0, u1 = max(int(cols[0]) - 1, 0), min(int(cols[-1]) + 2, depth.shape[1])
    depth, mask = depth[v0:v1, u0:u1], mask[v0:v1, u0:u1]
    far = np.where(np.isnan(depth), np.inf, depth)
    us, vs, zs, outs = [], [], [], []
    for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        neighbour = np.full_like(far, -np.inf)  # image borders: no neighbour, no contour
        h, w = far.shape
        neighbour[max(-dv, 0):h - max(dv, 0), max(-du, 0):w - max(du, 0)] = \
            far[max(dv, 0):h - max(-dv, 0), max(du, 0):w - max(-du, 0)]
        with np.errstate(invalid="ignore"):  # inf - inf off the model: not a contour either way
            v, u = np.nonzero(mask & (neighbour - far >= min_step_m))
        v, u = v[::stride], u[::stride]
        us.append(u + u0 + 0.5 * du)
        vs.append(v + v0 + 0.5 * dv)
        zs.append(depth[v, u])
        outs.append(np.tile(np.array([du, dv], dtype=np.float64), (len(u), 1)))
    u, v, z = np.concatenate(us), np.concatenate(vs), np.concatenate(zs)
    cam = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    points_base = (cam - T[:3, 3]) @ T[:3, :3]
    return ContourPoints(points_base, np.concatenate(outs))


#: The model's contours seen from T_camera_base (4, 4): one ``ContourPoints`` per image, in the images' order.
ContourModel = Callable[[FloatArray], Sequence[ContourPoints]]


@dataclass(frozen=True)
class OutlineConfig:
    """Settings of ``fit_outline_pose``.

    Attributes:
        max_match_px: a contour point further than this from every image edge is left out, pixels.
        max_normal_angle_deg: an edge pairs with a contour point only if its normal is within this angle
            of the point's outward direction (either sign: the outline may be darker or brighter).
        cauchy_px: the Cauchy loss's scale on the point-to-line distances, pixels.
        renders: times the model's contour is taken (at the start, then at each new pose).
        associations: pairings per contour, each followed by a least-squares solve.
        max_nfev: function evaluations per solve.
        min_pairs: fewer pairs than this raise ``InsufficientMotionsError``.
    """

    max_match_px: float = 8.0
    max_normal_angle_deg: float = 45.0
    cauchy_px: float = 1.0
    renders: int = 4
    associations: int = 3
    max_nfev: int = 40
    min_pairs: int = 50

    def __post_init__(self) -> None:
        if min(self.max_match_px, self.cauchy_px) <= 0 or not 0 < self.max_normal_angle_deg <= 90:
            raise InvalidInputError("max_match_px and cauchy_px must be > 0 and max_normal_angle_deg in (0, 90]")
        if min(self.renders, self.associations, self.max_nfev, self.min_pairs) < 1:
            raise InvalidInputError("renders, associations, max_nfev and min_pairs must be >= 1")


@dataclass(frozen=True)
class OutlineFit:
    """``fit_outline_pose``'s result.

    Attributes:
        T_camera_base: (4, 4) float64: the fitted pose.
        n_pairs: contour points paired with an image edge at the last solve.
        median_abs_px: their median point-to-line distance there, pixels.
    """

    T_camera_base: FloatArray
    n_pairs: int
    median_abs_px: float


@dataclass(frozen=True)
class EdgePairs:
    """Contour points paired with image edges (``pair_contour_points``).

    Attributes:
        points_base: (P, 3) float64, metres: contour points in the base frame.
        edge_points: (P, 2) float64, pixels: their paired edge points.
        normals: (P, 2) float64: the edges' unit normals, turned outward (the contour point's outward side).
        in_front: how many contour points were in front of the camera, paired or not (``pair_contour_points``; 0
            where the pairs were assembled otherwise).
        image: (P,) int64: the index of the image each pair comes from (``pair_contour_points``' order); None where
            the pairs were assembled otherwise.
        polarity: (P,) float64, +1 where the image is brighter outside the contour than inside (its gradient points
            outward), -1 where brighter inside (``pair_contour_points``); None where the pairs were assembled
            otherwise.
    """

    points_base: FloatArray
    edge_points: FloatArray
    normals: FloatArray
    in_front: int = 0
    image: NDArray[np.int64] | None = None
    polarity: FloatArray | None = None
    strength: FloatArray | None = None


def pair_contour_points(T_camera_base: FloatArray, contours: Sequence[ContourPoints], edges: Sequence[ImageEdges],
                        intrinsics: CameraIntrinsics, config: OutlineConfig) -> EdgePairs:
    """Every contour point, seen from T_camera_base (4, 4), paired with its nearest image edge of a matching direction.

    ``contours`` and ``edges`` run over the same images; points further than ``config.max_match_px`` from every
    edge, or whose nearest edge's normal is more than ``config.max_normal_angle_deg`` from their outward
    direction, or behind the camera, are left out.
    """
    if len(contours) != len(edges):
        raise InvalidInputError(f"{len(contours)} contours for {len(edges)} edge images")
    if not contours:
        return EdgePairs(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), image=np.zeros(0, np.int64),
                         polarity=np.zeros(0))
    parts: list[tuple[FloatArray, FloatArray, FloatArray, NDArray[np.int64], FloatArray, FloatArray]] = [
        (np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))]
    strong = all(image.strengths is not None for image in edges)  # every image's edges know their contrast
    # every image's points projected at once (one pose, one camera), then paired image by image
    split = np.cumsum([len(contour.points_base) for contour in contours])[:-1]
    all_points = np.concatenate([contour.points_base for contour in contours])
    all_pixels, all_visible = project_base_points(T_camera_base, all_points, intrinsics)
    for i, (contour, image, pixels, visible) in enumerate(zip(contours, edges, np.split(all_pixels, split),
                                                              np.split(all_visible, split), strict=True)):
        if len(image.points) == 0:  # an image without edges pairs nothing
            continue
        idx, matched, along = image.matching(pixels, contour.outward, config.max_match_px, config.max_normal_angle_deg)
        normals = image.normals[idx]
        keep = visible & matched
        sign = np.sign(along[keep])  # the edges' normals point from dark to bright
        strengths = image.strengths[idx[keep]] if strong and image.strengths is not None else np.zeros(len(sign))
        parts.append((contour.points_base[keep], image.points[idx[keep]], normals[keep] * sign[:, None],
                      np.full(int(keep.sum()), i, np.int64), sign, strengths))
    points, edge_points, normals, index, polarity, strength = (np.concatenate(p) for p in zip(*parts, strict=True))
    return EdgePairs(points, edge_points, normals, in_front=int(all_visible.sum()), image=index, polarity=polarity,
                     strength=strength if strong else None)


def project_base_points(T_camera_base: FloatArray, points_base: FloatArray, intrinsics: CameraIntrinsics
             ) -> tuple[FloatArray, NDArray[np.bool_]]:
    """(..., N, 2) pixels of base points (N, 3) m, and (..., N) whether each is in front of the camera.

    T_camera_base: (4, 4), or a stack (..., 4, 4) seen from each at once. Points behind the camera get -1e9 px.
    """
    cam = points_base @ np.swapaxes(T_camera_base[..., :3, :3], -1, -2) + T_camera_base[..., None, :3, 3]
    front = cam[..., 2] > 1e-6
    pixels = np.full(cam.shape[:-1] + (2,), -1e9)
    pixels[front] = pixels_from_camera_points(cam[front], intrinsics)
    return pixels, front


def outline_residuals(T_camera_base: FloatArray, points_base: FloatArray, edge_points: FloatArray,
                      normals: FloatArray, intrinsics: CameraIntrinsics) -> FloatArray:
    """(P,) pixels: each contour point's signed distance to its paired edge's line, positive along the normal.

    Args:
        T_camera_base: (4, 4) float64: the pose the points (P, 3) are projected from.
        points_base: (P, 3) float64, metres: contour points in the base frame.
        edge_points: (P, 2) float64, pixels: their paired edge points.
        normals: (P, 2) float64: the edges' unit normals (``fit_outline_pose`` turns them outward).
        intrinsics: the camera.
    """
    pixels, _ = project_base_points(T_camera_base, points_base, intrinsics)
    return np.sum((pixels - edge_points) * normals, axis=1)


def outline_residuals_and_jacobian(T_camera_base: FloatArray, pairs: EdgePairs, intrinsics: CameraIntrinsics
                                   ) -> tuple[FloatArray, FloatArray]:
    """``outline_residuals`` (P,) pixels and their Jacobian (P, 6) by the pose perturbation xi = (omega, tau).

    ``solver.frames.perturb``'s parameters: R <- Exp(omega) R, t <- t + tau, so a point's camera coordinates move by
    -[p_cam - t]x omega + tau. The projection's derivative by the camera point comes from OpenCV (its Jacobian by
    the translation, taken at zero rotation and translation); fisheye lenses by central differences.
    """
    cam = pairs.points_base @ T_camera_base[:3, :3].T + T_camera_base[:3, 3]
    rotated = cam - T_camera_base[:3, 3]
    n = len(cam)
    front = cam[:, 2] > 1e-6
    pixels = np.full((n, 2), -1e9)
    d_pixel = np.zeros((n, 2, 3))  # d pixel / d p_cam
    if front.any():
        pts = np.ascontiguousarray(cam[front])
        if intrinsics.is_fisheye:
            pixels[front] = pixels_from_camera_points(pts, intrinsics)
            step = 1e-7 * np.maximum(pts[:, 2:], 1e-3)
            for k in range(3):
                e = np.zeros(3)
                e[k] = 1.0
                d_pixel[front, :, k] = (pixels_from_camera_points(pts + step * e, intrinsics)
                                        - pixels_from_camera_points(pts - step * e, intrinsics)) / (2 * step)
        else:
            dist = intrinsics.dist if intrinsics.dist.size else np.zeros(5)
            out, jac = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), intrinsics.K, dist)
            pixels[front] = out.reshape(-1, 2)
            d_pixel[front] = jac[:, 3:6].reshape(-1, 2, 3)
    r = np.sum((pixels - pairs.edge_points) * pairs.normals, axis=1)
    d_residual = np.einsum("pi,pij->pj", pairs.normals, d_pixel)  # (P, 3): d r / d p_cam
    # d p_cam / d omega = -[rotated]x, so d r / d omega = rotated x (d r / d p_cam)
    return r, np.concatenate([np.cross(rotated, d_residual), d_residual], axis=1)


def fit_outline_pose(T_init: FloatArray, edges: Sequence[ImageEdges], model: ContourModel,
                     intrinsics: CameraIntrinsics, config: OutlineConfig | None = None) -> OutlineFit:
    """The camera pose that puts the model's occluding contours on the images' edges.

    Args:
        T_init: (4, 4) float64: the starting pose, e.g. the bundle adjustment's (the pairing reaches
            ``OutlineConfig.max_match_px``: a start within a few pixels of the outlines).
        edges: one ``ImageEdges`` per image.
        model: the contours seen from a pose, one per image in the same order (``ContourModel``).
        intrinsics: the camera of the images.
        config: settings; defaults to ``OutlineConfig()``.

    Raises:
        InvalidInputError: T_init is not a finite rigid transform, no images are given, or the model
            returns another number of contours than there are images.
        InsufficientMotionsError: fewer than ``OutlineConfig.min_pairs`` contour points pair with an edge.
    """
    config = config or OutlineConfig()
    T = check_transform(np.asarray(T_init, dtype=np.float64), "T_init")
    if not edges:
        raise InvalidInputError("fit_outline_pose needs at least one image's edges")
    pairs = EdgePairs(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)))
    residual = np.zeros(0)
    for _ in range(config.renders):
        contours = list(model(T))
        if len(contours) != len(edges):
            raise InvalidInputError(f"the contour model gave {len(contours)} contours for {len(edges)} images")
        for _ in range(config.associations):
            pairs = pair_contour_points(T, contours, edges, intrinsics, config)
            if len(pairs.points_base) < config.min_pairs:
                raise InsufficientMotionsError(
                    f"only {len(pairs.points_base)} contour points lie within {config.max_match_px} px of an image "
                    f"edge of their direction (at least {config.min_pairs} needed): the start is too far off, or "
                    "the outlines are not in the images")

            def residuals(xi: FloatArray, T0: FloatArray = T, p: EdgePairs = pairs) -> FloatArray:
                return outline_residuals(perturb(T0, xi), p.points_base, p.edge_points, p.normals, intrinsics)

            solution = least_squares(residuals, np.zeros(6), loss="cauchy", f_scale=config.cauchy_px,
                                     x_scale=np.full(6, 1e-3), diff_step=1e-4, max_nfev=config.max_nfev)
            T = perturb(T, solution.x)
            residual = solution.fun
    return OutlineFit(T, len(pairs.points_base), float(np.median(np.abs(residual))) if residual.size else np.inf)
