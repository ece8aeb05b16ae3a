"""Forward kinematics the solver needs: Gamma(Q, J) -> (axis, joint position) in the base frame.

The solver takes Gamma as a plain function (``AxisFunction``), so any robot works. ``DHChain`` is a
pure-numpy implementation for serial arms given by modified (Craig) Denavit-Hartenberg parameters;
``PANDA`` holds the Franka Emika Panda's published parameters and joint limits.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from solver.arrays import FloatArray
from solver.errors import InvalidInputError

#: Gamma(q, joint) -> (axis_base (3,) unit, point_base (3,) metres) for a 0-based joint index.
AxisFunction = Callable[[FloatArray, int], tuple[FloatArray, FloatArray]]


def _rot_x(alpha: float) -> FloatArray:
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


@dataclass(frozen=True)
class DHChain:
    """A serial arm of revolute joints in modified DH convention.

    Frame i follows frame i-1 by RotX(alpha_i) TransX(a_i) RotZ(theta_i + q_i) TransZ(d_i); joint i
    turns about frame i's z axis through frame i's origin.

    Attributes:
        a: (N,) float64, metres.
        d: (N,) float64, metres.
        alpha: (N,) float64, radians.
        lower: (N,) float64, radians: joint lower limits.
        upper: (N,) float64, radians: joint upper limits.
        flange: (4, 4) float64: the flange frame in the last joint's frame.
    """

    a: FloatArray
    d: FloatArray
    alpha: FloatArray
    lower: FloatArray
    upper: FloatArray
    flange: FloatArray

    def __post_init__(self) -> None:
        for name in ("a", "d", "alpha", "lower", "upper"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        n = self.a.shape[0]
        if any(getattr(self, k).shape != (n,) for k in ("d", "alpha", "lower", "upper")):
            raise InvalidInputError("DH parameter arrays must all have shape (N,)")
        if np.any(self.lower >= self.upper):
            raise InvalidInputError("every joint needs lower < upper")

    @property
    def n_joints(self) -> int:
        """Number of joints N."""
        return int(self.a.shape[0])

    def frames(self, q: FloatArray) -> FloatArray:
        """Joint frames in the base frame: q (N,) rad -> (N + 1, 4, 4); the last is the flange."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n_joints,):
            raise InvalidInputError(f"q must have shape ({self.n_joints},), got {q.shape}")
        out = np.empty((self.n_joints + 1, 4, 4))
        T = np.eye(4)
        for i in range(self.n_joints):
            c, s = np.cos(q[i]), np.sin(q[i])
            link = _rot_x(self.alpha[i])
            link[0, 3] = self.a[i]  # RotX(alpha) TransX(a): x is fixed by RotX
            rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, self.d[i]], [0, 0, 0, 1.0]])
            link = link @ rz
            T = T @ link
            out[i] = T
        out[-1] = T @ self.flange
        return out

    def axis_and_point(self, q: FloatArray, joint: int) -> tuple[FloatArray, FloatArray]:
        """Gamma(q, joint): joint's unit axis and a point on it, both in the base frame."""
        if not 0 <= joint < self.n_joints:
            raise InvalidInputError(f"joint {joint} out of range 0..{self.n_joints - 1}")
        T = self.frames(q)[joint]
        return T[:3, 2].copy(), T[:3, 3].copy()

    def clip(self, q: FloatArray) -> FloatArray:
        """Q clipped into the joint limits."""
        return np.clip(q, self.lower, self.upper)


def _panda() -> DHChain:
    flange = np.eye(4)
    flange[2, 3] = 0.107
    return DHChain(
        a=np.array([0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088]),
        d=np.array([0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0]),
        alpha=np.array([0.0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2]),
        lower=np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]),
        upper=np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
        flange=flange,
    )


#: Franka Emika Panda, modified DH parameters and joint limits as Franka publishes them.
PANDA = _panda()
