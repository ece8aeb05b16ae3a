"""What a candidate motion would tell the bundle adjustment: predicted tracks, their Fisher information, the gain.

With an estimate ``T_camera_base``, a candidate motion (Q, J, Delta) is scored by what the bundle adjustment
would learn from it: its predicted tracks are the projections, through the estimate, of points sampled on
the surface of the links J moves (as many tracks and frames as the calibrator keeps per motion), and
``solver.refinement.pose_information`` gives their Fisher information about the pose (omega, tau) with
every point marginalized out, exactly as the bundle adjustment does. The information of the motions
already executed and accepted is predicted the same way and summed, plus a weak prior; the candidate's
score is the D-optimal gain ``log det(I_done + I_candidate) - log det(I_done)``. Occlusion is predicted
from depth images rendered with the estimate, when the planning context has a renderer.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from planners.context import PlanningContext, SceneRenderer
from planners.informed.config import InformedPlannerConfig
from solver.arrays import FloatArray, IndexArray, evenly_spaced
from solver.camera import normalized_from_pixels
from solver.refinement import build_track_set, pose_information

#: Depth images for the occlusion prediction are up to this many times smaller per side than the
#: camera image, and no narrower than OCCLUSION_MIN_WIDTH px (else the whole image).
OCCLUSION_DOWNSCALE = 4
OCCLUSION_MIN_WIDTH = 480


@dataclass(frozen=True)
class ScoredMotion:
    """A candidate and its score.

    Attributes:
        q: (n,) rad, start configuration.
        joint: the joint that turns.
        delta: rad.
        gain: D-optimal information gain (nats); -inf when not in view.
        in_view: fraction of sampled points in view at the worse end of the sweep.
        source: "random" or "ik".
        occlusion: whether the gain accounts for occlusion (else it is an upper bound).
        tracks: tracks the bundle adjustment is expected to get (``expected_tracks``).
    """

    q: FloatArray
    joint: int
    delta: float
    gain: float
    in_view: float
    source: str
    occlusion: bool = False
    tracks: float = 0.0


class InformationModel:
    """Predicts the information motions give about ``T_camera_base``, and the tracker's yield.

    Args:
        context: what the planner reads (robot model, intrinsics, calibrator, executed motions, renderer).
        config: the informed planner's settings.
    """

    def __init__(self, context: PlanningContext, config: InformedPlannerConfig):
        self.context = context
        self.config = config
        self._tracks_per_px2 = config.prior_tracks / (
            config.prior_area * context.intrinsics.width * context.intrinsics.height)

    def predicted_information(self, q: FloatArray, joint: int, delta: float, T_camera_base: FloatArray,
                              occlusion: bool = False) -> tuple[FloatArray, float, float]:
        """Fisher information (6, 6) of (omega, tau) per sampled track a motion would give seen from the estimate.

        Args:
            q: (n,) rad, start configuration.
            joint: the joint that turns.
            delta: rad.
            T_camera_base: (4, 4) the pose estimate to project with.
            occlusion: also drop the observations that other links (or the moving links' own far
                side) would hide, from depth images rendered with the estimate at ``occlusion_frames``
                frames (needs the context's renderer; without one nothing is dropped).

        Returns:
            ((6, 6) information in (rad or m)^-2 at ``noise_px`` averaged per sampled track,
            fraction of the sampled points in view at the worse end of the sweep, projected area
            of the moving links in px^2: the convex hull of the points in view, mean of both ends).
        """
        s, c = self.context.robot, self.config
        body, local = s.surface_points(joint)
        if len(body) == 0:
            return np.zeros((6, 6)), 0.0, 0.0
        pick = np.random.default_rng(joint).choice(len(body), size=min(c.predicted_tracks, len(body)),
                                                   replace=False)
        body, local = body[pick], local[pick]
        deltas = np.linspace(0.0, delta, c.predicted_frames)
        saved = s.q
        uv = np.empty((len(deltas), len(body), 2))
        ok = np.empty((len(deltas), len(body)), dtype=bool)
        for k, d in enumerate(deltas):
            s.set_swept(q, joint, d)
            uv[k], ok[k] = s.project_points(body, local, T_camera_base, self.context.intrinsics, min_depth=0.1,
                                            margin_px=c.image_margin_px)
        in_view = float(min(ok[0].mean(), ok[-1].mean()))
        area = float(np.mean([cv2.contourArea(cv2.convexHull(uv[k][ok[k]].astype(np.float32)))
                              if ok[k].sum() >= 3 else 0.0 for k in (0, -1)]))
        renderer = self.context.renderer
        if occlusion and renderer is not None:
            checked = evenly_spaced(len(deltas), c.occlusion_frames)
            seen = np.stack([self.visible_points(renderer, q, joint, deltas[k], body, local, T_camera_base, uv[k])
                             for k in checked])
            nearest = np.abs(np.arange(len(deltas))[:, None] - checked[None, :]).argmin(axis=1)
            ok &= seen[nearest]
        s.set_q(saved)
        assert self.context.calibrator is not None
        min_frames = self.context.calibrator.config.refinement.min_track_frames
        if not (ok.sum(axis=0) >= min_frames).any():
            return np.zeros((6, 6)), in_view, area
        normalized = np.full_like(uv, np.nan)
        normalized[ok] = normalized_from_pixels(uv[ok], self.context.intrinsics)
        tracks = [(normalized[ok[:, p], p], deltas[ok[:, p]]) for p in range(len(body))]
        axis, point = s.axis_and_point(q, joint)
        info = pose_information(build_track_set([(axis, point, tracks)], self.context.intrinsics.focal, min_frames),
                                T_camera_base)
        return info / c.noise_px**2 / len(body), in_view, area

    def visible_points(self, renderer: SceneRenderer, q: FloatArray, joint: int, delta: float, body: IndexArray,
                       local: FloatArray, T_camera_base: FloatArray, uv: FloatArray) -> NDArray[np.bool_]:
        """(P,) bool: which body-fixed points the depth image rendered from the estimate shows, swept by delta rad.

        The arm (the context's robot model) is left at the swept state.

        Args:
            renderer: renders the depth image.
            q: (n,) rad, start configuration.
            joint: the joint that turns.
            delta: rad, how far it has turned at the state to render.
            body: (P,) body ids.
            local: (P, 3) m, the points in those bodies' frames.
            T_camera_base: (4, 4) the camera pose to render with.
            uv: (P, 2) px, the points' projections through it.
        """
        s = self.context.robot
        s.set_swept(q, joint, delta)
        scale = max(1, min(OCCLUSION_DOWNSCALE, self.context.intrinsics.width // OCCLUSION_MIN_WIDTH))
        depth = renderer.depth_at(s.q, T_camera_base, scale)
        h, w = depth.shape
        col = np.clip((uv[:, 0] + 0.5) / scale - 0.5, 0, w - 1).round().astype(int)
        row = np.clip((uv[:, 1] + 0.5) / scale - 0.5, 0, h - 1).round().astype(int)
        z = (s.points_base(body, local) @ T_camera_base[:3, :3].T + T_camera_base[:3, 3])[:, 2]
        return z <= depth[row, col] + self.config.occlusion_tolerance_m

    def expected_tracks(self, area_px: float) -> float:
        """Tracks the bundle adjustment is expected to get from moving links covering area_px px^2.

        The tracker's yield per projected pixel is learned from this episode: the tracks of the
        executed motions over their predicted areas, with a prior of ``prior_tracks`` tracks
        on ``prior_area`` of the image; capped at ``predicted_tracks`` (the calibrator's cap).
        """
        c = self.config
        return min(float(c.predicted_tracks), self._tracks_per_px2 * area_px)

    def information_so_far(self, T_camera_base: FloatArray, motions: Sequence[int] | None = None) -> FloatArray:
        """The prior plus the predicted information (6, 6) of the executed motions the calibrator accepted.

        ``motions`` (indices of executed motions) replaces "accepted" when given: before an
        estimate no motion is accepted yet, though those with an axis will be used.

        Also refits the tracker's yield per projected pixel (``expected_tracks``) from the
        executed motions' track counts and predicted areas.
        """
        c = self.config
        intr = self.context.intrinsics
        info = np.diag(np.r_[np.full(3, c.prior_std[0] ** -2), np.full(3, c.prior_std[1] ** -2)])
        reports = self.context.calibrator.reports if self.context.calibrator is not None else []
        tracks, area = c.prior_tracks, c.prior_area * intr.width * intr.height
        per_motion = []
        for i, (q, joint, delta) in enumerate(self.context.executed[:len(reports)]):
            motion_info, _, motion_area = self.predicted_information(q, joint, delta, T_camera_base)
            tracks += reports[i].n_tracks
            area += motion_area
            per_motion.append((reports[i], motion_info, motion_area))
        self._tracks_per_px2 = tracks / area
        for i, (report, motion_info, _) in enumerate(per_motion):
            if (report.accepted if motions is None else i in motions):
                info = info + motion_info * min(report.n_tracks, c.predicted_tracks)
        return info

    def score(self, q: FloatArray, joint: int, delta: float, T_camera_base: FloatArray, info_so_far: FloatArray,
              source: str = "", occlusion: bool = False) -> ScoredMotion:
        """The candidate's D-optimal gain log det(I + I_c) - log det(I) (-inf when not in view).

        Without ``occlusion`` the gain is an upper bound of the one with it (hiding observations
        never adds information; the expected track count comes from the same projected area).
        """
        info, in_view, area = self.predicted_information(q, joint, delta, T_camera_base, occlusion)
        tracks = self.expected_tracks(area)
        if in_view < self.config.min_in_view:
            return ScoredMotion(q, joint, delta, -np.inf, in_view, source, occlusion, tracks)
        gain = np.linalg.slogdet(info_so_far + info * tracks)[1] - np.linalg.slogdet(info_so_far)[1]
        return ScoredMotion(q, joint, delta, float(gain), in_view, source, occlusion, tracks)
