"""Informed exploratory motions (ours): the safe candidate that adds the most information about the pose.

The parts: ``information`` (predicted tracks, Fisher information, the D-optimal gain), ``candidates``
(random and IK-seeded candidates; the score before any estimate), ``hypotheses`` (poses between the
second axis and the first estimate), ``config``; this module puts them together.

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

Candidates. Random (Q, J, Delta) as in the paper, plus IK-seeded ones (``planners.informed.candidates``):
mink places the arm's last link at a random pixel of the central image at a depth near the arm's, seen
with T, so the moving links are large and whole in view. The best-scoring candidates are checked by the
session (limits, collisions over the sweep: ``PlanningContext.refusal_reason``) in order, and the first
valid one is returned.

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
from typing import Any

import numpy as np

from planners.context import PlanningContext, estimate_from_observation
from planners.errors import PlanningError
from planners.informed.candidates import (
    CandidateSampler,
    bootstrap_score,
    ellipse_quality,
    view_direction_posterior,
)
from planners.informed.config import InformedPlannerConfig
from planners.informed.hypotheses import pose_hypotheses
from planners.informed.information import InformationModel, ScoredMotion
from planners.random_planner import image_change, motion_action, planner_setup
from solver.arrays import FloatArray
from solver.errors import ArcCalibError
from solver.motion import fibonacci_sphere


class InformedPlanner:
    """Chooses the valid exploratory motion with the largest predicted information gain.

    Same interface as ``RandomPlanner``: ``plan(observation)`` returns an env action.

    Args:
        context: what the planner reads (robot model, collision checks, executed motions and the
            calibrator's verdicts on them; a renderer for image tests and occlusion when there is one),
            e.g. ``env.session``.
        rng: random generator; None seeds one from the context's ``np_random``.
        config: settings. Without a renderer in the context, the image tests and the occlusion
            prediction are skipped (as with ``bootstrap_image_tests = occlusion_checks = 0``).

    Attributes:
        information: the information model (``planners.informed.information``).
        sampler: the candidate sampler (``planners.informed.candidates``).
        last_candidates: the candidates scored by the last ``plan`` call (best first), for inspection.
    """

    def __init__(self, context: PlanningContext, rng: np.random.Generator | None = None,
                 config: InformedPlannerConfig | None = None):
        self.context = context
        self.config = config or InformedPlannerConfig()
        # the renderer serves the bootstrap's image tests and the occlusion prediction
        self.rng, _ = planner_setup(context, rng, self.config.bootstrap_image_tests > 0)
        self.renderer = context.renderer
        self.sampler = CandidateSampler(context, self.config, self.rng)
        self.information = InformationModel(context, self.config)
        self._sphere = fibonacci_sphere(2000)
        self.last_candidates: list[ScoredMotion] = []

    def plan(self, observation: dict[str, Any]) -> dict[str, Any]:
        """The next motion as an env action {"Q", "J", "delta"}.

        Raises:
            PlanningError: no valid, visible motion was found.
        """
        T_camera_base = estimate_from_observation(observation)
        if T_camera_base is not None:
            return self._plan_scored([T_camera_base], [self.information.information_so_far(T_camera_base)])
        hypotheses = self.pose_hypotheses()
        if hypotheses:
            return self._plan_hypotheses(hypotheses)
        return self._plan_bootstrap()

    def pose_hypotheses(self) -> list[FloatArray]:
        """Poses (4, 4) to plan with before an estimate (``planners.informed.hypotheses.pose_hypotheses``)."""
        return pose_hypotheses(self.context, self.config)

    def score_all(self, q: FloatArray, joint: int, delta: float, poses: list[FloatArray],
                   so_far: list[FloatArray], source: str, occlusion: bool = False,
                   need_axis: bool = False) -> ScoredMotion:
        """``score`` averaged over pose hypotheses (a hypothesis that loses the links from view adds 0).

        With ``need_axis`` (no estimate yet: the motion must give stage one an axis for the linear
        calibration) the gain is weighted by ``ellipse_quality`` of the axis seen with the
        hypotheses' rotation (they share it), since edge-on circles are lines to stage one, and by
        the expected tracks over ``predicted_tracks`` (at most 1), since few short arcs leave the
        axis ambiguous (seen: 21 tracks of the hand, two axes fitting within 1.09x).
        """
        scored = [self.information.score(q, joint, delta, T_camera_base, info, source, occlusion)
                  for T_camera_base, info in zip(poses, so_far, strict=True)]
        if len(scored) == 1 and not need_axis:
            return scored[0]
        gains = np.array([m.gain for m in scored])
        gain = float(np.mean(np.where(np.isfinite(gains), gains, 0.0))) if np.isfinite(gains).any() else -np.inf
        tracks = float(np.mean([m.tracks for m in scored]))
        if need_axis and np.isfinite(gain):
            axis_cam = poses[0][:3, :3] @ self.context.robot.axis_and_point(q, joint)[0]
            gain *= float(ellipse_quality(np.array([axis_cam[2]]))[0])
            gain *= min(1.0, tracks / self.config.predicted_tracks)
        return ScoredMotion(q, joint, delta, gain, max(m.in_view for m in scored), source, occlusion, tracks)

    def _plan_scored(self, poses: list[FloatArray], so_far: list[FloatArray], need_axis: bool = False,
                     ) -> dict[str, Any]:
        c = self.config
        mid = len(poses) // 2
        ik_pose = poses[mid]
        max_checks = c.occlusion_checks if self.context.renderer is not None else 0
        for _ in range(c.max_rounds):
            scored: list[ScoredMotion] = []
            for k in range(c.n_random + c.n_ik):
                source = "random" if k < c.n_random else "ik"
                try:
                    cand = self.sampler.random() if source == "random" else self.sampler.ik(ik_pose)
                except ArcCalibError:
                    cand = None
                if cand is None:
                    continue
                # several hypotheses: screen every candidate with the middle one, average the best over all
                sm = self.score_all(*cand, poses[mid:mid + 1], so_far[mid:mid + 1], source, need_axis=need_axis)
                if np.isfinite(sm.gain):
                    scored.append(sm)
            scored.sort(key=lambda m: -m.gain)
            if len(poses) > 1:
                scored = [self.score_all(m.q, m.joint, m.delta, poses, so_far, m.source, need_axis=need_axis)
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
                    return motion_action(m.q, m.joint, m.delta)
                if self.context.refusal_reason(m.q, m.joint, m.delta):
                    continue
                if checks >= max_checks:
                    m = next((x for x in queue if x.occlusion), m)
                    return motion_action(m.q, m.joint, m.delta)
                checks += 1
                exact = self.score_all(m.q, m.joint, m.delta, poses, so_far, m.source, occlusion=True,
                                        need_axis=need_axis)
                if np.isfinite(exact.gain):
                    queue.append(exact)
                    queue.sort(key=lambda x: -x.gain)
        raise PlanningError(f"no valid, visible motion in {c.max_rounds} rounds of "
                                f"{c.n_random + c.n_ik} candidates")

    def _plan_hypotheses(self, poses: list[FloatArray]) -> dict[str, Any]:
        calibrator = self.context.calibrator
        assert calibrator is not None
        with_axis = [i for i in range(len(calibrator.reports)) if calibrator.motion_geometry(i) is not None]
        return self._plan_scored(poses, [self.information.information_so_far(T_camera_base, with_axis)
                                         for T_camera_base in poses], need_axis=True)

    def _plan_bootstrap(self) -> dict[str, Any]:
        c = self.config
        posterior = view_direction_posterior(self.context, self._sphere)
        for _ in range(c.max_rounds):
            drawn = [cand for cand in (self.sampler.random() for _ in range(c.bootstrap_candidates))
                     if cand is not None]
            ranked = sorted(((bootstrap_score(self.context, c, *cand, posterior), *cand) for cand in drawn),
                            key=lambda v: -v[0])
            tests = c.bootstrap_image_tests if self.renderer is not None else 0
            needed = max(1, tests)  # validate best-first, only as many as get tested
            valid = list(itertools.islice(
                (v for v in ranked[:c.n_validate] if not self.context.refusal_reason(v[1], v[2], v[3])), needed))
            if not valid:
                continue
            tested = [(v[0] * min(1.0, image_change(self.context, self.renderer, *v[1:]) / c.changed_fraction_full),
                       *v[1:]) for v in valid[:tests]] if self.renderer is not None else []
            _, q, joint, delta = max(tested, key=lambda v: v[0]) if tested else valid[0]
            return motion_action(q, joint, delta)
        raise PlanningError(f"no valid motion in {c.max_rounds} rounds of {c.bootstrap_candidates} candidates")
