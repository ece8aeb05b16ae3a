"""The tracks' pose and the robot's outlines adjusted together, with a covariance that the outlines cannot fool.

The bundle adjustment of the tracks gives a pose and its covariance; its points, marginalized out, leave on the
pose a quadratic cost (the Schur complement's information, ``solver.refinement``). The outlines
(``solver.outlines``) depend on the pose alone. ``OutlineAdjustment.fuse`` adjusts the pose to the outlines' cost
plus that quadratic prior (the prior holds the pairing of contour points with edges where the outlines alone fix
a direction weakly), takes from there the outlines' own estimate (one Newton step without the prior) with its
honest covariance (below), and combines it with the tracks' by their covariances.

Each image keeps the contour its model gave at the pose it was last rendered from, and is rendered again only
when the pose has moved its contour by more than ``OutlineFusionConfig.rerender_px``: once the estimate settles,
an update renders only the new motion's images. Likewise an image's contour points keep the edges they were paired
with until the pose moves them by ``OutlineFusionConfig.repair_px`` along those edges' normals: an update then pairs
the new images alone.

The outlines' covariance must not be the textbook one: thousands of contour points per image, each a pixel from
its neighbours, share what makes them wrong (the shading of a casting moves its whole edge, a link's model
differs from the part). What guards it:

- the residuals' scatter per motion (a cluster: its images share the links' shading and the model's errors)
  replaces the model's covariance where it is larger (a clustered sandwich, ``conservative_covariance``);
- the edges' offsets from the true outline are consider parameters, each of ``OutlineFusionConfig.edge_offset_px``
  1-sigma: not estimated (measured: fitting a common one over-corrects), their effect on the pose added to the
  covariance. Three: a common offset along every outward normal (measured on rendered realistic images, the
  edges of shaded castings lie about 0.24 px inside the outline, ``docs/realistic-imaging.md``, which leaves the
  outline fit 0.4-1.3 mm off along the optical axis), and offsets that grow with the outward normal's x and y
  (light from one side: the shaded side's edges move in, the lit side's do not; an image shift, which moves
  the pose sideways). On a realistic 960x540 Panda episode (8 motions, 24 images) the fit was 0.6 / 1.1 / 2.4 mm
  off (x, y, depth) with 1-sigma 0.17 / 0.13 / 2.0 mm from the common offset alone (chi-square 255), and
  0.94 / 0.96 / 2.0 mm with all three (chi-square 8.0). 0.3 px each until stop 52, now 0.2 px (below);
- the edges' shift towards the brighter side (``OutlineFusionConfig.polarity_offset_px``) is estimated with the pose
  and eliminated (its Schur complement): where a casting darkens towards its outline, the image's edge lies a
  fraction of a pixel off it, out where the background is brighter and in where the robot is. Measured on captured
  realistic episodes (Sobel's edges): the estimate 0.11-0.52 px, and the error after 8-25 motions 0.75 -> 0.49 mm
  median over ten runs (a far 720p Panda view 2.87 -> 1.60 mm, 1-sigma 3.44 -> 2.80 mm). The shift is not one
  number: at the true pose of a realistic 720p Panda episode, a robot brighter than its background had its bottom
  edges 0.5-0.6 px inside, its top edges 0.02 px (a rim turned away from the light is dark, one facing it is not);
  a turn of the camera about its x, to the outlines. So its growth along the outward normal's image x and y is
  estimated with it (``OutlineFusionConfig.polarity_direction_px``), for its part that differs between the
  polarities (the rest is a turn of the camera: left to the tracks), and the pairs are weighted by their edges'
  contrast (``OutlineFusionConfig.contrast_grey``: faint edges lie furthest off). Replayed on 18 captured
  realistic episodes (``docs/realistic-imaging.md``, stop 54): median error at 25 motions 0.33 -> 0.28 mm, at 5
  0.37 -> 0.33 mm, a pose by motion 5 on 17 -> 18 of 18;
- a floor (``OutlineFusionConfig.floor_px``): the outlines fix the pose no better than to a 0.07 px RMS displacement
  of their contour points, in any direction (0.1 px until stop 52). Measured on two episodes, outline-only chi-square
  of the truth without / with it: a clean painted 960x540 recording (9 motions, 27 images) 40.7 / 0.4, the realistic
  one above 7.4 / 1.1; the combined pose then weighs the tracks more where the outlines are overconfident, and its
  error went 0.71 -> 0.48 mm and 2.22 -> 1.74 mm. Measured again once the brighter-side shift was estimated (60
  captured realistic 720p episodes of three arms, 346 updates at motions 5-25; ``docs/realistic-imaging.md``, stop
  52): with a floor of 0.1 px and offsets of 0.3 px the outlines' own estimate lay at a median chi-square of 0.28-1.12
  per arm (5.35 over 6 dof is honest), its depth error 0.46 of its 1-sigma (RMS). Since then 0.07 px and 0.2 px:
  0.60-2.41, depth 0.65, the depth's 1-sigma 1.22 -> 0.85 mm (median), 99.7 % inside the 95 % region both ways;
- the outlines' pose must agree with the tracks' (Mahalanobis distance under the sum of both covariances below
  ``OutlineFusionConfig.max_disagreement_chi2``), else the outlines are not used and the reason is given.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray
from solver.errors import (
    InsufficientMotionsError,
    InvalidInputError,
    OutlineDisagreementError,
    OutlineMismatchError,
    OutlineReachError,
)
from solver.frames import check_transform, perturb, pose_difference
from solver.mask_start import ChangeMask
from solver.observations import CameraIntrinsics
from solver.outlines import (
    ContourPoints,
    EdgePairs,
    ImageEdges,
    OutlineConfig,
    outline_residuals_and_jacobian,
    pair_contour_points,
    project_base_points,
)
from solver.refinement import conservative_covariance, few_clusters_factor

__all__ = ["CoarseContours", "ContourRenderer", "OutlineAdjustment", "OutlineFusion", "OutlineFusionConfig",
           "OutlineImage"]

#: The robot's occluding contour with the arm at q (n,) rad, seen from T_camera_base (4, 4).
ContourRenderer = Callable[[FloatArray, FloatArray], ContourPoints]


@runtime_checkable
class CoarseContours(Protocol):
    """A contour renderer with a cheaper one: the same contours from fewer pixels, a pixel or two less exact."""

    def coarse(self) -> ContourRenderer:
        """The cheaper renderer (its points are base-frame points as this one's: they project with the same camera).

        Called at every coarse scoring: an implementation makes it once and keeps it (``RobotContours.coarse``).
        """
        ...

#: The smaller polarity's least share of the pairs' weight for the edges' shift's growth along the outward normal
#: (``OutlineFusionConfig.polarity_direction_px``) to be estimated.
MIN_POLARITY_SHARE = 0.1

#: A Gauss-Newton step, or a pairing's whole move, shorter than this in units of the fused pose's 1-sigma (its length
#: under the prior's information plus the outlines' honest one at the fuse's start) ends it.
_CONVERGED_SIGMA = 0.02
#: ``_capped_scores`` projects at most about this many contour points at once (poses x points)
_SCORED_POINTS = 200_000


@dataclass(frozen=True)
class OutlineImage:
    """One image's edges and what the robot did in it.

    Attributes:
        edges: its sub-pixel edges (``solver.outlines.image_edges``).
        q: (n,) float64, rad: the arm's configuration in it.
        group: the motion it belongs to (its images share the links' shading: one cluster).
        changed: where it differs from its motion's first image (``solver.mask_start.change_mask``), for a first
            pose from the moving links (``Calibrator``'s mask rescue); None: not known (the first image, or none).
    """

    edges: ImageEdges
    q: FloatArray
    group: int
    changed: ChangeMask | None = None

    def __post_init__(self) -> None:
        q = np.asarray(self.q, dtype=np.float64).reshape(-1)
        if q.size == 0 or not np.all(np.isfinite(q)):
            raise InvalidInputError("an outline image's joint configuration must be a finite (n,) array")
        object.__setattr__(self, "q", q)


@dataclass(frozen=True)
class OutlineFusionConfig:
    """Settings of ``OutlineAdjustment``.

    Attributes:
        outline: the pairing of contour points with edges (``OutlineConfig``: distance, angle, Cauchy scale,
            pairings per render, minimum pairs).
        rerender_px: an image's contour is rendered again when the pose has moved it by more than this, pixels.
        repair_px: an image's contour points keep the edges they were paired with while the pose has moved them by
            less than this along those edges' normals since, pixels (re-pairing them would find the same edges: the
            pairing is most of a fuse's time once the estimate settles); 0: every image paired again each time.
        renders: rounds of (render where needed, pair, solve) per fuse.
        gauss_newton_steps: iteratively reweighted Gauss-Newton steps per pairing.
        edge_offset_px: 1-sigma of each of the edges' offsets from the true outline (common, and along the image's
            x and y with the outward normal), pixels: consider parameters of the covariance.
        polarity_offset_px: 1-sigma of the prior of the edges' shift from the outline towards the brighter side,
            pixels, estimated with the pose in every fuse (0: not estimated). A surface's shading next to its
            outline moves the image's edge (measured: ``solver.outlines.image_edges``). Edges of both kinds in one
            image separate it from the pose; a common offset alone is the depth's (``edge_offset_px``).
        polarity_direction_px: 1-sigma of the prior of two more parts of that shift, growing with the outline's
            outward normal's image x and y, estimated with it (0: not estimated). A surface turned away from the
            light has a dark rim that moves its edge further (measured at the true pose of realistic 720p Panda
            and 1080p xArm 6 frames: bottom edges of a robot brighter than its background 0.5-0.6 px towards the
            robot, its top edges 0.02-0.03 px). Estimated only while each polarity holds ``MIN_POLARITY_SHARE`` of
            the weight: with one polarity the growth moves every edge one way, as a turn of the camera does.
        direction_centred: estimate only the growth's part that differs between the polarities (the polarity less
            its weighted mean, times the normal), leaving the rest to the tracks. Off (stop 55): on 18 realistic
            captures (stops 53-54) the median error 0.326 -> 0.308 mm at 5 motions, 0.284 -> 0.270 at 25, the mean
            error in image y -0.157 -> -0.139 mm, updates beyond the 99.9 % chi-square 1 -> 0 of 409, 7 captures
            better at 25 and 2 worse (the Panda 720p pose 0 by 0.08 mm); the tests' one-polarity spheres alike (the
            share gate).
        contrast_grey: the pairs are weighted by s^2 / (s^2 + contrast_grey^2), s the edge's contrast
            (``solver.outlines.ImageEdges.strengths``, grey levels per pixel; 0: unweighted). A faint edge is
            found less surely, and where the robot's dark rim meets a dark background it lies furthest inside
            (measured at the true pose, the xArm 6 frames above: bottom edges of contrast below 42 grey levels
            over 4 px 0.85 px off, above 72 0.24 px).
        floor_px: the outlines are trusted to fix the pose no better than to this RMS displacement of their contour
            points, pixels: a covariance floor (this squared times the inverse of J^T W J / sum W) for what no
            offset above describes (the model's small differences from the robot's surfaces, the contours'
            half-pixel steps). See the module's docstring for what it did on two episodes.
        max_prior_px: the outlines are not used while the tracks' 1-sigma moves their contour points by more than
            this RMS, pixels (pairing each with its nearest edge would then be a guess). Measured: a realistic 720p
            iiwa episode whose tracks were 164 mm off with a 1-sigma of 170 mm at motion 6 had its outlines paired
            with the wrong edges, 118 mm off with a 1-sigma of 1.8 mm (chi-square 4293), until motion 9.
        max_rescue_prior_px: ... and this, when the calibrator's rescue has searched the tracks' weakest direction
            first (``Calibrator._rescue_wide``): the rescue's residual-scale test vouches for the pairing instead.
        min_groups: fewest motions with images before the outlines are used.
        trusted_groups: below this many motions with images the fused covariance is at least the outlines' own
            (``conservative_covariance``): the tracks' clustered covariance needs several clusters, and from three
            motions it was too narrow (chi-square of the truth up to 40 over 6 dof where the outlines' own gave
            0.8-5.9, ``docs/realistic-imaging.md``).
        max_early_sigma_px: below ``trusted_groups`` motions the outlines are not used when their residuals' robust
            scale at the fused pose exceeds this, pixels: contours fitted to the wrong edges. Measured on captured
            realistic episodes at three motions: 0.41-0.68 px where the fused pose was 0.6-0.9 mm off, 1.73 px where
            a tracks' pose 115 mm off (and sure of itself: chi-square 34) had its contours paired with the wrong
            edges (88 mm off, chi-square 610). The calibrator refuses such a fusion at any count
            (``Calibrator._fuse_outlines``).
        max_disagreement_chi2: the fused pose is refused when it lies further than this from the tracks' pose
            (Mahalanobis, under the sum of the tracks' and the outlines' covariances; chi-square, 6 dof, 0.999).
        min_groups_along: fewest motions with images for ``fuse`` with a free direction (it serves the first
            motions, whose tracks may leave the depth free: the Panda's joints 1-3 alone).
        search_px: ``search_along`` first scores each contour point's distance to its nearest edge capped at this,
            pixels (a wide basin for a coarse grid); each later round halves it, down to
            ``OutlineConfig.max_match_px``.
        search_rounds: rounds of ``search_along`` (each renders every image at the best pose so far and searches
            again between the best offset's neighbours).
        search_samples: offsets per refining round.
        coarse_search: ``search_along``'s rounds before the last (caps of ``search_px`` and its half: a contour point
            a pixel or two off does not change their ranking) render with the renderer's cheaper one when it has one
            (``CoarseContours``); the last round renders at full resolution.
        few_groups_t: below ``trusted_groups`` motions the outlines' covariance, the floor under the fused pose's (and
            a rescued one's, ``OutlineFusion.outline_covariance``), is taken ``few_clusters_factor(G)`` times (G motions
            with pairs; 4.8 at three, 2.0 at five): their errors are shared within a motion, so its scale is known
            from G - 1 degrees of freedom. The fusion still weighs the outlines by the estimate itself (widened there
            too, the poses from three motions moved towards the tracks': median 0.36 -> 0.68 mm on 13 as-shipped
            xArm 6 1080p captures). Off (stop 64): those runs held the truth in the 95 % region after 71 of 80
            updates, eight misses outline poses from three to five motions 0.6-3.1 mm off at a 1-sigma of 0.3-0.9
            mm; on, 79 of 80, every pose the same (``docs/realistic-imaging.md``, stop 65).
    """

    outline: OutlineConfig = OutlineConfig()
    rerender_px: float = 1.0
    repair_px: float = 0.25
    renders: int = 3
    gauss_newton_steps: int = 4
    edge_offset_px: float = 0.2
    polarity_offset_px: float = 0.5
    polarity_direction_px: float = 0.3
    contrast_grey: float = 25.0
    direction_centred: bool = False
    floor_px: float = 0.07
    max_prior_px: float = 8.0
    max_rescue_prior_px: float = 40.0
    min_groups: int = 3
    trusted_groups: int = 6
    max_early_sigma_px: float = 1.0
    max_disagreement_chi2: float = 22.46
    min_groups_along: int = 3
    search_px: float = 32.0
    search_rounds: int = 3
    search_samples: int = 9
    coarse_search: bool = True
    few_groups_t: bool = True

    def __post_init__(self) -> None:
        if not (self.rerender_px > 0 and self.repair_px >= 0 and self.edge_offset_px >= 0
                and self.polarity_offset_px >= 0 and self.max_disagreement_chi2 > 0 and self.max_early_sigma_px > 0):
            raise InvalidInputError("need rerender_px > 0, repair_px >= 0, edge_offset_px >= 0, "
                                    "polarity_offset_px >= 0, max_disagreement_chi2 > 0 and max_early_sigma_px > 0")
        if min(self.renders, self.gauss_newton_steps, self.min_groups, self.min_groups_along, self.search_rounds,
               self.trusted_groups) < 1:
            raise InvalidInputError("renders, gauss_newton_steps, min_groups, min_groups_along, search_rounds and "
                                    "trusted_groups must be >= 1")
        if not (self.search_px > 0 and self.search_samples >= 3):
            raise InvalidInputError("need search_px > 0 and search_samples >= 3")


@dataclass(frozen=True)
class OutlineFusion:
    """``OutlineAdjustment.fuse``'s result.

    Attributes:
        T_camera_base: (4, 4) float64: the tracks' pose and the outlines' combined.
        covariance: (6, 6) float64: its covariance of (omega rad, tau m) (``perturb``'s parameters).
        outline_covariance: (6, 6) float64: the outlines' alone (clustered, with the edge offsets considered; from
            fewer than ``trusted_groups`` motions widened, ``OutlineFusionConfig.few_groups_t``).
        disagreement_chi2: the outlines' pose's Mahalanobis distance squared from the tracks' pose.
        n_pairs: contour points paired with an edge at the end.
        n_images: images used.
        n_groups: motions they came from.
        sigma_px: the residuals' robust scale, pixels.
        rendered: contours rendered during this fuse.
        polarity_offset_px: the edges' shift from the outline towards the brighter side, estimated with the pose
            (``OutlineFusionConfig.polarity_offset_px``; 0.0 when not estimated), pixels.
        polarity_direction_px: (2,) float64, pixels: how much the shift grows with the outline's outward normal's
            image x and y (``OutlineFusionConfig.polarity_direction_px``; zeros when not estimated).
        prior_scale: the factor the tracks' covariance was multiplied by (``fuse``'s ``prior_scale``; 1: as given).
    """

    T_camera_base: FloatArray
    covariance: FloatArray
    outline_covariance: FloatArray
    disagreement_chi2: float
    n_pairs: int
    n_images: int
    n_groups: int
    sigma_px: float
    rendered: int
    polarity_offset_px: float = 0.0
    polarity_direction_px: FloatArray = field(default_factory=lambda: np.zeros(2))
    prior_scale: float = 1.0


@dataclass
class _Cached:
    image: OutlineImage
    contour: ContourPoints | None = None
    pixels: FloatArray | None = None  # (N, 2): the contour's points projected from the pose it was rendered at
    pairs: EdgePairs | None = None  # its contour's points paired with its edges (image index 0), None: pair again
    paired_T: FloatArray | None = None  # (4, 4): the pose they were paired at
    paired_r: FloatArray | None = None  # (P,) px: their residuals there
    paired_J: FloatArray | None = None  # (P, 6): the residuals' Jacobian there

    def render(self, renderer: ContourRenderer, T: FloatArray, intrinsics: CameraIntrinsics) -> None:
        self.contour = renderer(T, self.image.q)
        self.pixels = project_base_points(T, self.contour.points_base, intrinsics)[0]
        self.forget_pairs()

    def forget_pairs(self) -> None:
        self.pairs = self.paired_T = self.paired_r = self.paired_J = None


@dataclass(frozen=True)
class _Paired:
    """Every image's pairs, with their residuals linearized where each image was paired."""

    pairs: EdgePairs  # (P,) pairs; ``image``: the image's index
    groups: FloatArray  # (P,): the motion of each pair
    r: FloatArray  # (P,) px: the residuals at the pose their image was paired at
    J: FloatArray  # (P, 6): their Jacobian there
    poses: list[FloatArray]  # the poses the images were paired at (each (4, 4))
    pose_of: NDArray[np.int64]  # (P,): each pair's index into poses

    def residuals(self, T: FloatArray) -> FloatArray:
        """(P,) px: the residuals at T, to first order in the pose's move from where each image was paired."""
        if not self.poses:
            return self.r
        moves = np.stack([pose_difference(paired_at, T) for paired_at in self.poses])
        return self.r + np.einsum("pj,pj->p", self.J, moves[self.pose_of])


@dataclass(frozen=True)
class _Normal:
    """The whitened normal equations of the outlines at a pose: information, gradient, per-group scores."""

    information: FloatArray  # (6, 6)
    gradient: FloatArray  # (6,): J^T W r / sigma^2
    group_scores: FloatArray  # (G, 6): each group's share of the gradient
    offset_gradient: FloatArray  # (6, 3): J^T W U / sigma^2, U (P, 3) = (1, n_x, n_y): the residuals' derivatives
    # by the edge offsets (a common one, and one that grows along the image's x and y with the outward normal)
    sigma_px: float
    n_pairs: int
    mean_information: FloatArray  # (6, 6): J^T W J / sum(W), px^2 per unit^2: a pose change at an average pair
    polarity_offset_px: float  # the edges' estimated shift towards the brighter side (0: not estimated)
    polarity_direction_px: FloatArray  # (2,): its growth with the outward normal's image x and y (zeros: not)


class OutlineAdjustment:
    """The outline images of a calibration and their joint adjustment with the tracks' pose.

    Args:
        renderer: the robot's contour at a configuration, from a pose (``ContourRenderer``).
        intrinsics: the camera of the images.
        config: settings; defaults to ``OutlineFusionConfig()``.
    """

    def __init__(self, renderer: ContourRenderer, intrinsics: CameraIntrinsics,
                 config: OutlineFusionConfig | None = None):
        self.renderer = renderer
        self.intrinsics = intrinsics
        self.config = config or OutlineFusionConfig()
        self._images: list[_Cached] = []

    @property
    def images(self) -> tuple[OutlineImage, ...]:
        """The images added so far, in order."""
        return tuple(c.image for c in self._images)

    def contour_rays(self, T: FloatArray) -> FloatArray:
        """(N, 2): every image's contour points (as last rendered) seen from T (4, 4), normalized image coordinates.

        x / z and y / z, without the lens's distortion; points behind the camera left out.
        """
        T = check_transform(np.asarray(T, dtype=np.float64), "T")
        parts = [c.contour.points_base for c in self._images if c.contour is not None]
        if not parts:
            return np.zeros((0, 2))
        cam = np.concatenate(parts) @ T[:3, :3].T + T[:3, 3]
        cam = cam[cam[:, 2] > 1e-6]
        return cam[:, :2] / cam[:, 2:]

    @property
    def n_images(self) -> int:
        """Images added so far."""
        return len(self._images)

    @property
    def n_groups(self) -> int:
        """Motions the images come from."""
        return len({c.image.group for c in self._images})

    def add(self, image: OutlineImage) -> None:
        """Keep one image for the next ``fuse``."""
        self._images.append(_Cached(image))

    def fuse(self, T_prior: FloatArray, covariance_prior: FloatArray, T_start: FloatArray | None = None,
             free_direction: FloatArray | None = None, start_covariance: FloatArray | None = None,
             max_prior_px: float | None = None, prior_scale: float = 1.0) -> OutlineFusion:
        """The pose that fits the tracks' estimate (a Gaussian prior) and every image's outlines.

        Args:
            T_prior: (4, 4) float64: the tracks' pose.
            covariance_prior: (6, 6) float64: its covariance of (omega rad, tau m).
            T_start: (4, 4) float64: where the adjustment starts (e.g. the last fused pose); None: T_prior. It
                must put the outlines within ``OutlineConfig.max_match_px`` of the images' edges.
            free_direction: (3,) a translation direction (camera frame) that the tracks leave free and the caller
                has searched (``search_along``: T_start is its best pose): the prior's reach is judged with it fixed
                (the prior's covariance conditioned on it: its marginal keeps whatever of the direction's metres of
                variance the rest shares), and images from ``min_groups_along`` motions suffice.
            start_covariance: (6, 6) float64: T_start's own covariance, when the start is known better than the
                prior (a pose the outlines fixed in an earlier update): the pairing's reach is judged by it instead
                of the prior's (the nearest edges are no guess from a start that fit them closely).
            max_prior_px: the reach allowed, px RMS, instead of ``OutlineFusionConfig.max_prior_px`` (a caller that
                vouches for the start otherwise, e.g. by the outlines' search and their residual scale after).
            prior_scale: the tracks' covariance is taken times this (>= 1) in the adjustment and the disagreement
                test (a caller that has found it too narrow); the reach is judged as without it.

        Raises:
            InvalidInputError: a non-rigid pose, a covariance that is not finite, symmetric positive definite, or a
                bad direction.
            InsufficientMotionsError: images from fewer than ``min_groups`` motions, or too few contour points pair
                with an edge.
            OutlineDisagreementError: the outlines' pose disagrees with the tracks' (``max_disagreement_chi2``; the
                message and its ``chi2`` give the distance).
            OutlineMismatchError: from fewer than ``trusted_groups`` motions, the outlines' residual scale at the
                adjusted pose exceeds ``max_early_sigma_px`` (the tracks' pose may be far off).
            OutlineReachError: the reach covariance's 1-sigma moves the contour points by more than ``max_prior_px``
                (or ``OutlineFusionConfig.max_prior_px``) RMS.
        """
        T0 = check_transform(np.asarray(T_prior, dtype=np.float64), "T_prior")
        C0 = _symmetric(covariance_prior, "the prior covariance")
        if not (np.isfinite(prior_scale) and prior_scale >= 1.0):
            raise InvalidInputError(f"prior_scale must be a finite number >= 1, got {prior_scale!r}")
        try:
            L_inv = np.linalg.inv(np.linalg.cholesky(C0))
        except np.linalg.LinAlgError as exc:
            raise InvalidInputError("the prior covariance is not positive definite") from exc
        P0 = L_inv.T @ L_inv
        reach = C0
        if free_direction is not None:
            w = np.concatenate([np.zeros(3), _unit(free_direction)])
            Q = np.eye(6) - np.outer(w, w)
            reach = np.linalg.pinv(Q @ P0 @ Q, rcond=1e-10, hermitian=True)
        if start_covariance is not None:
            if T_start is None:
                raise InvalidInputError("a start covariance needs its start")
            reach = _symmetric(start_covariance, "the start covariance")
        self._require_groups(self.config.min_groups if free_direction is None else self.config.min_groups_along)
        T = T0 if T_start is None else check_transform(np.asarray(T_start, dtype=np.float64), "T_start")
        return self._fuse(T0, P0 / prior_scale, T, reach,
                          self.config.max_prior_px if max_prior_px is None else max_prior_px, prior_scale)

    def search_along(self, T: FloatArray, direction: FloatArray, offsets: FloatArray) -> tuple[FloatArray, float]:
        """The translation along a direction the tracks leave free that puts the robot's contours on the edges.

        The joints whose axes all meet in one point (the Panda's joints 1-3) turn the robot about that point, and the
        tracks of their motions fit every camera pose on the line from it to the camera alike (their points scale
        along). The robot's outlines have its size: the poses T + s ``direction`` (s in ``offsets``) are scored by
        the mean over contour points of min(d, cap)^2, d the distance to the nearest edge of a matching direction,
        with every image's contour rendered at T; then, ``search_rounds`` times, rendered again at the best pose
        and searched between the best offset's neighbours, the cap halved each round (from ``search_px`` down to
        ``OutlineConfig.max_match_px``).

        Args:
            T: (4, 4) float64: a pose on the line (the tracks').
            direction: (3,) the line's direction in the camera frame.
            offsets: (S,) m, S >= 2: the translations to score first (e.g. ``solver.calibration.family_offsets``).

        Returns:
            The best pose (4, 4) (its contours cached for ``fuse``), and the spacing of the last offsets there, m.

        Raises:
            InvalidInputError: a non-rigid pose, a bad direction or offsets.
            InsufficientMotionsError: no images, or no offset puts the contours within the last cap of the edges.
        """
        cfg = self.config
        T0 = check_transform(np.asarray(T, dtype=np.float64), "T")
        u = _unit(direction)
        offsets = np.unique(np.asarray(offsets, dtype=np.float64).reshape(-1))
        if offsets.size < 2 or not np.all(np.isfinite(offsets)):
            raise InvalidInputError("need at least two finite offsets to search")
        if not self._images:
            raise InsufficientMotionsError("no outline images to search with")
        cap = cfg.search_px
        best_T = T0
        step = float("nan")
        for round_ in range(cfg.search_rounds):
            shifted = [_translated(T0, s * u) for s in offsets]
            coarse = cfg.coarse_search and round_ + 1 < cfg.search_rounds
            scores = self.capped_scores(best_T, np.array(shifted), cap, coarse=coarse)  # rendered at the best so far
            if not np.isfinite(scores).any():
                raise InsufficientMotionsError("no pose along the free direction puts the robot's contour in front "
                                               "of the camera")
            i = int(np.nanargmin(scores))
            best_T = shifted[i]
            lo, hi = offsets[max(i - 1, 0)], offsets[min(i + 1, len(offsets) - 1)]
            step = float(hi - lo) / 2
            if round_ + 1 < cfg.search_rounds:
                offsets = np.linspace(lo, hi, cfg.search_samples)
                cap = max(cap / 2, cfg.outline.max_match_px)
            elif scores[i] >= cap**2:
                raise InsufficientMotionsError(f"no pose along the free direction puts the robot's contour within "
                                               f"{cap:g} px of the images' edges")
        return best_T, step

    def capped_scores(self, T_render: FloatArray, poses: FloatArray, cap_px: float, stride: int = 1,
                      screen: tuple[int, int] | None = None, coarse: bool = False) -> FloatArray:
        """(N,) px^2: how well each of ``poses`` (N, 4, 4) puts the robot's contours on the images' edges.

        Every image's contour is rendered at ``T_render`` (4, 4) (so the poses should lie near it), then each pose
        is scored as ``search_along`` scores: the mean over contour points in front of the camera of min(d, cap_px)^2,
        d the distance to the nearest edge of a matching direction; NaN where no point is in front. ``stride`` > 1:
        every stride-th contour point only (a search's cheaper ranking). ``screen`` = (s, k): every pose is scored
        first with every s-th point, and only the k best of them with every ``stride``-th; the others score inf.
        ``coarse``: the contours rendered with the renderer's cheaper one (``CoarseContours``; the renderer itself when
        it has none).

        Raises:
            InvalidInputError: a non-rigid pose, a cap that is not positive, a stride or screen below 1.
            InsufficientMotionsError: no images.
        """
        T0 = check_transform(np.asarray(T_render, dtype=np.float64), "T_render")
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        if not cap_px > 0 or stride < 1 or (screen is not None and min(screen) < 1):
            raise InvalidInputError(f"cap_px must be > 0, stride and screen >= 1, got {cap_px}, {stride}, {screen}")
        if not self._images:
            raise InsufficientMotionsError("no outline images to score with")
        renderer = self.renderer.coarse() if coarse and isinstance(self.renderer, CoarseContours) else self.renderer
        for cached in self._images:
            cached.render(renderer, T0, self.intrinsics)
        poses = np.stack([check_transform(T, "a pose") for T in poses])
        if screen is None or screen[1] >= len(poses):
            return self._capped_scores(poses, cap_px, stride)
        screened = self._capped_scores(poses, cap_px, screen[0])
        best = np.argsort(np.where(np.isnan(screened), np.inf, screened), kind="stable")[:screen[1]]
        scores = np.full(len(poses), np.inf)
        scores[best] = self._capped_scores(poses[best], cap_px, stride)
        return scores

    def paired_share(self, T: FloatArray, max_px: float) -> float:
        """The share of every image's contour points seen inside the image from T (4, 4) with an edge near them.

        Near: within ``max_px`` px, of a matching direction (``ImageEdges.matching``). Contours are rendered at T. A
        pose far off can fit the few edges its contours fall near closely (a small residual scale) while most of its
        contour finds none; at the pose, most does. 0 when no contour point is seen.

        Raises:
            InsufficientMotionsError: no images.
        """
        T = check_transform(np.asarray(T, dtype=np.float64), "T")
        if not self._images:
            raise InsufficientMotionsError("no outline images to pair with")
        seen = paired = 0
        for cached in self._images:
            cached.render(self.renderer, T, self.intrinsics)
            if cached.contour is None or not len(cached.contour.points_base):
                continue
            pixels, front = project_base_points(T, cached.contour.points_base, self.intrinsics)
            inside = front & np.all(pixels >= -0.5, axis=1) & (pixels[:, 0] < self.intrinsics.width - 0.5) & (
                pixels[:, 1] < self.intrinsics.height - 0.5)
            if not inside.any():
                continue
            _, matched, _ = cached.image.edges.matching(pixels[inside], cached.contour.outward[inside], max_px,
                                                        self.config.outline.max_normal_angle_deg)
            seen += int(inside.sum())
            paired += int(matched.sum())
        return paired / seen if seen else 0.0

    def _require_groups(self, fewest: int) -> None:
        if self.n_groups < fewest:
            raise InsufficientMotionsError(f"outline images from {self.n_groups} motion(s); at least {fewest} are "
                                           "needed")

    def _fuse(self, T0: FloatArray, P: FloatArray, T: FloatArray, reach_covariance: FloatArray,
              max_prior_px: float, prior_scale: float) -> OutlineFusion:
        """The adjustment from T with the tracks' pose T0 and information P (6, 6) as the prior; the combination.

        ``prior_scale``: the factor already applied to P (it is reported with the result).
        """
        cfg = self.config
        metric: FloatArray | None = None  # the fused pose's information, for convergence: set at the first pairing
        rendered = 0
        for round_ in range(cfg.renders):
            fresh = self._render_where_moved(T)
            rendered += fresh
            if round_ and not fresh:  # every contour is where it was: the pairing would be the same
                break
            for _ in range(cfg.outline.associations):
                paired = self._pairs(T)
                T_paired = T
                for _ in range(cfg.gauss_newton_steps):
                    normal = self._normal(T, paired)
                    if metric is None:  # at the start's first pairing
                        self._check_prior_reach(normal, reach_covariance, max_prior_px)
                        metric = P + np.linalg.inv(self._outline_covariance(normal))
                    d = pose_difference(T0, T)
                    step = -np.linalg.solve(P + normal.information, P @ d + normal.gradient)
                    T = perturb(T, step)
                    if step @ metric @ step < _CONVERGED_SIGMA**2:
                        break
                moved = pose_difference(T_paired, T)
                if moved @ metric @ moved < _CONVERGED_SIGMA**2:
                    break
        normal = self._normal(T, self._pairs(T))
        if self.n_groups < cfg.trusted_groups and normal.sigma_px > cfg.max_early_sigma_px:
            raise OutlineMismatchError(
                f"from {self.n_groups} motions the outlines fit their edges too loosely (residual scale "
                f"{normal.sigma_px:.2f} px, at most {cfg.max_early_sigma_px:g}): the tracks' pose may be far off")
        cov_outline = self._outline_covariance(normal)
        information_outline = np.linalg.inv(cov_outline)
        # The outlines' own estimate (relative to the tracks' pose): one Newton step without the prior from the joint
        # fit, where P d + gradient = 0. It and the tracks' are combined by their honest covariances, so a direction
        # the outlines fix less surely than their raw information says keeps the tracks' weight.
        d = pose_difference(T0, T)
        xi_outline = d + np.linalg.solve(normal.information, P @ d)
        disagreement = disagreement_chi2(xi_outline, P, information_outline)
        if disagreement > cfg.max_disagreement_chi2:
            raise OutlineDisagreementError(
                f"the outlines disagree with the tracks: their pose lies {np.sqrt(disagreement):.1f} sigma from the "
                f"tracks' (at most {np.sqrt(cfg.max_disagreement_chi2):.1f}); the robot model may not match the "
                "robot, or other edges lie along its outline", disagreement, xi_outline, P, information_outline)
        cov = np.linalg.inv(P + information_outline)
        cov = 0.5 * (cov + cov.T)
        T_fused = perturb(T0, cov @ information_outline @ xi_outline)
        if self.n_groups < cfg.trusted_groups:  # the tracks' covariance from too few motions: the outlines' a floor
            groups = len(normal.group_scores)
            if cfg.few_groups_t and groups >= 2:  # the outlines' scale known from few motions: their floor widened
                cov_outline = few_clusters_factor(groups) * cov_outline
            cov = conservative_covariance(cov, cov_outline)
        return OutlineFusion(T_fused, cov, cov_outline, disagreement, normal.n_pairs, len(self._images), self.n_groups,
                             normal.sigma_px, rendered, normal.polarity_offset_px, normal.polarity_direction_px,
                             prior_scale)

    def _capped_scores(self, poses: FloatArray, cap_px: float, stride: int = 1) -> FloatArray:
        """(N,) px^2: per pose (N, 4, 4), the mean over the contour points in front of the camera of min(d, cap_px)^2.

        d: the distance along its normal to the nearest edge of a matching direction (as ``pair_contour_points``
        pairs them; cap_px for a point with none within cap_px). NaN where no point is in front. ``stride``: every
        stride-th contour point only. The poses are scored together, a chunk at a time: one projection and one
        nearest-edge query per image for all of a chunk's poses.
        """
        seen = [cached for cached in self._images if cached.contour is not None and len(cached.contour.points_base)]
        scores = np.full(len(poses), np.nan)
        if not seen:
            return scores
        points = [cached.contour.points_base[::stride] for cached in seen]
        outward = [cached.contour.outward[::stride] for cached in seen]
        bounds = np.cumsum([0] + [len(p) for p in points])
        all_points = np.concatenate(points)
        max_angle_deg = self.config.outline.max_normal_angle_deg
        chunk = max(1, _SCORED_POINTS // len(all_points))
        for start in range(0, len(poses), chunk):
            Ts = poses[start:start + chunk]
            pixels, front = project_base_points(Ts, all_points, self.intrinsics)  # (n, M, 2), (n, M)
            total = np.zeros(len(Ts))
            for cached, directions, lo, hi in zip(seen, outward, bounds[:-1], bounds[1:], strict=True):
                edges = cached.image.edges
                image_front = front[:, lo:hi]
                image_pixels = pixels[:, lo:hi].reshape(-1, 2)
                idx, matched, _ = edges.matching(image_pixels, np.tile(directions, (len(Ts), 1)), cap_px, max_angle_deg)
                paired = image_front.reshape(-1) & matched
                r = np.sum((image_pixels[paired] - edges.points[idx[paired]]) * edges.normals[idx[paired]], axis=1)
                capped = np.where(image_front, cap_px**2, 0.0)  # (n, m): a point in front with no edge counts cap^2
                capped.reshape(-1)[paired] = np.minimum(r**2, cap_px**2)
                total += capped.sum(axis=1)
            in_front = front.sum(axis=1)
            scores[start:start + chunk] = np.where(in_front > 0, total / np.maximum(in_front, 1), np.nan)
        return scores

    def _check_prior_reach(self, normal: _Normal, covariance_prior: FloatArray, max_prior_px: float) -> None:
        """Refuse a tracks' pose so uncertain that pairing its contours with the nearest edges would be a guess.

        Its 1-sigma moves the contour points by sqrt(trace(M C)) px RMS (M: ``_Normal.mean_information``).
        """
        reach = float(np.sqrt(max(np.trace(normal.mean_information @ covariance_prior), 0.0)))
        if reach > max_prior_px:
            raise OutlineReachError(
                f"the tracks' pose is too uncertain for the outlines yet: its 1-sigma moves their contour points by "
                f"{reach:.1f} px RMS (at most {max_prior_px:g}): the nearest edges may be the wrong ones")

    def _render_where_moved(self, T: FloatArray) -> int:
        """Render the contours the pose T has moved by more than ``rerender_px``; returns how many."""
        stale = [c.contour is None or c.pixels is None or not len(c.pixels) for c in self._images]
        kept: list[tuple[int, FloatArray, FloatArray]] = [(i, c.contour.points_base, c.pixels) for i, c in
                                                          enumerate(self._images) if c.contour is not None
                                                          and c.pixels is not None and not stale[i]]
        if kept:  # every rendered contour projected from T at once
            now, _ = project_base_points(T, np.concatenate([points for _, points, _ in kept]), self.intrinsics)
            for (i, _, before), after in zip(kept, np.split(now, np.cumsum([len(p) for _, p, _ in kept])[:-1]),
                                             strict=True):
                stale[i] = bool(np.max(np.linalg.norm(after - before, axis=1)) > self.config.rerender_px)
        for cached, render in zip(self._images, stale, strict=True):
            if render:
                cached.render(self.renderer, T, self.intrinsics)
        return int(sum(stale))

    def _pairs(self, T: FloatArray) -> _Paired:
        """Every image's contour points paired with edges, linearized where each image was paired.

        An image keeps its pairs while T has moved them by less than ``repair_px`` along their normals since they were
        paired (to first order); the others are paired again at T, all at once.
        """
        kept = [c for c in self._images if c.pairs is not None]
        if kept and self.config.repair_px > 0:
            joined = self._joined(kept)
            moved = np.zeros(len(kept))
            np.maximum.at(moved, joined.pairs.image, np.abs(joined.residuals(T) - joined.r))
            for cached, far in zip(kept, moved > self.config.repair_px, strict=True):
                if far:
                    cached.forget_pairs()
        else:
            for cached in kept:
                cached.forget_pairs()
        fresh = [c for c in self._images if c.pairs is None]
        if fresh:
            contours: list[ContourPoints] = []
            for cached in fresh:
                assert cached.contour is not None
                contours.append(cached.contour)
            paired = pair_contour_points(T, contours, [cached.image.edges for cached in fresh], self.intrinsics,
                                         self.config.outline)
            assert paired.image is not None
            r, J = outline_residuals_and_jacobian(T, paired, self.intrinsics)
            for i, cached in enumerate(fresh):
                mine = paired.image == i
                cached.pairs = EdgePairs(paired.points_base[mine], paired.edge_points[mine], paired.normals[mine],
                                         image=np.zeros(int(mine.sum()), np.int64),
                                         polarity=None if paired.polarity is None else paired.polarity[mine],
                                         strength=None if paired.strength is None else paired.strength[mine])
                cached.paired_T, cached.paired_r, cached.paired_J = T, r[mine], J[mine]
        every = self._joined(self._images)
        if len(every.r) < self.config.outline.min_pairs:
            raise InsufficientMotionsError(
                f"only {len(every.r)} contour points lie within {self.config.outline.max_match_px} px of an "
                f"image edge of their direction (at least {self.config.outline.min_pairs} needed): the estimate is "
                "too far off, or the outlines are not in the images")
        return every

    @staticmethod
    def _joined(images: list[_Cached]) -> _Paired:
        """The images' pairs (each must have them) joined; ``image`` and ``pose_of`` index ``images``' order."""
        parts: list[EdgePairs] = []
        poses: list[FloatArray] = []
        pose_index: dict[int, int] = {}
        pose_of: list[int] = []
        for cached in images:
            assert cached.pairs is not None and cached.paired_T is not None
            parts.append(cached.pairs)
            pose_of.append(pose_index.setdefault(id(cached.paired_T), len(poses)))
            if pose_of[-1] == len(poses):
                poses.append(cached.paired_T)
        pairs = _concatenated(parts)
        assert pairs.image is not None
        counts = [len(p.points_base) for p in parts]
        groups = np.repeat(np.array([c.image.group for c in images], dtype=np.float64), counts)
        return _Paired(pairs, groups,
                       np.concatenate([c.paired_r for c in images if c.paired_r is not None] or [np.zeros(0)]),
                       np.concatenate([c.paired_J for c in images if c.paired_J is not None] or [np.zeros((0, 6))]),
                       poses, np.repeat(np.array(pose_of, dtype=np.int64), counts))

    def _normal(self, T: FloatArray, paired: _Paired) -> _Normal:
        """The outlines' whitened normal equations at T (Cauchy weights, scale from the residuals).

        With ``polarity_offset_px``, the edges' shift towards the brighter side (with ``polarity_direction_px``, and
        its growth along the outward normal) is estimated at T (weighted least squares under its prior) and
        eliminated: the residuals are taken with it, the information is its Schur complement, and each pair's score
        uses the Jacobian projected off it. With ``contrast_grey``, faint edges weigh less.
        """
        r, J, pairs, groups = paired.residuals(T), paired.J, paired.pairs, paired.groups
        prior_px = self.config.polarity_offset_px
        s = pairs.polarity if prior_px > 0 else None
        directions = s is not None and self.config.polarity_direction_px > 0
        sigmas = np.array([prior_px] + [self.config.polarity_direction_px] * (2 if directions else 0))
        prior_information = np.diag(sigmas**-2.0) if s is not None else np.zeros((0, 0))
        c = self.config.outline.cauchy_px
        contrast: FloatArray | float = 1.0
        if self.config.contrast_grey > 0 and pairs.strength is not None:
            contrast = np.maximum(pairs.strength**2 / (pairs.strength**2 + self.config.contrast_grey**2), 1e-3)
        S: FloatArray | None = None  # (P, m): the shift's regressors, each pair's
        offset, rho = np.zeros(len(sigmas) if s is not None else 0), r
        offset_information = np.zeros((len(offset), len(offset)))
        for _ in range(1 if s is None else 2):  # weights from the residuals, the offset, the weights again
            z = rho * np.sqrt(contrast)  # residuals on the scale of an edge of full contrast
            sigma = _robust_scale(z)
            w = contrast / (1.0 + (z / c) ** 2) / sigma**2
            if s is not None:
                S = s[:, None]
                balance = float(w @ s) / float(np.sum(w))  # the polarities' weighted mean
                if directions:  # the growth along the outward normal (``direction_centred``: of the polarity's
                    # part apart from its mean); none while either polarity weighs less than MIN_POLARITY_SHARE
                    # (with one polarity it is an image shift, a turn of the camera, and a few stray pairs would set it)
                    shared = (1.0 - abs(balance)) / 2.0 >= MIN_POLARITY_SHARE
                    centre = balance if self.config.direction_centred else 0.0
                    S = np.column_stack([s, (s - centre)[:, None] * pairs.normals * shared])
                offset_information = S.T @ (w[:, None] * S) + prior_information
                offset = -np.linalg.solve(offset_information, S.T @ (w * r))
                rho = r + S @ offset
        information = J.T @ (w[:, None] * J)
        J_reduced = J
        if S is not None:
            Q = J.T @ (w[:, None] * S)  # (6, m)
            gain = np.linalg.solve(offset_information, Q.T)  # (m, 6)
            information = information - Q @ gain
            J_reduced = J - S @ gain
        per_pair = J_reduced * (w * rho)[:, None]
        # the residuals' own robust scale (every pair alike, as ``OutlineFusion.sigma_px`` and the early check read it)
        spread = _robust_scale(rho)
        labels, index = np.unique(groups, return_inverse=True)
        scores = np.stack([np.bincount(index, weights=per_pair[:, k], minlength=len(labels)) for k in range(6)], axis=1)
        U = np.column_stack([np.ones(len(r)), pairs.normals])
        mean = information * sigma**2 / float(np.sum(w * sigma**2))
        return _Normal(0.5 * (information + information.T), J.T @ (w * rho), scores, J_reduced.T @ (w[:, None] * U),
                       spread, len(r), 0.5 * (mean + mean.T), float(offset[0]) if len(offset) else 0.0,
                       offset[1:3] if len(offset) == 3 else np.zeros(2))

    def _outline_covariance(self, normal: _Normal) -> FloatArray:
        """The outlines' covariance (6, 6): clustered by motion, the edge offsets considered."""
        A = normal.information
        G = len(normal.group_scores)
        centred = normal.group_scores - normal.group_scores.mean(axis=0)
        B = centred.T @ centred * G / max(G - 1, 1)
        A_inv = np.linalg.inv(A)
        # the clustered sandwich where it exceeds the model's covariance, in the model's eigen-directions
        cov = conservative_covariance(A_inv, A_inv @ B @ A_inv)
        offset = A_inv @ normal.offset_gradient
        cov = cov + self.config.edge_offset_px**2 * offset @ offset.T
        if self.config.floor_px > 0:
            cov += self.config.floor_px**2 * np.linalg.inv(normal.mean_information)
        return 0.5 * (cov + cov.T)


def disagreement_chi2(xi: FloatArray, prior_information: FloatArray, outline_information: FloatArray) -> float:
    """The chi-square of a pose difference xi (6,) under C_tracks + C_outline, from their (6, 6) informations P, I.

    xi^T (P - P (P + I)^-1 P) xi: (C_tracks + C_outline)^-1 in information form, well conditioned where the tracks
    leave a direction free.
    """
    P = prior_information
    return float(xi @ (P - P @ np.linalg.solve(P + outline_information, P)) @ xi)


def consistent_prior_scale(failure: OutlineDisagreementError, target_chi2: float, max_scale: float) -> float | None:
    """The least factor s in [1, max_scale] on the tracks' covariance that brings a disagreement to ``target_chi2``.

    ``disagreement_chi2`` with the tracks' information P / s, at the failure's xi and informations (to first order:
    the outlines' own pose does not move with s); bisection on log s. None when even ``max_scale`` leaves it above
    the target, or the failure does not carry them.
    """
    xi, P, I_outline = failure.xi, failure.prior_information, failure.outline_information
    if xi is None or P is None or I_outline is None:
        return None

    def chi2(scale: float) -> float:
        return disagreement_chi2(np.asarray(xi), np.asarray(P) / scale, np.asarray(I_outline))

    if chi2(1.0) <= target_chi2:
        return 1.0
    if chi2(max_scale) > target_chi2:
        return None
    lo, hi = 0.0, float(np.log(max_scale))
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi2(float(np.exp(mid))) > target_chi2 else (lo, mid)
    return float(np.exp(hi))


def _robust_scale(residuals: FloatArray) -> float:
    """px: the robust scale of residuals (P,) px, 1.4826 x their median absolute deviation, at least 0.05 px."""
    return max(1.4826 * float(np.median(np.abs(residuals - np.median(residuals)))), 0.05)


def _symmetric(matrix: FloatArray, what: str) -> FloatArray:
    """A finite symmetric (6, 6) float64 array, or InvalidInputError naming ``what``."""
    M = np.asarray(matrix, dtype=np.float64)
    if M.shape != (6, 6) or not np.all(np.isfinite(M)) or not np.allclose(M, M.T, rtol=1e-9, atol=0.0):
        raise InvalidInputError(f"{what} must be a finite symmetric (6, 6) array")
    return M


def _concatenated(parts: list[EdgePairs]) -> EdgePairs:
    """One image's pairs each (``EdgePairs.image`` all 0) joined, ``image`` the position in ``parts``."""
    if not parts:
        return EdgePairs(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros((0, 2)), image=np.zeros(0, np.int64),
                         polarity=np.zeros(0))
    polarities = [p.polarity for p in parts]
    strengths = [p.strength for p in parts]
    return EdgePairs(np.concatenate([p.points_base for p in parts]), np.concatenate([p.edge_points for p in parts]),
                     np.concatenate([p.normals for p in parts]),
                     image=np.repeat(np.arange(len(parts)), [len(p.points_base) for p in parts]),
                     polarity=None if any(p is None for p in polarities) else np.concatenate(polarities),
                     strength=None if any(p is None for p in strengths) else np.concatenate(strengths))


def _translated(T: FloatArray, shift: FloatArray) -> FloatArray:
    """T (4, 4) with its translation moved by shift (3,) m in the camera frame."""
    out = T.copy()
    out[:3, 3] += shift
    return out


def _unit(direction: FloatArray) -> FloatArray:
    """A (3,) direction normalized, or InvalidInputError."""
    u = np.asarray(direction, dtype=np.float64).reshape(-1)
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) == 0:
        raise InvalidInputError("the free direction must be a finite non-zero (3,) array")
    return u / np.linalg.norm(u)
