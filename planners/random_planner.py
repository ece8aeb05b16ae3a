"""Random exploratory motions (the paper's selection, §IV-A): random Q and J, |Delta| above a minimum.

A candidate is kept when the environment would accept it (limits, collisions over the sweep) and
the moving links are in view: with an estimate of ``T_camera_base``, their surface points at
both ends of the sweep must project inside the image with a margin; without one, an image test
(the start and end frames of the sweep must differ in enough pixels, as a real robot would check
with two snapshots). No ground truth is used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from planners.sampling import check_sampling, random_motion
from solver.errors import InvalidInputError
from solver.frames import transform_from_rt

if TYPE_CHECKING:
    from arc_env.env import ArcCalibEnv
    from arc_env.scene import Scene

FloatArray = NDArray[np.float64]


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


def image_change(scene: Scene, q: FloatArray, joint: int, delta: float) -> float:
    """Fraction of pixels that change (by more than 12 of 255 in some channel) between a sweep's end frames.

    The image test a real robot does with two snapshots: renders the sweep (q (n,) rad, joint,
    delta rad) at 0 and delta as thumbnails (``IMAGE_TEST_DOWNSCALE``), then puts the arm back.
    """
    saved = scene.q
    frames = []
    for d in (0.0, delta):
        scene.set_swept(q, joint, d)
        frames.append(scene.render(IMAGE_TEST_DOWNSCALE).astype(np.int16))
    scene.set_q(saved)
    return float((np.abs(frames[0] - frames[1]).max(axis=2) > 12).mean())


def prepare_image_test(scene: Scene) -> None:
    """Create the thumbnail renderer now (about 1 s of GL set-up), so no planning call pays for it."""
    scene.render(IMAGE_TEST_DOWNSCALE)


class RandomPlanner:
    """Draws random valid, visible exploratory motions for an ``ArcCalibEnv``.

    Args:
        env: the environment (its robot model, collision checker and camera image).
        rng: random generator; None seeds one from the env's ``np_random``.
        config: settings.
    """

    def __init__(self, env: ArcCalibEnv, rng: np.random.Generator | None = None,
                 config: RandomPlannerConfig | None = None):
        self.env = env
        self.rng = rng if rng is not None else np.random.default_rng(env.np_random.integers(2**31 - 1))
        self.config = config or RandomPlannerConfig()
        if self.config.max_image_tests:
            prepare_image_test(env.scene)

    def _sample(self) -> tuple[FloatArray, int, float] | None:
        c, env = self.config, self.env.config
        delta_range = (max(c.delta_range[0], env.min_delta), min(c.delta_range[1], env.max_delta))
        return random_motion(self.env.scene, self.rng, c.limit_margin, delta_range)

    def _in_view_estimate(self, q: FloatArray, joint: int, delta: float, T: FloatArray) -> bool:
        s, c = self.env.scene, self.config
        body, local = s.surface_points(joint)
        if len(body) == 0:
            return False
        pick = self.rng.choice(len(body), size=min(200, len(body)), replace=False)
        body, local = body[pick], local[pick]
        saved = s.q
        fractions = []
        for d in (0.0, delta):
            s.set_swept(q, joint, d)
            _, visible = s.project_points(body, local, T, min_depth=0.1, margin_px=c.image_margin_px)
            fractions.append(visible.mean())
        s.set_q(saved)
        return min(fractions) >= c.min_in_view

    def _in_view_image(self, q: FloatArray, joint: int, delta: float) -> bool:
        return image_change(self.env.scene, q, joint, delta) >= self.config.min_changed_fraction

    def plan(self, observation: dict[str, Any]) -> dict[str, Any]:
        """The next motion as an env action {"Q", "J", "delta"}.

        Raises:
            InvalidInputError: no valid, visible motion was found in ``max_tries`` candidates.
        """
        c = self.config
        T = None
        if int(observation.get("has_estimate", 0)):
            R = Rotation.from_rotvec(np.asarray(observation["rotation"], dtype=np.float64)).as_matrix()
            T = transform_from_rt(R, np.asarray(observation["translation"], dtype=np.float64))
        image_tests = 0
        for _ in range(c.max_tries):
            cand = self._sample()
            if cand is None:
                continue
            q, joint, delta = cand
            if self.env.validate(q, joint, delta):
                continue
            if T is not None:
                if not self._in_view_estimate(q, joint, delta, T):
                    continue
            else:
                if image_tests >= c.max_image_tests:
                    return {"Q": q, "J": joint, "delta": np.array([delta])}
                image_tests += 1
                if not self._in_view_image(q, joint, delta):
                    continue
            return {"Q": q, "J": joint, "delta": np.array([delta])}
        raise InvalidInputError(f"no valid, visible motion in {c.max_tries} random candidates")
