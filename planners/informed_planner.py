"""Informed exploratory motions (ours): the safe candidate that adds the most information about the pose.

Criterion. With an estimate T of ``T_camera_base``, a candidate motion (Q, J, Delta) is scored by
what the bundle adjustment would learn from it: its predicted tracks are the projections, through
T, of points sampled on the surface of the links that J moves (as many tracks and frames as the
calibrator keeps per motion), and ``solver.refinement.pose_information`` gives their Fisher
information about the pose (omega, tau) with every point marginalized out, exactly as the bundle
adjustment does (each point is an unknown). The information of the motions already executed and
accepted is predicted the same way with the current T and summed, plus a weak prior; the
candidate's score is the D-optimal gain

    gain = log det(I_done + I_candidate) - log det(I_done),

the expected shrinkage of the uncertainty ellipsoid's volume. D-optimality is invariant to the
units of rotation and translation (a rescaling of the parameters changes both determinants by the
same factor), so no weighting of radians against metres is needed, and it rewards what the pose
still lacks: a motion that repeats information already held gains little. Degenerate motions
score low by construction, with no hand-made penalty: a joint whose axis points at the camera
moves its points in a plane parallel to the image, which leaves the depth along the axis to the
unknown points (the marginalization removes it); tiny projected circles carry little information
per pixel of noise; points that leave the image or go behind the camera are dropped from the
prediction, and a candidate whose moving links are not in view at both ends of the sweep (with a
margin) is not considered. Occlusion (by other links, or a link's own far side) is predicted for the
best valid candidates only, since it needs rendering: depth images rendered with T at a few frames
of the sweep hide the points behind a nearer surface; as hiding observations can only lower the
gain, the unoccluded gain bounds it from above, and a rescored candidate that falls below the next
one gives way to it (lazy evaluation); after ``occlusion_checks`` rescorings the best rescored
candidate is taken.

Candidates. Random (Q, J, Delta) as in the paper, plus IK-seeded ones: mink places the arm's last
link at a random pixel of the central image at a depth near the arm's, seen with T, so the
moving links are large and whole in view. The best-scoring candidates are checked by the
environment (limits, collisions over the sweep) in order, and the first valid one is returned.

Before any estimate exists (the first motions), there is nothing to project with, yet the
linear calibration needs three motions whose ellipses stage one can read and whose axis lines
fix the pose. Valid random candidates are scored by (1) the expected ellipse quality of their
axis under a belief about the camera's viewing direction in the base frame, which stage one's
verdicts on the executed motions sharpen (a recovered camera-frame axis gives the cosine between
the axis and the optical axis; "lines, not ellipses" says it was seen edge-on); (2) the novelty
of their axis line against the motions that gave an axis (angle and distance: lines that all
meet in one point cannot fix depth); (3) |Delta|. Of the best few, the one whose start and end
frames differ in the most pixels (the image test a real robot does with two snapshots) is chosen.

Between two axes and the first estimate. Two motions whose axes stage one recovered (not
parallel) already fix the rotation and two of the translation's three components; what they leave
free is the distance along one ray from the camera (``solver.calibration.pose_family``: each
motion's circles fix its axis only up to the axis' own distance). The third motion is the one that
fixes it best, so from then on candidates are scored as above with the D-optimal gain, averaged over
``n_hypotheses`` members of that family that put the arm's axes in front of the camera at depths
spread over ``hypothesis_depths`` (the one assumption: the camera is 0.5-3 m from the arm), and
weighted by the ellipse quality of the axis seen with the known rotation and by the expected
track count, since the linear calibration needs stage one to read the motion's ellipses (edge-on
circles are lines; a few short arcs leave the axis ambiguous). This
replaces the bootstrap's proxies (posterior viewing direction, line novelty) with the prediction
itself once R is known: ellipse quality, visibility and the information about the free depth.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planners.ik import IKSolver, target_in_view
from planners.random_planner import image_change, prepare_image_test
from planners.sampling import check_sampling, random_delta, random_motion, random_q
from solver.calibration import AxisCorrespondence, pose_family
from solver.camera import normalized_from_pixels
from solver.errors import ArcCalibError, InvalidInputError
from solver.frames import transform_from_rt
from solver.motion import LINES_NOT_ELLIPSES, fibonacci_sphere
from solver.refinement import build_track_set, pose_information

if TYPE_CHECKING:
    from arc_env.env import ArcCalibEnv

FloatArray = NDArray[np.float64]
#: Depth images for the occlusion prediction are up to this many times smaller per side than the
#: camera image, and no narrower than OCCLUSION_MIN_WIDTH px (else the whole image).
OCCLUSION_DOWNSCALE = 4
OCCLUSION_MIN_WIDTH = 480
#: m; pose hypotheses are searched this far either side of the least-norm member of the family.
HYPOTHESIS_RANGE_M = 6.0


@dataclass(frozen=True)
class InformedPlannerConfig:
    """Settings of ``InformedPlanner``.

    Attributes:
        delta_range: (min, max) rad of |Delta| of candidates (the env's limits apply on top).
        limit_margin: fraction of each joint's range kept from its limits when sampling Q.
        n_random: random candidates scored per call.
        n_ik: IK-seeded candidates scored per call.
        n_validate: best-scoring candidates checked by the environment before drawing new ones.
        max_rounds: rounds of drawing, scoring and checking before giving up.
        predicted_tracks: tracks per predicted motion (the calibrator keeps 40 in the env).
        predicted_frames: frames per predicted track (the calibrator keeps 15).
        noise_px: assumed pixel noise of a track, px (scales the motions' information against
            the prior).
        prior_std: (rotation rad, translation m) 1-sigma of the weak prior that makes the
            information of the first motions invertible.
        image_margin_px: px; predicted points must be this far inside the image.
        min_in_view: fraction of the moving links' sampled points that must be in view at both
            ends of the sweep.
        ik_region: fraction of the image width/height (centred) where IK targets are drawn.
        ik_depth_spread: m; IK target depths are the arm's current depth +- this.
        full_radius_m: m; before an estimate, motions whose moving points lie (median) closer
            to the axis than this are discounted in proportion.
        prior_tracks: tracks of the prior on the tracker's yield (``expected_tracks``) ...
        prior_area: ... on this fraction of the image's area.
        bootstrap_candidates: candidates drawn per round before an estimate exists (the best
            ``n_validate`` are checked by the environment).
        bootstrap_image_tests: of those, how many (best scores first) get the image test.
        changed_fraction_full: fraction of pixels changing between the sweep's end frames at
            which the image test no longer discounts a candidate (below it the score scales down:
            small moving links give few tracks).
        occlusion_checks: valid candidates per call whose gain is recomputed with predicted
            occlusion (depth images rendered with the estimate), best first; 0 turns it off.
        occlusion_frames: frames of the sweep at which occlusion is predicted (evenly spread;
            every frame takes the verdict of the nearest).
        occlusion_tolerance_m: m; a point is hidden when the rendered surface at its pixel is
            nearer than the point by more than this.
        n_hypotheses: pose hypotheses planned with once two motions gave axes but no estimate
            exists (``pose_hypotheses``); 0 keeps the bootstrap score until the first estimate.
        hypothesis_depths: (min, max) m; the depths of the arm's axes the hypotheses may put them
            at (the camera is assumed this far from the arm).
        min_axis_angle: rad; the axes must span at least this angle for the hypotheses (two
            nearly parallel axes fix the rotation about them poorly).
    """

    delta_range: tuple[float, float] = (0.6, 1.5)
    limit_margin: float = 0.05
    n_random: int = 32
    n_ik: int = 8
    n_validate: int = 12
    max_rounds: int = 6
    predicted_tracks: int = 40
    predicted_frames: int = 15
    noise_px: float = 0.5
    prior_std: tuple[float, float] = (0.1, 0.1)
    image_margin_px: float = 20.0
    min_in_view: float = 0.7
    ik_region: float = 0.6
    ik_depth_spread: float = 0.25
    full_radius_m: float = 0.25
    prior_tracks: float = 40.0
    prior_area: float = 0.03
    bootstrap_candidates: int = 32
    bootstrap_image_tests: int = 2
    changed_fraction_full: float = 0.03
    occlusion_checks: int = 4
    occlusion_frames: int = 3
    occlusion_tolerance_m: float = 0.02
    n_hypotheses: int = 3
    hypothesis_depths: tuple[float, float] = (0.5, 3.0)
    min_axis_angle: float = 0.3

    def __post_init__(self) -> None:
        check_sampling(self.delta_range, self.limit_margin)
        if self.n_random + self.n_ik < 1 or self.n_validate < 1 or self.max_rounds < 1:
            raise InvalidInputError("need n_random + n_ik >= 1, n_validate >= 1, max_rounds >= 1")
        if self.predicted_tracks < 1 or self.predicted_frames < 4:
            raise InvalidInputError("predicted_tracks must be >= 1 and predicted_frames >= 4")
        if self.noise_px <= 0 or min(self.prior_std) <= 0:
            raise InvalidInputError("noise_px and prior_std must be > 0")
        if self.bootstrap_candidates < 1 or self.bootstrap_image_tests < 0:
            raise InvalidInputError("bootstrap_candidates must be >= 1, bootstrap_image_tests >= 0")
        if self.occlusion_checks < 0 or self.occlusion_frames < 2 or self.occlusion_tolerance_m <= 0:
            raise InvalidInputError("need occlusion_checks >= 0, occlusion_frames >= 2, occlusion_tolerance_m > 0")
        if self.n_hypotheses < 0 or not 0 < self.hypothesis_depths[0] < self.hypothesis_depths[1]:
            raise InvalidInputError("need n_hypotheses >= 0 and 0 < hypothesis_depths[0] < hypothesis_depths[1]")


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


class InformedPlanner:
    """Chooses the valid exploratory motion with the largest predicted information gain.

    Same interface as ``RandomPlanner``: ``plan(observation)`` returns an env action.

    Args:
        env: the environment (robot model, collision checks, camera image, executed motions and
            the calibrator's verdicts on them).
        rng: random generator; None seeds one from the env's ``np_random``.
        config: settings.
    """

    def __init__(self, env: ArcCalibEnv, rng: np.random.Generator | None = None,
                 config: InformedPlannerConfig | None = None):
        self.env = env
        self.rng = rng if rng is not None else np.random.default_rng(env.np_random.integers(2**31 - 1))
        self.config = config or InformedPlannerConfig()
        self.ik = IKSolver(env.scene)
        self._tracks_per_px2 = self.config.prior_tracks / (
            self.config.prior_area * env.intrinsics.width * env.intrinsics.height)
        self._sphere = fibonacci_sphere(2000)
        if self.config.bootstrap_image_tests:
            prepare_image_test(env.scene)
        #: the candidates scored by the last ``plan`` call (best first), for inspection.
        self.last_candidates: list[ScoredMotion] = []

    # -- sampling ------------------------------------------------------------------------------
    def _delta_range(self) -> tuple[float, float]:
        c, env = self.config, self.env.config
        return max(c.delta_range[0], env.min_delta), min(c.delta_range[1], env.max_delta)

    def _random_candidate(self) -> tuple[FloatArray, int, float] | None:
        return random_motion(self.env.scene, self.rng, self.config.limit_margin, self._delta_range())

    def _ik_candidate(self, T: FloatArray) -> tuple[FloatArray, int, float] | None:
        s, c = self.env.scene, self.config
        intr = self.env.intrinsics
        tip = int(s.model.jnt_bodyid[s.arm_joints[-1]])
        depth_now = float((T[:3, :3] @ s.points_base(np.array([tip]), np.zeros((1, 3)))[0] + T[:3, 3])[2])
        depth = max(0.3, depth_now + self.rng.uniform(-c.ik_depth_spread, c.ik_depth_spread))
        half = 0.5 * c.ik_region
        pixel = np.array([intr.width * self.rng.uniform(0.5 - half, 0.5 + half),
                          intr.height * self.rng.uniform(0.5 - half, 0.5 + half)])
        result = self.ik.solve(tip, target_in_view(T, intr, pixel, depth), random_q(s, self.rng, c.limit_margin))
        if not result.reached:
            return None
        joint = int(self.rng.integers(s.n_joints))
        delta = random_delta(s, self.rng, result.q, joint, self._delta_range())
        return None if delta is None else (result.q, joint, delta)

    # -- prediction ----------------------------------------------------------------------------
    def predicted_information(self, q: FloatArray, joint: int, delta: float, T: FloatArray,
                              occlusion: bool = False) -> tuple[FloatArray, float, float]:
        """Fisher information (6, 6) of (omega, tau) per sampled track a motion would give seen with T.

        Args:
            q: (n,) rad, start configuration.
            joint: the joint that turns.
            delta: rad.
            T: (4, 4) the pose estimate to project with.
            occlusion: also drop the observations that other links (or the moving links' own far
                side) would hide, from depth images rendered with T at ``occlusion_frames`` frames.

        Returns:
            ((6, 6) information in (rad or m)^-2 at ``noise_px`` averaged per sampled track,
            fraction of the sampled points in view at the worse end of the sweep, projected area
            of the moving links in px^2: the convex hull of the points in view, mean of both ends).
        """
        s, c = self.env.scene, self.config
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
            uv[k], ok[k] = s.project_points(body, local, T, min_depth=0.1, margin_px=c.image_margin_px)
        in_view = float(min(ok[0].mean(), ok[-1].mean()))
        area = float(np.mean([cv2.contourArea(cv2.convexHull(uv[k][ok[k]].astype(np.float32)))
                              if ok[k].sum() >= 3 else 0.0 for k in (0, -1)]))
        if occlusion:
            checked = np.unique(np.linspace(0, len(deltas) - 1, c.occlusion_frames).round().astype(int))
            seen = np.stack([self.visible_points(q, joint, deltas[k], body, local, T, uv[k]) for k in checked])
            nearest = np.abs(np.arange(len(deltas))[:, None] - checked[None, :]).argmin(axis=1)
            ok &= seen[nearest]
        s.set_q(saved)
        min_frames = self.env.config.calibrator.refinement.min_track_frames
        if not (ok.sum(axis=0) >= min_frames).any():
            return np.zeros((6, 6)), in_view, area
        normalized = np.full_like(uv, np.nan)
        normalized[ok] = normalized_from_pixels(uv[ok], self.env.intrinsics)
        tracks = [(normalized[ok[:, p], p], deltas[ok[:, p]]) for p in range(len(body))]
        axis, point = s.axis_and_point(q, joint)
        info = pose_information(build_track_set([(axis, point, tracks)], self.env.intrinsics.focal, min_frames), T)
        return info / c.noise_px**2 / len(body), in_view, area

    def visible_points(self, q: FloatArray, joint: int, delta: float, body: NDArray[np.int64], local: FloatArray,
                       T: FloatArray, uv: FloatArray) -> NDArray[np.bool_]:
        """(P,) bool: which body-fixed points the depth image rendered with T shows, swept by delta rad.

        The arm is left at the swept state.

        Args:
            q: (n,) rad, start configuration.
            joint: the joint that turns.
            delta: rad, how far it has turned at the state to render.
            body: (P,) body ids.
            local: (P, 3) m, the points in those bodies' frames.
            T: (4, 4) the camera pose to render with.
            uv: (P, 2) px, the points' projections through it.
        """
        s = self.env.scene
        s.set_swept(q, joint, delta)
        scale = max(1, min(OCCLUSION_DOWNSCALE, self.env.intrinsics.width // OCCLUSION_MIN_WIDTH))
        depth = s.depth(T, scale)
        h, w = depth.shape
        col = np.clip((uv[:, 0] + 0.5) / scale - 0.5, 0, w - 1).round().astype(int)
        row = np.clip((uv[:, 1] + 0.5) / scale - 0.5, 0, h - 1).round().astype(int)
        z = (s.points_base(body, local) @ T[:3, :3].T + T[:3, 3])[:, 2]
        return z <= depth[row, col] + self.config.occlusion_tolerance_m

    def expected_tracks(self, area_px: float) -> float:
        """Tracks the bundle adjustment is expected to get from moving links covering area_px px^2.

        The tracker's yield per projected pixel is learned from this episode: the tracks of the
        executed motions over their predicted areas, with a prior of ``prior_tracks`` tracks
        on ``prior_area`` of the image; capped at ``predicted_tracks`` (the calibrator's cap).
        """
        c = self.config
        return min(float(c.predicted_tracks), self._tracks_per_px2 * area_px)

    def information_so_far(self, T: FloatArray, motions: Sequence[int] | None = None) -> FloatArray:
        """The prior plus the predicted information (6, 6) of the executed motions the calibrator accepted.

        ``motions`` (indices of executed motions) replaces "accepted" when given: before an
        estimate no motion is accepted yet, though those with an axis will be used.

        Also refits the tracker's yield per projected pixel (``expected_tracks``) from the
        executed motions' track counts and predicted areas.
        """
        c = self.config
        intr = self.env.intrinsics
        info = np.diag(np.r_[np.full(3, c.prior_std[0] ** -2), np.full(3, c.prior_std[1] ** -2)])
        reports = self.env.calibrator.reports if self.env.calibrator is not None else []
        tracks, area = c.prior_tracks, c.prior_area * intr.width * intr.height
        per_motion = []
        for i, (q, joint, delta) in enumerate(self.env.executed[:len(reports)]):
            motion_info, _, motion_area = self.predicted_information(q, joint, delta, T)
            tracks += reports[i].n_tracks
            area += motion_area
            per_motion.append((reports[i], motion_info, motion_area))
        self._tracks_per_px2 = tracks / area
        for i, (report, motion_info, _) in enumerate(per_motion):
            if (report.accepted if motions is None else i in motions):
                info = info + motion_info * min(report.n_tracks, c.predicted_tracks)
        return info

    def score(self, q: FloatArray, joint: int, delta: float, T: FloatArray, info_so_far: FloatArray,
              source: str = "", occlusion: bool = False) -> ScoredMotion:
        """The candidate's D-optimal gain log det(I + I_c) - log det(I) (-inf when not in view).

        Without ``occlusion`` the gain is an upper bound of the one with it (hiding observations
        never adds information; the expected track count comes from the same projected area).
        """
        info, in_view, area = self.predicted_information(q, joint, delta, T, occlusion)
        tracks = self.expected_tracks(area)
        if in_view < self.config.min_in_view:
            return ScoredMotion(q, joint, delta, -np.inf, in_view, source, occlusion, tracks)
        gain = np.linalg.slogdet(info_so_far + info * tracks)[1] - np.linalg.slogdet(info_so_far)[1]
        return ScoredMotion(q, joint, delta, float(gain), in_view, source, occlusion, tracks)

    # -- planning ------------------------------------------------------------------------------
    def plan(self, observation: dict[str, Any]) -> dict[str, Any]:
        """The next motion as an env action {"Q", "J", "delta"}.

        Raises:
            InvalidInputError: no valid, visible motion was found.
        """
        if int(observation.get("has_estimate", 0)):
            R = Rotation.from_rotvec(np.asarray(observation["rotation"], dtype=np.float64)).as_matrix()
            return self._plan_informed(transform_from_rt(R, np.asarray(observation["translation"], dtype=np.float64)))
        hypotheses = self.pose_hypotheses()
        if hypotheses:
            return self._plan_hypotheses(hypotheses)
        return self._plan_bootstrap()

    def _plan_informed(self, T: FloatArray) -> dict[str, Any]:
        return self._plan_scored([T], [self.information_so_far(T)])

    def _score_all(self, q: FloatArray, joint: int, delta: float, poses: list[FloatArray],
                   so_far: list[FloatArray], source: str, occlusion: bool = False,
                   need_axis: bool = False) -> ScoredMotion:
        """``score`` averaged over pose hypotheses (a hypothesis that loses the links from view adds 0).

        With ``need_axis`` (no estimate yet: the motion must give stage one an axis for the linear
        calibration) the gain is weighted by ``ellipse_quality`` of the axis seen with the
        hypotheses' rotation (they share it), since edge-on circles are lines to stage one, and by
        the expected tracks over ``predicted_tracks`` (at most 1), since few short arcs leave the
        axis ambiguous (seen: 21 tracks of the hand, two axes fitting within 1.09x).
        """
        scored = [self.score(q, joint, delta, T, info, source, occlusion)
                  for T, info in zip(poses, so_far, strict=True)]
        if len(scored) == 1 and not need_axis:
            return scored[0]
        gains = np.array([m.gain for m in scored])
        gain = float(np.mean(np.where(np.isfinite(gains), gains, 0.0))) if np.isfinite(gains).any() else -np.inf
        tracks = float(np.mean([m.tracks for m in scored]))
        if need_axis and np.isfinite(gain):
            axis_cam = poses[0][:3, :3] @ self.env.scene.axis_and_point(q, joint)[0]
            gain *= float(self.ellipse_quality(np.array([axis_cam[2]]))[0])
            gain *= min(1.0, tracks / self.config.predicted_tracks)
        return ScoredMotion(q, joint, delta, gain, max(m.in_view for m in scored), source, occlusion, tracks)

    def _plan_scored(self, poses: list[FloatArray], so_far: list[FloatArray], need_axis: bool = False,
                     ) -> dict[str, Any]:
        c = self.config
        mid = len(poses) // 2
        ik_pose = poses[mid]
        for _ in range(c.max_rounds):
            scored: list[ScoredMotion] = []
            for k in range(c.n_random + c.n_ik):
                source = "random" if k < c.n_random else "ik"
                try:
                    cand = self._random_candidate() if source == "random" else self._ik_candidate(ik_pose)
                except ArcCalibError:
                    cand = None
                if cand is None:
                    continue
                # several hypotheses: screen every candidate with the middle one, average the best over all
                sm = self._score_all(*cand, poses[mid:mid + 1], so_far[mid:mid + 1], source, need_axis=need_axis)
                if np.isfinite(sm.gain):
                    scored.append(sm)
            scored.sort(key=lambda m: -m.gain)
            if len(poses) > 1:
                scored = [self._score_all(m.q, m.joint, m.delta, poses, so_far, m.source, need_axis=need_axis)
                          for m in scored[:c.n_validate]]
                scored = sorted((m for m in scored if np.isfinite(m.gain)), key=lambda m: -m.gain)
            self.last_candidates = scored
            # best first: check validity; a valid candidate whose gain ignores occlusion is rescored
            # with it and goes back into the queue, since its gain can only drop. Once the checks are
            # spent, the best rescored candidate wins over the unchecked ones.
            queue, checks = scored[:c.n_validate], 0
            while queue:
                m = queue.pop(0)
                if m.occlusion:
                    return {"Q": m.q, "J": m.joint, "delta": np.array([m.delta])}
                if self.env.validate(m.q, m.joint, m.delta):
                    continue
                if checks >= c.occlusion_checks:
                    m = next((x for x in queue if x.occlusion), m)
                    return {"Q": m.q, "J": m.joint, "delta": np.array([m.delta])}
                checks += 1
                exact = self._score_all(m.q, m.joint, m.delta, poses, so_far, m.source, occlusion=True,
                                        need_axis=need_axis)
                if np.isfinite(exact.gain):
                    queue.append(exact)
                    queue.sort(key=lambda x: -x.gain)
        raise InvalidInputError(f"no valid, visible motion in {c.max_rounds} rounds of "
                                f"{c.n_random + c.n_ik} candidates")

    def pose_hypotheses(self) -> list[FloatArray]:
        """Poses (4, 4) to plan with before an estimate, once two motions gave non-parallel axes.

        Two axes fix the rotation and two components of the translation
        (``solver.calibration.pose_family``); the third, the distance along a ray from the camera,
        stays free until a third motion. The members kept put each axis where it crosses the ray
        to its circles' centres (D^c) in front of the camera, with the axes' mean point at a depth within
        ``hypothesis_depths``; ``n_hypotheses`` of them, evenly spread in that depth, are returned
        (empty: fewer than two axes, all within ``min_axis_angle`` of parallel, or no member in range).
        """
        c, s = self.config, self.env.scene
        calibrator = self.env.calibrator
        if calibrator is None or c.n_hypotheses < 1:
            return []
        cors, refs = [], []
        for i, (q, joint, _) in enumerate(self.env.executed[:len(calibrator.reports)]):
            geometry = calibrator.motion_geometry(i)
            if geometry is not None:
                axis, point = s.axis_and_point(q, joint)
                cors.append(AxisCorrespondence(axis, point, geometry.axis_cam, geometry.plane_normal))
                refs.append(geometry.reference_cam * np.sign(geometry.reference_cam[2]))  # the ray in front
        if len(cors) < 2:
            return []
        axes = np.array([cor.axis_base for cor in cors])
        if np.linalg.svd(axes, compute_uv=False)[1] < np.sin(c.min_axis_angle):
            return []  # nearly parallel axes leave the rotation about them poorly fixed
        try:
            R, t0, u = pose_family(cors)
        except ArcCalibError:
            return []
        ts = t0 + np.linspace(-HYPOTHESIS_RANGE_M, HYPOTHESIS_RANGE_M, 2001)[:, None] * u  # (S, 3)
        ok = np.ones(len(ts), dtype=bool)
        for cor, ref in zip(cors, refs, strict=True):
            p = (R @ cor.point_base)[None, :] + ts  # (S, 3) a point of the axis, camera frame
            a = R @ cor.axis_base
            foot = p - (p @ a)[:, None] * a  # the axis' point nearest the camera centre
            ok &= foot @ ref > 0  # the axis crosses the ray to its circles' centres in front of the camera
        depth = (R @ np.mean([cor.point_base for cor in cors], axis=0))[2] + ts[:, 2]  # (S,) m
        ok &= (depth >= c.hypothesis_depths[0]) & (depth <= c.hypothesis_depths[1])
        if not ok.any():
            return []
        lo, hi = depth[ok].min(), depth[ok].max()
        picks = []
        for target in np.linspace(lo, hi, c.n_hypotheses + 2)[1:-1]:
            k = int(np.argmin(np.where(ok, np.abs(depth - target), np.inf)))
            picks.append(transform_from_rt(R, ts[k]))
        return picks

    def _plan_hypotheses(self, poses: list[FloatArray]) -> dict[str, Any]:
        calibrator = self.env.calibrator
        with_axis = [i for i in range(len(calibrator.reports)) if calibrator.motion_geometry(i) is not None]
        return self._plan_scored(poses, [self.information_so_far(T, with_axis) for T in poses], need_axis=True)

    def view_direction_posterior(self) -> tuple[FloatArray, FloatArray]:
        """Belief about the camera's optical axis in the base frame, from stage one's verdicts.

        With R of T_camera_base, v = R^T e_z is the optical axis in the base frame, and a motion
        whose axis stage one recovered gives v . a_base = (R a_base)_z = the z of its camera-frame
        axis; a motion stage one found to be "lines, not ellipses" was seen nearly edge-on,
        |v . a_base| small. A weak prior says the camera looks down or level rather than up.

        Returns:
            directions (N, 3) unit vectors (a Fibonacci sphere) and weights (N,) summing to 1.
        """
        dirs = self._sphere
        cost = 0.5 * (np.maximum(0.0, dirs[:, 2] - 0.2) / 0.1) ** 2
        calibrator = self.env.calibrator
        if calibrator is not None:
            for i, (q, joint, _) in enumerate(self.env.executed[:len(calibrator.reports)]):
                axis = self.env.scene.axis_and_point(q, joint)[0]
                dots = dirs @ axis
                geometry = calibrator.motion_geometry(i)
                if geometry is not None:
                    cost += 0.5 * ((dots - geometry.axis_cam[2]) / 0.1) ** 2
                elif calibrator.reports[i].stage_one.startswith(LINES_NOT_ELLIPSES):
                    cost += 0.5 * (np.maximum(0.0, np.abs(dots) - 0.15) / 0.05) ** 2
        w = np.exp(-(cost - cost.min()))
        return dirs, w / w.sum()

    @staticmethod
    def ellipse_quality(cos_view: FloatArray) -> FloatArray:
        """How well stage one sees a circle whose axis makes |cos| = cos_view with the optical axis, 0..1.

        Edge-on circles (|cos| < ~0.12) project to lines; between about 0.3 and 0.95 the ellipse's
        shape fixes the circle's normal well; head-on circles (|cos| -> 1) leave the two normal
        candidates close and can be ambiguous.
        """
        c = np.abs(cos_view)
        return np.clip((c - 0.12) / 0.2, 0.0, 1.0) * np.where(c > 0.95, 0.6, 1.0)

    @staticmethod
    def line_distance(p1: FloatArray, a1: FloatArray, p2: FloatArray, a2: FloatArray) -> float:
        """Closest-approach distance (m) between the lines p1 + s a1 and p2 + s a2 (unit a1, a2)."""
        n = np.cross(a1, a2)
        if np.linalg.norm(n) < 1e-6:
            return float(np.linalg.norm(np.cross(p2 - p1, a1)))
        return float(abs((p2 - p1) @ n) / np.linalg.norm(n))

    def bootstrap_score(self, q: FloatArray, joint: int, delta: float,
                        posterior: tuple[FloatArray, FloatArray]) -> float:
        """Score of a motion before any estimate: ellipse quality x novelty x size x |Delta|.

        Quality is expected under ``view_direction_posterior``; size is the median distance of
        the moving links' surface points from the axis over ``full_radius_m`` (at most 1): a hand
        turning about its own axis sweeps small arcs and gives few tracks.

        Novelty is against the executed motions that gave an axis (what the linear calibration
        will use): the smallest angle to their axes and the smallest distance to their lines, so
        that three motions fix the rotation and the translation (axes that all meet in one point,
        like the Panda's joints 1-3, cannot fix depth).
        """
        s = self.env.scene
        axis, point = s.axis_and_point(q, joint)
        dirs, w = posterior
        quality = float(w @ self.ellipse_quality(dirs @ axis))
        angle, dist = np.pi / 2, 0.15
        calibrator = self.env.calibrator
        for i, (qe, je, _) in enumerate(self.env.executed):
            if calibrator is None or i >= len(calibrator.reports) or calibrator.motion_geometry(i) is None:
                continue
            ae, pe = s.axis_and_point(qe, je)
            angle = min(angle, float(np.arccos(min(1.0, abs(float(axis @ ae))))))
            dist = min(dist, self.line_distance(point, axis, pe, ae))
        novelty = (0.25 + angle / (np.pi / 2)) * (0.25 + dist / 0.15)
        body, local = s.surface_points(joint)
        if len(body) == 0:
            return 0.0
        saved = s.q
        s.set_q(q)
        rel = s.points_base(body, local) - point
        s.set_q(saved)
        radius = float(np.median(np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)))
        size = min(1.0, radius / self.config.full_radius_m)
        return quality * novelty * size * abs(delta) / self.env.config.max_delta

    def _plan_bootstrap(self) -> dict[str, Any]:
        c = self.config
        posterior = self.view_direction_posterior()
        for _ in range(c.max_rounds):
            drawn = [cand for cand in (self._random_candidate() for _ in range(c.bootstrap_candidates))
                     if cand is not None]
            ranked = sorted(((self.bootstrap_score(*cand, posterior), *cand) for cand in drawn),
                            key=lambda v: -v[0])
            needed = max(1, c.bootstrap_image_tests)  # validate best-first, only as many as get tested
            valid = list(itertools.islice(
                (v for v in ranked[:c.n_validate] if not self.env.validate(v[1], v[2], v[3])), needed))
            if not valid:
                continue
            tested = [(v[0] * min(1.0, image_change(self.env.scene, *v[1:]) / c.changed_fraction_full), *v[1:])
                      for v in valid[:c.bootstrap_image_tests]]
            _, q, joint, delta = max(tested, key=lambda v: v[0]) if tested else valid[0]
            return {"Q": q, "J": joint, "delta": np.array([delta])}
        raise InvalidInputError(f"no valid motion in {c.max_rounds} rounds of {c.bootstrap_candidates} candidates")
