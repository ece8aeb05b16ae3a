"""Pose hypotheses between the second axis and the first estimate.

Two motions whose axes stage one recovered (not parallel) already fix the rotation and two of the
translation's three components; what they leave free is the distance along one ray from the camera
(``solver.calibration.pose_family``: each motion's circles fix its axis only up to the axis' own distance).
``pose_hypotheses`` returns a few members of that family that put the arm's axes in front of the camera at
plausible depths, for the planner to score candidates with until a third motion fixes the depth.
"""

from __future__ import annotations

import numpy as np

from planners.context import PlanningContext
from planners.informed.config import InformedPlannerConfig
from solver.arrays import FloatArray
from solver.calibration import AxisCorrespondence, pose_family
from solver.errors import ArcCalibError
from solver.frames import transform_from_rt

#: m; pose hypotheses are searched this far either side of the least-norm member of the family.
HYPOTHESIS_RANGE_M = 6.0


def pose_hypotheses(context: PlanningContext, config: InformedPlannerConfig) -> list[FloatArray]:
    """Poses (4, 4) to plan with before an estimate, once two motions gave non-parallel axes.

    Two axes fix the rotation and two components of the translation
    (``solver.calibration.pose_family``); the third, the distance along a ray from the camera,
    stays free until a third motion. The members kept put each axis where it crosses the ray
    to its circles' centres (D^c) in front of the camera, with the axes' mean point at a depth within
    ``hypothesis_depths``; ``n_hypotheses`` of them, evenly spread in that depth, are returned
    (empty: fewer than two axes, all within ``min_axis_angle`` of parallel, or no member in range).
    """
    c, s = config, context.robot
    calibrator = context.calibrator
    if calibrator is None or c.n_hypotheses < 1:
        return []
    cors, refs = [], []
    for i, (q, joint, _) in enumerate(context.executed[:len(calibrator.reports)]):
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
        R_camera_base, t0, u = pose_family(cors)
    except ArcCalibError:
        return []
    ts = t0 + np.linspace(-HYPOTHESIS_RANGE_M, HYPOTHESIS_RANGE_M, 2001)[:, None] * u  # (S, 3)
    ok = np.ones(len(ts), dtype=bool)
    for cor, ref in zip(cors, refs, strict=True):
        p = (R_camera_base @ cor.point_base)[None, :] + ts  # (S, 3) a point of the axis, camera frame
        a = R_camera_base @ cor.axis_base
        foot = p - (p @ a)[:, None] * a  # the axis' point nearest the camera centre
        ok &= foot @ ref > 0  # the axis crosses the ray to its circles' centres in front of the camera
    depth = (R_camera_base @ np.mean([cor.point_base for cor in cors], axis=0))[2] + ts[:, 2]  # (S,) m
    ok &= (depth >= c.hypothesis_depths[0]) & (depth <= c.hypothesis_depths[1])
    if not ok.any():
        return []
    lo, hi = depth[ok].min(), depth[ok].max()
    picks = []
    for target in np.linspace(lo, hi, c.n_hypotheses + 2)[1:-1]:
        k = int(np.argmin(np.where(ok, np.abs(depth - target), np.inf)))
        picks.append(transform_from_rt(R_camera_base, ts[k]))
    return picks
