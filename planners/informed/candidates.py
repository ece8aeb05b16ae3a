"""Candidate motions for the informed planner, and how they are judged before any estimate exists.

Candidates. Random (Q, J, Delta) as in the paper, plus IK-seeded ones: mink places the arm's last
link at a random pixel of the central image at a depth near the arm's, seen with the estimate, so the
moving links are large and whole in view (``CandidateSampler``).

Before any estimate exists (the first motions), there is nothing to project with, yet the linear
calibration needs three motions whose ellipses stage one can read and whose axis lines fix the pose.
Valid random candidates are scored (``bootstrap_score``) by (1) the expected ellipse quality of their
axis under a belief about the camera's viewing direction in the base frame, which stage one's verdicts
on the executed motions sharpen (``view_direction_posterior``); (2) the novelty of their axis line
against the motions that gave an axis (angle and distance: lines that all meet in one point cannot fix
depth); (3) the size of the moving links and |Delta|.
"""

from __future__ import annotations

import numpy as np

from planners.context import PlanningContext
from planners.ik import IKSolver, target_in_view
from planners.informed.config import InformedPlannerConfig
from planners.sampling import random_delta, random_motion, random_q
from solver.arrays import FloatArray
from solver.motion import LINES_NOT_ELLIPSES

Motion = tuple[FloatArray, int, float]


class CandidateSampler:
    """Draws candidate motions (Q (n,) rad, J, delta rad): random ones, and IK-seeded ones in view.

    Args:
        context: the planning context (robot model, intrinsics, the session's |Delta| bounds).
        config: the informed planner's settings.
        rng: the planner's generator (every draw comes from it, in a fixed order).
    """

    def __init__(self, context: PlanningContext, config: InformedPlannerConfig, rng: np.random.Generator):
        self.context = context
        self.config = config
        self.rng = rng
        self.ik_solver = IKSolver(context.robot)

    def delta_range(self) -> tuple[float, float]:
        """(min, max) rad of |Delta|: the config's, within the session's bounds."""
        c, ctx = self.config, self.context
        return max(c.delta_range[0], ctx.min_delta), min(c.delta_range[1], ctx.max_delta)

    def random(self) -> Motion | None:
        """A random motion as in the paper, or None when the drawn joint has no room to turn."""
        return random_motion(self.context.robot, self.rng, self.config.limit_margin, self.delta_range())

    def ik(self, T_camera_base: FloatArray) -> Motion | None:
        """A motion from a configuration that puts the last link in view of the estimate (None: IK missed)."""
        s, c = self.context.robot, self.config
        intr = self.context.intrinsics
        tip = s.joint_body(s.n_joints - 1)
        depth_now = float((T_camera_base[:3, :3] @ s.points_base(np.array([tip]), np.zeros((1, 3)))[0]
                           + T_camera_base[:3, 3])[2])
        depth = max(0.3, depth_now + self.rng.uniform(-c.ik_depth_spread, c.ik_depth_spread))
        half = 0.5 * c.ik_region
        pixel = np.array([intr.width * self.rng.uniform(0.5 - half, 0.5 + half),
                          intr.height * self.rng.uniform(0.5 - half, 0.5 + half)])
        result = self.ik_solver.solve(tip, target_in_view(T_camera_base, intr, pixel, depth),
                                      random_q(s, self.rng, c.limit_margin))
        if not result.reached:
            return None
        joint = int(self.rng.integers(s.n_joints))
        delta = random_delta(s, self.rng, result.q, joint, self.delta_range())
        return None if delta is None else (result.q, joint, delta)


def ellipse_quality(cos_view: FloatArray) -> FloatArray:
    """How well stage one sees a circle whose axis makes |cos| = cos_view with the optical axis, 0..1.

    Edge-on circles (|cos| < ~0.12) project to lines; between about 0.3 and 0.95 the ellipse's
    shape fixes the circle's normal well; head-on circles (|cos| -> 1) leave the two normal
    candidates close and can be ambiguous.
    """
    c = np.abs(cos_view)
    return np.clip((c - 0.12) / 0.2, 0.0, 1.0) * np.where(c > 0.95, 0.6, 1.0)


def line_distance(p1: FloatArray, a1: FloatArray, p2: FloatArray, a2: FloatArray) -> float:
    """Closest-approach distance (m) between the lines p1 + s a1 and p2 + s a2 (unit a1, a2; all (3,))."""
    n = np.cross(a1, a2)
    if np.linalg.norm(n) < 1e-6:
        return float(np.linalg.norm(np.cross(p2 - p1, a1)))
    return float(abs((p2 - p1) @ n) / np.linalg.norm(n))


def view_direction_posterior(context: PlanningContext, sphere: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Belief about the camera's optical axis in the base frame, from stage one's verdicts.

    With R of T_camera_base, v = R^T e_z is the optical axis in the base frame, and a motion
    whose axis stage one recovered gives v . a_base = (R a_base)_z = the z of its camera-frame
    axis; a motion stage one found to be "lines, not ellipses" was seen nearly edge-on,
    |v . a_base| small. A weak prior says the camera looks down or level rather than up.

    Args:
        context: the planning context (executed motions, the calibrator's verdicts).
        sphere: (N, 3) unit directions to weigh (a Fibonacci sphere).

    Returns:
        directions (N, 3) and weights (N,) summing to 1.
    """
    dirs = sphere
    cost = 0.5 * (np.maximum(0.0, dirs[:, 2] - 0.2) / 0.1) ** 2
    calibrator = context.calibrator
    if calibrator is not None:
        for i, (q, joint, _) in enumerate(context.executed[:len(calibrator.reports)]):
            axis = context.robot.axis_and_point(q, joint)[0]
            dots = dirs @ axis
            geometry = calibrator.motion_geometry(i)
            if geometry is not None:
                cost += 0.5 * ((dots - geometry.axis_cam[2]) / 0.1) ** 2
            elif calibrator.reports[i].stage_one.startswith(LINES_NOT_ELLIPSES):
                cost += 0.5 * (np.maximum(0.0, np.abs(dots) - 0.15) / 0.05) ** 2
    w = np.exp(-(cost - cost.min()))
    return dirs, w / w.sum()


def bootstrap_score(context: PlanningContext, config: InformedPlannerConfig, q: FloatArray, joint: int,
                    delta: float, posterior: tuple[FloatArray, FloatArray]) -> float:
    """Score of a motion (q (n,) rad, joint, delta rad) before any estimate: quality x novelty x size x |Delta|.

    Quality is expected under ``view_direction_posterior``; size is the median distance of
    the moving links' surface points from the axis over ``full_radius_m`` (at most 1): a hand
    turning about its own axis sweeps small arcs and gives few tracks.

    Novelty is against the executed motions that gave an axis (what the linear calibration
    will use): the smallest angle to their axes and the smallest distance to their lines, so
    that three motions fix the rotation and the translation (axes that all meet in one point,
    like the Panda's joints 1-3, cannot fix depth).
    """
    s = context.robot
    axis, point = s.axis_and_point(q, joint)
    dirs, w = posterior
    quality = float(w @ ellipse_quality(dirs @ axis))
    angle, dist = np.pi / 2, 0.15
    calibrator = context.calibrator
    for i, (qe, je, _) in enumerate(context.executed):
        if calibrator is None or i >= len(calibrator.reports) or calibrator.motion_geometry(i) is None:
            continue
        ae, pe = s.axis_and_point(qe, je)
        angle = min(angle, float(np.arccos(min(1.0, abs(float(axis @ ae))))))
        dist = min(dist, line_distance(point, axis, pe, ae))
    novelty = (0.25 + angle / (np.pi / 2)) * (0.25 + dist / 0.15)
    body, local = s.surface_points(joint)
    if len(body) == 0:
        return 0.0
    saved = s.q
    s.set_q(q)
    rel = s.points_base(body, local) - point
    s.set_q(saved)
    radius = float(np.median(np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)))
    size = min(1.0, radius / config.full_radius_m)
    return quality * novelty * size * abs(delta) / context.max_delta
