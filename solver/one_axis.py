"""A first pose from one motion's axis, the tracks of every motion and the robot's outlines (ours).

One motion's axis, seen by the camera (its direction A^c and the plane through the camera centre that holds it,
``solver.motion.MotionGeometry``), fixes the camera pose up to three numbers: the turn phi of the robot about A^c
(R = Rot(A^c, phi) R0, R0 the least rotation taking the joint's axis a_b onto A^c), and where the joint's point d_b
lies on the axis's line, which the image fixes only up to scale: at distance d from the camera, along the bearing
psi in the plane (ray(psi) = cos psi f + sin psi A^c, f the plane's direction perpendicular to A^c). So
T = [R | d ray(psi) - R d_b]. On smooth castings a motion often has an axis while the others' tracks mostly slide
(seen: as-shipped iiwa and xArm 6 at 1080p, 7 and 6 of 10 runs with no pose by motion 5, five with one axis), and
neither the linear calibration (three axes) nor the pose family (two) can start.

``search_one_axis`` scores the family on a grid with every motion's tracks (``linear_track_scores``: each track
triangulated at the pose, its residuals capped), refines its lowest basins on a finer grid, then scores their
neighbourhoods with the outlines (their contour points' capped distances to the images' edges,
``OutlineAdjustment.capped_scores``) in two narrowing rounds; the outlines pick the basin, and then whether the
axis, tilted by a few degrees, lets them fit better (a motion's axis can be degrees off). Its result is a start for
the outlines' own adjustment (``OutlineAdjustment.fuse``), which
also frees the axis's direction; the calibrator accepts it only on the outlines' tests (``Calibrator``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import minimum_filter
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.camera import pixels_from_camera_points
from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.observations import CameraIntrinsics
from solver.outline_fusion import OutlineAdjustment
from solver.refinement import TrackSet, linear_track_scores

__all__ = ["OneAxisSearch", "axis_frame", "axis_plane", "coarse_basins", "one_axis_poses", "search_one_axis",
           "visible_bearings"]


@dataclass(frozen=True)
class OneAxisSearch:
    """The grids of ``search_one_axis``.

    Attributes:
        turn_step_deg: the coarse grid's step in phi (all turns), degrees.
        bearing_step_deg: its step in psi, degrees (bearings that point into the image's neighbourhood only).
        distances: m, the joint's point is searched this far from the camera ...
        distance_samples: ... at this many log-spaced distances.
        basins: the coarse grid's lowest basins searched on (``coarse_basins``), each on the fine grid and in the
            outline rounds; the outlines pick among them. Measured on the as-shipped iiwa 1080p pose 9 (a weak axis 1.7
            degrees off): at motion 5 the tracks' lowest basin was 2.8 m off, the fourth 0.04 rad / 0.45 m off, and
            the outline rounds from the six lowest ended 21.3 px^2 (the fourth's: 0.03 rad / 20 mm off) against
            26.9-32.1 px^2 for the others; with 4 basins it has a pose at motion 5 (0.08 mm), none with 1. The other
            nine runs' first five motions: pose 0 first at motion 3 (1.7 mm; at 4 with 1), the rest the same.
        tilt_deg: the best basin's axis is then tilted by up to this, degrees, in two directions (``_tilted``), and the
            tilted family's best member kept if the outlines fit it better; 0: never. The motions' axes can be degrees
            off (as-shipped iiwa 1080p poses 3 and 5: 6.8 and 9.1), and no member of a wrong axis's family fits the
            outlines: from the true axis the same search ended at 11.8-13.9 px^2, 2-5 mm off, from theirs at
            27.7-29.5 px^2, 70-320 mm off.
        tilt_step_deg: ... in steps of this, degrees ...
        tilt_rounds: ... at most this many times, each round about the last round's best member (its axis and its
            joint's point) while the outlines' score falls. A tilt is made through the joint's point where the member
            puts it, which is off when the axis is (the family's members fit the outlines only roughly): measured on the
            as-shipped xArm 6 720p pose 9 at motion 3 (its axis 6.6 degrees off), the first round 26.67 px^2 at
            0.174 rad / 113 mm (the joint 81 mm off), the second 17.02 px^2 at 0.024 rad / 4 mm, the third no lower
            (from the true axis: 11.09 px^2, 3 mm).
        fine_turn_deg: the fine grid spans phi +- this (1-degree steps) ...
        fine_distance: ... and d within a factor of 1 +- this (11 samples), psi +- one coarse step (9 samples).
        outline_rounds: per round (phi +- degrees, psi +- degrees, d within 1 +- fraction, the cap in px), each
            13 x 9 x 11 poses about the best so far, the contours rendered at it (the tracks leave the distance along
            the line weakest: seen, an as-shipped iiwa's best fine member 1.96 m where the truth was 1.34 m) ...
        outline_stride: ... and scored with every outline_stride-th contour point ...
        outline_screen: ... (s, k): after a first ranking of all with every s-th point, the best k only
            (``OutlineAdjustment.capped_scores``); None: all. Measured on the 20 outline rounds of the as-shipped iiwa
            1080p searches (poses 0-3, 5 and 9, motions 3-5), the best member at every 2nd point ranked 0-5th at every
            8th, but for pose 9's refused searches (1st-125th: scores flat, the best two 31.165 and 31.166 px^2).
        max_tries: a calibrator searches from one motion's axis at most this many updates (each brings more
            images; seen: as-shipped iiwas found at the second and third try) ...
        max_searches: ... and at most this many in all (a search costs 10-40 s of CPU with 9-15 images at 1080p).
        track_cap_px: the tracks' residuals are capped at this, px.
        image_margin: bearings whose ray projects within this fraction of the image's size outside it are kept.
        weak_share: a motion whose rigid fit too few tracks follow for the rigid front end (below
            ``RigidAxisConfig.min_inlier_fraction``) but at least this fraction of its tracks (and
            ``RigidAxisConfig.min_tracks``) is searched from too, after the motions with an axis (its axis is used
            nowhere else: the outlines' tests decide); None: never. Measured on the as-shipped iiwa's first five
            motions of the 1080p runs that had no axis in them (poses 1, 3, 9) and of the 720p one (pose 1): at 0.15,
            weak axes 0.3 and 2.8 degrees off the truth (pose 1, 27 and 25 %), 6.8 (pose 3, 20 %), 1.7 (pose 9,
            19 %), 3.3 and 1.4 (720p pose 1, 18 and 27 %).
    """

    turn_step_deg: float = 10.0
    bearing_step_deg: float = 4.0
    distances: tuple[float, float] = (0.3, 5.0)
    distance_samples: int = 16
    fine_turn_deg: float = 10.0
    fine_distance: float = 0.15
    outline_rounds: tuple[tuple[float, float, float, float], ...] = ((12.0, 4.0, 0.35, 12.0), (3.0, 1.0, 0.08, 6.0))
    basins: int = 4
    tilt_deg: float = 12.0
    tilt_step_deg: float = 3.0
    tilt_rounds: int = 3
    outline_stride: int = 2
    outline_screen: tuple[int, int] | None = (8, 128)
    max_tries: int = 3
    max_searches: int = 6
    track_cap_px: float = 3.0
    image_margin: float = 0.5
    weak_share: float | None = 0.15

    def __post_init__(self) -> None:
        lo, hi = self.distances
        if not (0 < self.turn_step_deg <= 90 and 0 < self.bearing_step_deg <= 45 and 0 < lo < hi
                and self.distance_samples >= 2 and self.fine_turn_deg > 0 and 0 < self.fine_distance < 1
                and self.track_cap_px > 0 and self.image_margin >= 0 and self.outline_stride >= 1
                and (self.outline_screen is None or (len(self.outline_screen) == 2 and min(self.outline_screen) >= 1))
                and (self.weak_share is None or 0 < self.weak_share <= 1)
                and self.max_tries >= 1 and self.max_searches >= 1 and self.basins >= 1 and self.outline_rounds
                and self.tilt_deg >= 0 and self.tilt_step_deg > 0 and self.tilt_rounds >= 1
                and all(len(r) == 4 and min(r) > 0 and r[2] < 1 for r in self.outline_rounds)):
            raise InvalidInputError("OneAxisSearch: steps, distances, caps and rounds must be positive (fractions < 1, "
                                    "weak_share in (0, 1])")


def axis_frame(axis_base: FloatArray, axis_cam: FloatArray, reference_cam: FloatArray
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """R0 (3, 3), the least rotation taking a_b (3,) onto A^c (3,), and the unit A^c and f (3,) of the family.

    f: ``axis_plane``'s, from the reference ray (3,).
    """
    a_b = np.asarray(axis_base, dtype=np.float64) / np.linalg.norm(axis_base)
    a_c, f = axis_plane(axis_cam, reference_cam)
    R0 = Rotation.align_vectors(a_c[None], a_b[None])[0].as_matrix()
    return R0, a_c, f


def axis_plane(axis_cam: FloatArray, reference_cam: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The unit A^c (3,) and f (3,): the plane through the camera centre and the axis, f perpendicular to A^c.

    f points towards the axis's line (from the reference ray (3,), a ray towards a point of it; either sign: taken
    in front of the camera).

    Raises:
        InvalidInputError: the reference ray lies along the axis.
    """
    a_c = np.asarray(axis_cam, dtype=np.float64) / np.linalg.norm(axis_cam)
    ref = np.asarray(reference_cam, dtype=np.float64)
    ref = ref if ref[2] >= 0 else -ref  # the line through the camera centre, towards the side in front of it
    f = ref - (ref @ a_c) * a_c
    if np.linalg.norm(f) < 1e-9:
        raise InvalidInputError("the reference ray lies along the axis: the axis's plane is undefined")
    return a_c, f / np.linalg.norm(f)


def one_axis_poses(axis_base: FloatArray, point_base: FloatArray, axis_cam: FloatArray, reference_cam: FloatArray,
                   turns: FloatArray, bearings: FloatArray, distances: FloatArray) -> FloatArray:
    """(P x B x D, 4, 4) T_camera_base: the family's members at every turn (P,), bearing (B,) and distance (D,).

    Turn-major, then bearing, then distance. a_b (3,) and d_b (3,) m: the joint's axis and a point of it in the base
    frame; A^c (3,) and the reference ray (3,): the motion's axis and plane in the camera frame (module doc).
    """
    R0, a_c, f = axis_frame(axis_base, axis_cam, reference_cam)
    turns, bearings, distances = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (turns, bearings, distances))
    Rs = Rotation.from_rotvec(turns[:, None] * a_c[None, :]).as_matrix() @ R0  # (P, 3, 3)
    rays = np.cos(bearings)[:, None] * f + np.sin(bearings)[:, None] * a_c  # (B, 3)
    joint_cam = distances[None, :, None] * rays[:, None, :]  # (B, D, 3)
    t = joint_cam[None] - (Rs @ np.asarray(point_base, dtype=np.float64))[:, None, None, :]  # (P, B, D, 3)
    T = np.zeros((len(turns), len(bearings), len(distances), 4, 4))
    T[..., :3, :3] = Rs[:, None, None]
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T.reshape(-1, 4, 4)


def visible_bearings(axis_cam: FloatArray, reference_cam: FloatArray, intrinsics: CameraIntrinsics,
                     step: float, margin: float) -> FloatArray:
    """(B,) rad: the bearings psi, on a grid of ``step`` rad, at which the joint's point can be.

    Those whose ray is in front of the camera and projects into the image grown by ``margin`` of its width and height
    on every side.
    """
    a_c, f = axis_plane(axis_cam, reference_cam)
    psi = np.arange(-np.pi / 2 + step / 2, np.pi / 2, step)
    rays = np.cos(psi)[:, None] * f + np.sin(psi)[:, None] * a_c
    front = rays[:, 2] > 0.05
    if not front.any():
        return np.zeros(0)
    uv = pixels_from_camera_points(rays[front], intrinsics)
    w, h = intrinsics.width, intrinsics.height
    inside = ((uv[:, 0] >= -margin * w) & (uv[:, 0] <= (1 + margin) * w)
              & (uv[:, 1] >= -margin * h) & (uv[:, 1] <= (1 + margin) * h))
    return psi[front][inside]


def _best(scores: FloatArray) -> int:
    finite = np.where(np.isfinite(scores), scores, np.inf)
    if not np.isfinite(finite).any():
        raise InsufficientMotionsError("no member of the one-axis family sees the tracks or the outlines")
    return int(np.argmin(finite))


def coarse_basins(scores: FloatArray, count: int) -> NDArray[np.intp]:
    """The ``count`` lowest local minima of a grid's scores (T, B, D) (turn, bearing, distance): their flat indices.

    A local minimum is no higher than any of its neighbours (3 x 3 x 3, the turn wrapping round); NaN scores never
    are one. Lowest first.

    Raises:
        InsufficientMotionsError: no finite score.
    """
    finite = np.where(np.isfinite(scores), scores, np.inf)
    if not np.isfinite(finite).any():
        raise InsufficientMotionsError("no member of the one-axis family sees the tracks or the outlines")
    lowest = minimum_filter(finite, size=3, mode=("wrap", "nearest", "nearest"))
    minima = np.flatnonzero((finite == lowest) & np.isfinite(finite))
    return minima[np.argsort(finite.reshape(-1)[minima], kind="stable")][:count]


def search_one_axis(tracks: TrackSet, axis_base: FloatArray, point_base: FloatArray, axis_cam: FloatArray,
                    reference_cam: FloatArray, intrinsics: CameraIntrinsics, outlines: OutlineAdjustment,
                    config: OneAxisSearch | None = None) -> tuple[FloatArray, float]:
    """The member of one motion's family (module doc) that the tracks and then the outlines fit best.

    The coarse grid's ``OneAxisSearch.basins`` lowest basins by the tracks (``coarse_basins``) are each refined on the
    fine grid by the tracks and then in the outline rounds; the member with the lowest outline score wins, unless a
    family of the axis tilted (``OneAxisSearch.tilt_deg``, ``_tilted``) holds one the outlines fit better: then the
    tilt is made again about that one (``OneAxisSearch.tilt_rounds``).

    Args:
        tracks: every live motion's tracks (a subsample serves: ``Calibrator``'s screening set).
        axis_base: (3,) the motion's joint axis, base frame.
        point_base: (3,) m, a point of it.
        axis_cam: (3,) its axis in the camera frame (stage one) ...
        reference_cam: (3,) ... and reference ray.
        intrinsics: the camera.
        outlines: the outline stage with its images; their contours are rendered at each round's centre.
        config: the grids; ``OneAxisSearch()`` if None.

    Returns:
        T_camera_base (4, 4) and its outline score (mean capped squared distance, px^2, at the last round's cap).

    Raises:
        InsufficientMotionsError: no bearing looks at the image, or no member sees the tracks or the outlines.
    """
    cfg = config or OneAxisSearch()
    step = np.radians(cfg.bearing_step_deg)
    bearings = visible_bearings(axis_cam, reference_cam, intrinsics, step, cfg.image_margin)
    if bearings.size == 0:
        raise InsufficientMotionsError("no bearing of the axis's plane looks into the image")

    poses = _family(axis_base, point_base, axis_cam, reference_cam)

    def by_tracks(Ts: FloatArray) -> FloatArray:
        return linear_track_scores(tracks, Ts, cfg.track_cap_px)

    turns = np.radians(np.arange(0.0, 360.0, cfg.turn_step_deg))
    distances = np.geomspace(*cfg.distances, cfg.distance_samples)
    Ts, (phi, psi, d) = poses(turns, bearings, distances)
    coarse = by_tracks(Ts).reshape(len(turns), len(bearings), len(distances))
    best: tuple[FloatArray, float] | None = None
    for start in coarse_basins(coarse, cfg.basins):
        try:
            found = _refined(poses, by_tracks, outlines, cfg, phi[start], psi[start], d[start], step)
        except InsufficientMotionsError:  # no member about this basin sees the outlines
            continue
        if best is None or found[1] < best[1]:
            best = found
    if best is None:
        raise InsufficientMotionsError("no member of the one-axis family sees the outlines")
    for _ in range(cfg.tilt_rounds if cfg.tilt_deg > 0 else 0):  # each round about the last one's best member
        try:
            tilted = _tilted(axis_base, point_base, best[0], outlines, cfg)
        except InsufficientMotionsError:  # no tilted member sees the outlines
            break
        if tilted[1] >= best[1]:
            break
        best = tilted
    return best


_Family = Callable[[FloatArray, FloatArray, FloatArray], tuple[FloatArray, tuple[FloatArray, ...]]]


def _refined(poses: _Family, by_tracks: Callable[[FloatArray], FloatArray], outlines: OutlineAdjustment,
             cfg: OneAxisSearch, phi: float, psi: float, d: float, step: float) -> tuple[FloatArray, float]:
    """``search_one_axis`` from one coarse member (phi, psi rad, d m): the fine grid, then the outline rounds."""
    Ts, (phi_, psi_, d_) = poses(phi + np.radians(np.arange(-cfg.fine_turn_deg, cfg.fine_turn_deg + 0.5, 1.0)),
                                 psi + np.linspace(-step, step, 9),
                                 d * np.geomspace(1 - cfg.fine_distance, 1 + cfg.fine_distance, 11))
    i = _best(by_tracks(Ts))
    return _outline_rounds(poses, outlines, cfg, Ts[i], float(phi_[i]), float(psi_[i]), float(d_[i]))


def _outline_rounds(poses: _Family, outlines: OutlineAdjustment, cfg: OneAxisSearch, centre: FloatArray, phi: float,
                    psi: float, d: float) -> tuple[FloatArray, float]:
    """The outline rounds about the family's member (phi, psi rad, d m), the pose ``centre`` (4, 4).

    Returns the best member (4, 4) and its score (px^2, at the last round's cap).
    """
    score = float("nan")
    for turn_deg, bearing_deg, spread, cap_px in cfg.outline_rounds:
        Ts, (phis, psis, ds) = poses(phi + np.radians(np.linspace(-turn_deg, turn_deg, 13)),
                                     psi + np.radians(np.linspace(-bearing_deg, bearing_deg, 9)),
                                     d * np.geomspace(1 - spread, 1 + spread, 11))
        scores = outlines.capped_scores(centre, Ts, cap_px, cfg.outline_stride, cfg.outline_screen)
        i = _best(scores)
        centre, score, phi, psi, d = Ts[i], float(scores[i]), float(phis[i]), float(psis[i]), float(ds[i])
    return centre, score


def _tilted(axis_base: FloatArray, point_base: FloatArray, T: FloatArray, outlines: OutlineAdjustment,
            cfg: OneAxisSearch) -> tuple[FloatArray, float]:
    """The family of a tilted axis that the outlines fit best, about the member T (4, 4): its best pose and score.

    T's axis A^c (the joint's axis a_b (3,) seen from T) is turned by up to ``OneAxisSearch.tilt_deg`` about the
    normal of its plane and about f (``axis_plane``: the plane through the camera centre and the joint's point d_b
    (3,) where T puts it), through that point; each tilted family is scored there (three distances) and at turns about
    the one nearest T's rotation (the first outline round's reach and cap), the best tilt then refined in the outline
    rounds. For a member of a family, A^c and its plane are the family's own.
    """
    joint = T[:3, :3] @ np.asarray(point_base, dtype=np.float64) + T[:3, 3]  # the joint's point, camera frame
    d = float(np.linalg.norm(joint))
    reference = joint / d  # every tilted axis's line runs through it
    a_c, f = axis_plane(T[:3, :3] @ np.asarray(axis_base, dtype=np.float64), reference)
    normal = np.cross(a_c, f)
    turn_deg, _, _, cap_px = cfg.outline_rounds[0]
    turns = np.radians(np.linspace(-turn_deg, turn_deg, 13))
    scales = np.array([0.9, 1.0, 1.1])
    angles = np.radians(np.arange(-cfg.tilt_deg, cfg.tilt_deg + 1e-9, cfg.tilt_step_deg))
    families: list[tuple[FloatArray, float, float]] = []  # (A', phi, psi)
    members: list[FloatArray] = []
    for alpha in angles:
        for beta in angles:
            axis = Rotation.from_rotvec(alpha * normal).apply(Rotation.from_rotvec(beta * f).apply(a_c))
            if np.linalg.norm(np.cross(axis, reference)) < 1e-6:  # the tilted axis points at the camera
                continue
            R0, tilted_a, tilted_f = axis_frame(axis_base, axis, reference)
            x, y, z, w = Rotation.from_matrix(T[:3, :3] @ R0.T).as_quat()  # the turn about A' nearest T's rotation
            phi = 2.0 * float(np.arctan2(np.array([x, y, z]) @ tilted_a, w))
            psi = float(np.arctan2(joint @ tilted_a, joint @ tilted_f))
            families.append((axis, phi, psi))
            members.append(one_axis_poses(axis_base, point_base, axis, reference, phi + turns, np.array([psi]),
                                          d * scales))
    if not members:
        raise InsufficientMotionsError("every tilted axis points at the camera")
    scores = outlines.capped_scores(T, np.concatenate(members), cap_px, cfg.outline_stride, cfg.outline_screen)
    k, j = divmod(_best(scores), len(turns) * len(scales))
    axis, phi, psi = families[k]
    return _outline_rounds(_family(axis_base, point_base, axis, reference), outlines, cfg, members[k][j],
                           phi + turns[j // len(scales)], psi, d * scales[j % len(scales)])


def _family(axis_base: FloatArray, point_base: FloatArray, axis_cam: FloatArray, reference_cam: FloatArray) -> _Family:
    """The family's members on a grid of turns, bearings and distances: (P, 4, 4), and each one's three numbers."""

    def poses(turns: FloatArray, bearings: FloatArray, distances: FloatArray
              ) -> tuple[FloatArray, tuple[FloatArray, ...]]:
        grid = np.meshgrid(turns, bearings, distances, indexing="ij")
        return (one_axis_poses(axis_base, point_base, axis_cam, reference_cam, turns, bearings, distances),
                tuple(g.reshape(-1) for g in grid))

    return poses
