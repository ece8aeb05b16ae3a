"""Random exploratory motions (the paper's selection, §IV-A): random Q and J, |Delta| above a minimum.

A candidate is kept when the environment would accept it (limits, collisions over the sweep) and
the moving links are in view: with an estimate of ``T_camera_base``, their surface points at
both ends of the sweep must project inside the image with a margin; without one, an image test
(the start and end frames of the sweep must differ in enough pixels, as a real robot would check
with two snapshots). No ground truth is used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from planners.context import PlanningContext, SceneRenderer, estimate_from_observation
from planners.errors import PlanningError
from planners.sampling import check_sampling, random_motion
from solver.arrays import FloatArray


@dataclass(frozen=True)
class RandomPlannerConfig:
    """Settings of ``RandomPlanner``.

    Attributes:
        delta_range: (min, max) rad of |Delta| (the env's minimum is enforced on top).
        limit_margin: fraction of each joint's range kept away from its limits when sampling Q.
        max_tries: candidates drawn before giving up.
        image_margin_px: px; projected points must be this far inside the image.
        min_in_view: fraction of the moving links' points that must be in view (with an estimate).
        min_changed_fraction: fraction of pixels that must change between the sweep's end frames
            (without an estimate).
        max_image_tests: image tests per call (each renders two frames).
    """

    delta_range: tuple[float, float] = (0.4, 1.2)
    limit_margin: float = 0.05
    max_tries: int = 300
    image_margin_px: float = 20.0
    min_in_view: float = 0.7
    min_changed_fraction: float = 0.01
    max_image_tests: int = 6

    def __post_init__(self) -> None:
        check_sampling(self.delta_range, self.limit_margin)


#: Thumbnails for the image test are this many times smaller per side than the camera image.
IMAGE_TEST_DOWNSCALE = 4


def image_change(context: PlanningContext, renderer: SceneRenderer, q: FloatArray, joint: int, delta: float) -> float:
    """Fraction of pixels that change (by more than 12 of 255 in some channel) between a sweep's end frames.

    The image test a real robot does with two snapshots: renders the sweep (q (n,) rad, joint,
    delta rad) at 0 and delta as thumbnails (``IMAGE_TEST_DOWNSCALE``), then puts the arm back.
    """
    saved = context.robot.q
    frames = []
    for d in (0.0, delta):
        swept = q.copy()
        swept[joint] += d
        frames.append(renderer.render_at(swept, IMAGE_TEST_DOWNSCALE).astype(np.int16))
    context.robot.set_q(saved)
    return float((np.abs(frames[0] - frames[1]).max(axis=2) > 12).mean())


class RandomPlanner:
    """Draws random valid, visible exploratory motions.

    Args:
        context: what the planner reads (robot model, collision checks, the session's limits; an image
            test when the context has a renderer), e.g. ``env.session``.
        rng: random generator; None seeds one from the context's ``np_random``.
        config: settings. Without a renderer in the context, no image test runs (``max_image_tests``
            is treated as 0): before an estimate exists, motions are not checked for visibility.
    """

    def __init__(self, context: PlanningContext, rng: np.random.Generator | None = None,
                 config: RandomPlannerConfig | None = None):
        self.context = context
        self.config = config or RandomPlannerConfig()
        self.rng, self.renderer = planner_setup(context, rng, self.config.max_image_tests > 0)

    def _sample(self) -> tuple[FloatArray, int, float] | None:
        c, ctx = self.config, self.context
        delta_range = (max(c.delta_range[0], ctx.min_delta), min(c.delta_range[1], ctx.max_delta))
        return random_motion(ctx.robot, self.rng, c.limit_margin, delta_range)

    def _in_view_estimate(self, q: FloatArray, joint: int, delta: float, T_camera_base: FloatArray) -> bool:
        s, c = self.context.robot, self.config
        body, local = s.surface_points(joint)
        if len(body) == 0:
            return False
        pick = self.rng.choice(len(body), size=min(200, len(body)), replace=False)
        body, local = body[pick], local[pick]
        saved = s.q
        fractions = []
        for d in (0.0, delta):
            s.set_swept(q, joint, d)
            _, visible = s.project_points(body, local, T_camera_base, self.context.intrinsics, min_depth=0.1,
                                          margin_px=c.image_margin_px)
            fractions.append(visible.mean())
        s.set_q(saved)
        return min(fractions) >= c.min_in_view

    def _in_view_image(self, renderer: SceneRenderer, q: FloatArray, joint: int, delta: float) -> bool:
        return image_change(self.context, renderer, q, joint, delta) >= self.config.min_changed_fraction

    def plan(self, observation: dict[str, Any]) -> dict[str, Any]:
        """The next motion as an env action {"Q", "J", "delta"}.

        Raises:
            PlanningError: no valid, visible motion was found in ``max_tries`` candidates.
        """
        c = self.config
        T_camera_base = estimate_from_observation(observation)
        image_tests = 0
        for _ in range(c.max_tries):
            cand = self._sample()
            if cand is None:
                continue
            q, joint, delta = cand
            if self.context.refusal_reason(q, joint, delta):
                continue
            if T_camera_base is not None:
                if not self._in_view_estimate(q, joint, delta, T_camera_base):
                    continue
            else:
                if self.renderer is None or image_tests >= c.max_image_tests:
                    return motion_action(q, joint, delta)
                image_tests += 1
                if not self._in_view_image(self.renderer, q, joint, delta):
                    continue
            return motion_action(q, joint, delta)
        raise PlanningError(f"no valid, visible motion in {c.max_tries} random candidates")


def planner_setup(context: PlanningContext, rng: np.random.Generator | None,
                  image_tests: bool) -> tuple[np.random.Generator, SceneRenderer | None]:
    """A planner's generator and renderer.

    The generator is ``rng``, or one seeded from the context's ``np_random``; the renderer is the
    context's when the planner runs image tests (prepared now: about 1 s of GL set-up), else None.
    """
    generator = rng if rng is not None else np.random.default_rng(context.np_random.integers(2**31 - 1))
    renderer = context.renderer if image_tests else None
    if renderer is not None:
        renderer.prepare(IMAGE_TEST_DOWNSCALE)
    return generator, renderer


def motion_action(q: FloatArray, joint: int, delta: float) -> dict[str, Any]:
    """The env action {"Q": (n,) rad, "J": joint, "delta": (1,) rad} of a motion."""
    return {"Q": q, "J": joint, "delta": np.array([delta])}
