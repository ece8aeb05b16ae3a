"""Whether an episode's first motions can fix the pose at all (the random planner's draws, their axes).

The joints the random planner draws first, and how well their axes fix T_camera_base at the true pose.

Simulation only (it reads the true camera pose). Until the first estimate the random planner's choices do not
depend on what the robot did: its tests (joint limits, collisions, the image change between thumbnail renders at
Q and Q + delta) read only the candidate, so K plans from the reset observation are the episode's first K motions
(after a first estimate it tests visibility against the estimate instead, and the draws may differ; by then the
run has its pose).

The first k motions' axes fix the pose only if ``solver.calibration.pose_observability`` at the true pose is at
least ``MIN_OBSERVABILITY`` (every motion given its axis). Axes that all meet in one point, as the Panda's and
the iiwa's joints 1-3 do at the shoulder, leave the distance along the line from the camera to that point free,
for the tracks as much as for the axes: scaling the scene and the camera's position about that point maps every
rotation about those axes to itself. A run whose first five motions do not fix the pose can have no pose by
motion 5, whatever the front ends do: the share of runs whose first five do is the ceiling of the realism issue's
"pose by 5" figure under random selection.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from arc_env.bench.episodes import EpisodeSpec, make_env
from planners.random_planner import RandomPlanner
from solver.arrays import FloatArray
from solver.calibration import MIN_OBSERVABILITY, AxisCorrespondence, pose_observability


@dataclass(frozen=True)
class FirstMotions:
    """The first motions of one benchmark episode.

    Attributes:
        joints: the joint each motion turns (0-based), in order.
        observability: after k = 1..K motions, ``pose_observability``'s ratio of their axes at the true pose
            (0 for one axis or parallel ones: the rotation about them is free).
    """

    joints: tuple[int, ...]
    observability: tuple[float, ...]

    def fixes_pose_by(self, k: int) -> bool:
        """Whether the first ``k`` motions' axes fix the pose (ratio at least ``MIN_OBSERVABILITY``)."""
        return self.observability[k - 1] >= MIN_OBSERVABILITY


def axes_observability(axes: Sequence[tuple[FloatArray, FloatArray]], T_camera_base: FloatArray) -> float:
    """``pose_observability``'s ratio (0..1) of joint axes (unit axis (3,), point (3,) m, base frame) at a pose (4, 4).

    One axis, or axes all parallel, give 0 (the rotation about them is free).
    """
    R, t = T_camera_base[:3, :3], T_camera_base[:3, 3]
    correspondences = []
    for axis, point in axes:
        axis_cam = R @ axis
        normal = np.cross(R @ point + t, axis_cam)
        correspondences.append(AxisCorrespondence(axis, point, axis_cam, normal / np.linalg.norm(normal)))
    directions = np.array([a for a, _ in axes])
    if len(axes) < 2 or np.linalg.matrix_rank(directions, tol=1e-6) < 2:
        return 0.0
    ratio, _ = pose_observability(correspondences, T_camera_base)
    return ratio


def draw_first_motions(spec: EpisodeSpec, k: int) -> FirstMotions:
    """The first ``k`` motions the random planner draws in ``spec``'s episode (module doc), with their observability."""
    env, observation = make_env(spec)
    try:
        planner = RandomPlanner(env.session, np.random.default_rng(spec.rng_seed))
        T_true = np.asarray(env.scene.T_camera_base, dtype=np.float64)
        joints: list[int] = []
        axes: list[tuple[FloatArray, FloatArray]] = []
        ratios: list[float] = []
        for _ in range(k):
            action = planner.plan(observation)
            joint = int(action["J"])
            joints.append(joint)
            axes.append(env.session.robot.axis_and_point(np.asarray(action["Q"], dtype=np.float64), joint))
            ratios.append(axes_observability(axes, T_true))
    finally:
        env.close()
    return FirstMotions(tuple(joints), tuple(ratios))
