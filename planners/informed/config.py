"""Settings of the informed planner (``InformedPlannerConfig``), shared by its parts."""

from __future__ import annotations

from dataclasses import dataclass

from planners.sampling import check_sampling
from solver.errors import InvalidInputError


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
        predicted_tracks: tracks per predicted motion (the online calibrator keeps 40).
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
