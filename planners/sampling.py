"""Random exploratory motions within the joint limits: the one sampler both planners draw from."""

from __future__ import annotations

import numpy as np

from planners.context import RobotKinematics
from solver.arrays import FloatArray
from solver.errors import InvalidInputError


def check_sampling(delta_range: tuple[float, float], limit_margin: float) -> None:
    """Raise InvalidInputError unless 0 < delta_range[0] <= delta_range[1] and 0 <= limit_margin < 0.5."""
    if not 0 < delta_range[0] <= delta_range[1]:
        raise InvalidInputError("delta_range must be (min, max) with 0 < min <= max")
    if not 0 <= limit_margin < 0.5:
        raise InvalidInputError("limit_margin must be in [0, 0.5)")


def random_q(robot: RobotKinematics, rng: np.random.Generator, limit_margin: float) -> FloatArray:
    """A uniform configuration (n,) rad, ``limit_margin`` of each joint's range inside its limits."""
    span = robot.upper - robot.lower
    return rng.uniform(robot.lower + limit_margin * span, robot.upper - limit_margin * span)


def random_delta(robot: RobotKinematics, rng: np.random.Generator, q: FloatArray, joint: int,
                 delta_range: tuple[float, float]) -> float | None:
    """A turn (rad) of joint from q, |delta| uniform in delta_range and the end within the limits.

    The sign is drawn among those with room for |delta| >= delta_range[0]; None when neither has.
    """
    dmin, dmax = delta_range
    room_up, room_down = robot.upper[joint] - q[joint], q[joint] - robot.lower[joint]
    signs = [sg for sg, room in ((1.0, room_up), (-1.0, room_down)) if room >= dmin]
    if not signs:
        return None
    sign = signs[int(rng.integers(len(signs)))]
    room = room_up if sign > 0 else room_down
    return float(sign * rng.uniform(dmin, min(dmax, room)))


def random_motion(robot: RobotKinematics, rng: np.random.Generator, limit_margin: float,
                  delta_range: tuple[float, float]) -> tuple[FloatArray, int, float] | None:
    """A random (Q (n,) rad, J, delta rad) as in the paper (§IV-A), or None when J has no room to turn."""
    q = random_q(robot, rng, limit_margin)
    joint = int(rng.integers(robot.n_joints))
    delta = random_delta(robot, rng, q, joint, delta_range)
    return None if delta is None else (q, joint, delta)
