"""Transit: a collision-free joint-space path from where the arm is to the next start configuration.

The straight joint-space segment is tried first (checked densely with ``CollisionChecker.path_free``,
so no point of the arm moves more than ``max_step_m`` between checks). When it is blocked, OMPL's
RRTConnect plans in the box of the joint limits with the fcl checker as its state validity test,
the path is shortened by OMPL's simplifier, and every segment of the result is checked again at
``max_step_m``: OMPL's own motion check samples at a fixed joint-space resolution, which is coarser
at the tip of a 1 m arm than the millimetres we promise. A path that fails that check is re-planned
at a finer resolution; after ``attempts`` tries the transit fails with a reason.

OMPL draws its random numbers from a process-wide generator; ``plan_transit`` reseeds it with the
caller's seed before every plan, so a seeded episode plans the same paths.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from planners.collision import CollisionChecker
from planners.errors import TransitError
from solver.arrays import FloatArray
from solver.errors import InvalidInputError

ou.setLogLevel(ou.LOG_WARN)

__all__ = ["TransitConfig", "TransitError", "TransitPath", "path_length", "plan_transit"]


@dataclass(frozen=True)
class TransitConfig:
    """Settings of ``plan_transit``.

    Attributes:
        time_limit: s, OMPL's planning time per attempt.
        attempts: plans tried (each at half the previous attempt's resolution) before giving up.
        resolution_rad: rad, OMPL's state-validity resolution along an edge in the first attempt.
        max_step_m: m, the final check's largest step of any point of the arm.
    """

    time_limit: float = 1.0
    attempts: int = 3
    resolution_rad: float = 0.02
    max_step_m: float = 0.005

    def __post_init__(self) -> None:
        if self.time_limit <= 0 or self.attempts < 1 or self.resolution_rad <= 0 or self.max_step_m <= 0:
            raise InvalidInputError("time_limit, attempts, resolution_rad and max_step_m must be positive")


@dataclass(frozen=True)
class TransitPath:
    """A checked transit.

    Attributes:
        waypoints: (W, n) rad, from the start to the goal configuration; consecutive waypoints are
            joined by straight joint-space segments, each checked collision-free.
        length_rad: joint-space length of the path (sum of the segments' Euclidean lengths), rad.
        planned: False when the straight segment was free (no planner call).
        seconds: wall time of planning and checking.
    """

    waypoints: FloatArray
    length_rad: float
    planned: bool
    seconds: float


def path_length(waypoints: FloatArray) -> float:
    """Joint-space length of a polyline of configurations (W, n) rad -> rad."""
    w = np.asarray(waypoints, dtype=np.float64)
    return float(np.linalg.norm(np.diff(w, axis=0), axis=1).sum()) if len(w) > 1 else 0.0


def _ompl_plan(checker: CollisionChecker, lower: FloatArray, upper: FloatArray, q_from: FloatArray,
               q_to: FloatArray, resolution_rad: float, time_limit: float, seed: int) -> FloatArray | None:
    n = len(q_from)
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)  # reseeding after the first draw logs an error; it still reseeds
    ou.RNG.setSeed(int(seed) % (2**31 - 1) + 1)
    ou.setLogLevel(level)
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(lower[i]))
        bounds.setHigh(i, float(upper[i]))
    space.setBounds(bounds)
    setup = og.SimpleSetup(space)

    def valid(state: object) -> bool:
        q = np.fromiter((state[i] for i in range(n)), dtype=np.float64, count=n)  # type: ignore[index]
        return not checker.in_collision(q)[0]

    setup.setStateValidityChecker(valid)
    info = setup.getSpaceInformation()
    info.setStateValidityCheckingResolution(min(0.5, resolution_rad / space.getMaximumExtent()))
    start, goal = space.allocState(), space.allocState()
    for i in range(n):
        start[i] = float(q_from[i])
        goal[i] = float(q_to[i])
    setup.setStartAndGoalStates(start, goal)
    setup.setPlanner(og.RRTConnect(info))
    solved = setup.solve(time_limit)
    if not solved or not setup.haveExactSolutionPath():
        return None
    setup.simplifySolution()
    path = setup.getSolutionPath()
    out = np.array([[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())])
    out[0], out[-1] = q_from, q_to  # exact ends (OMPL copies them; guard against float round trips)
    return out


def plan_transit(checker: CollisionChecker, lower: FloatArray, upper: FloatArray, q_from: FloatArray,
                 q_to: FloatArray, config: TransitConfig | None = None, seed: int = 0) -> TransitPath:
    """A collision-free path from q_from to q_to, both (n,) rad, inside [lower, upper] (n,) rad.

    Raises:
        TransitError: either end is in collision, or no checked path was found.
    """
    cfg = config or TransitConfig()
    t0 = time.perf_counter()
    q_from = np.asarray(q_from, dtype=np.float64)
    q_to = np.asarray(q_to, dtype=np.float64)
    for name, q in (("the current configuration", q_from), ("the target configuration", q_to)):
        hit, why = checker.in_collision(q)
        if hit:
            raise TransitError(f"{name} is in collision: {why}")
    free, _ = checker.path_free(q_from, q_to, cfg.max_step_m)
    if free:
        w = np.stack([q_from, q_to])
        return TransitPath(w, path_length(w), False, time.perf_counter() - t0)
    resolution = cfg.resolution_rad
    last = "RRTConnect found no path"
    for attempt in range(cfg.attempts):
        w = _ompl_plan(checker, lower, upper, q_from, q_to, resolution, cfg.time_limit, seed + attempt)
        if w is None:
            last = f"RRTConnect found no path in {cfg.time_limit:.1f} s"
        else:
            checks = (checker.path_free(a, b, cfg.max_step_m) for a, b in zip(w[:-1], w[1:], strict=True))
            bad = next((why for free, why in checks if not free), None)  # stops at the first blocked segment
            if bad is None:
                return TransitPath(w, path_length(w), True, time.perf_counter() - t0)
            last = f"the planned path failed the {cfg.max_step_m * 1e3:.0f} mm check: {bad}"
        resolution /= 2.0
    raise TransitError(f"no collision-free transit after {cfg.attempts} attempts: {last}")
