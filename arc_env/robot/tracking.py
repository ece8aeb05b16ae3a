"""Keypoint tracks from the frames of one exploratory motion: Shi–Tomasi corners, pyramidal Lucas–Kanade.

One joint turns, so the moving links are the only part of the image that changes. ``moving_mask`` finds
those pixels from the frames alone; ``track_keypoints`` detects corners inside them, follows each corner
frame to frame with pyramidal LK and a forward–backward check, and hands back
``solver.observations.KeypointTrack`` objects the solver consumes directly.

Translation-only LK drifts when the patch turns: each step is biased by (rotation) x (offset between the
corner and the window's gradient "balance point"), and on a rotating link that bias has the same sign
every frame, so a 1 rad sweep ends 1-2 px off the true point, and the fb check cannot see it (the backward
step has the opposite bias). So each frame the LK position is refined by an affine fit of the track's
first-frame patch (inverse-compositional Lucas–Kanade, Baker & Matthews 2004), which does not drift, and
the fit's residual, at the best contrast gain, ends tracks whose patch no longer matches (Shi & Tomasi
1994's dissimilarity check): occlusions, background points dragged by a passing edge, corners on
silhouettes.

On a curved surface the patch's image motion is not affine: a rolling cylinder's texture moves fastest
where it faces the camera and not at all at the rim, so an affine fit over a 21 px window follows the
window's mean motion, not its centre's, and lags the point by a few tenths of a pixel per sweep -- the same
sign on every track of a convex link. A lag along the arc reads as a shorter turn, which the bundle
adjustment explains by moving the camera away (measured on rendered 720p Panda sweeps with ray-cast
ground truth: tracked arcs 3 per mille short, the camera 4 mm too far; the same tracks' true
projections gave 0.3 mm). ``quadratic_warp`` gives the patch map quadratic terms, which follow the
curvature, with a weak prior that keeps them near zero where the texture cannot fix them
(``quadratic_ridge``); a patch that bends much is straddling an edge and ends (``max_bend_px``). It is
off by default: on realistic images the bend check that keeps rim tracks out also ends half the tracks
(``TrackerConfig``'s figures). By default the patch's pixels are weighed by a Gaussian about its centre
instead (``window_sigma_px``, 4 px): the lag grows with the window's second moment, so this halves it with no
new parameters; as the rim then counts little, a second check on the whole window, unweighted, ends tracks
whose rim slid onto other structure (``max_window_dissimilarity``). Corners that slide smoothly (shading,
highlights) pass every check here; the solver's rigid-motion check (``solver.rigid_axis``) and the bundle
adjustment's robust loss drop them.

A link turning under a lamp also turns its shading: the brightness across a patch changes along the sweep, not
only its mean and contrast, and on the faint texture of a casting (a label's edge, a screw head) the fit follows
the shading's gradient part of the way. The fit therefore leaves a linear ramp in x and y out of every patch as
well as the offset (``TrackerConfig.shading_ramp``: the patches and the steepest-descent images are projected off
(1, x, y) in the window's weights, which solves for the ramp's two coefficients with the map).

Pure numpy/OpenCV (never MuJoCo): rendered frames and real-robot recordings go through the same code.
Pixels are OpenCV pixels (x right, y down, origin at the centre of the top-left pixel).

Speed: OpenCV's Python bindings cannot pass ``cv2.buildOpticalFlowPyramid`` output to
``cv2.calcOpticalFlowPyrLK`` (opencv/opencv#4777), so each LK call builds its own pyramids. Instead all
work runs on the bounding box of the moving mask (plus the LK window's reach at the coarsest level),
which is usually a fraction of the frame. A track that has moved one step starts LK where that step predicts
its next position and searches fewer levels in a smaller crop (``TrackerConfig.predicted_max_level``).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass, fields

import cv2
import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray, ImageArray, MaskArray
from solver.errors import InvalidInputError
from solver.mask_start import changed_pixels
from solver.observations import KeypointTrack
from solver.schur import robust_sigma
from solver.threads import check_blas_threads, limited_blas

#: LK termination: stop after 30 iterations or when an update is below 0.01 px (per pyramid level).
DEFAULT_CRITERIA: tuple[int, int, float] = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of ``moving_mask`` and ``track_keypoints``.

    Attributes:
        max_corners: most live tracks at any time (``cv2.goodFeaturesToTrack``'s maxCorners); count.
        quality_level: a corner is kept if its smaller structure-tensor eigenvalue is at least this
            fraction of the strongest corner's in the searched region; dimensionless, in (0, 1).
        min_eigenvalue: a corner is also kept only if that eigenvalue is at least this, in
            ``cv2.cornerMinEigenVal``'s units (grey levels / 255, derivatives over a ``block_size`` window); 0:
            no floor. Smooth castings give weak corners where shading or a highlight curves, and those slide
            (module doc): on a realistic 720p Panda sweep set (benchmark pose 0, 8 motions, 416 tracks, scored
            against the simulator's surface points) 5 % of the tracks in the weakest quarter at detection
            (below 0.001) stayed within 1.5 px of their point and 42 % drifted over 3 px; in the strongest quarter
            (above 0.007) 52 % and 13 %. Off: at 0.002 (half the tracks gone at 1080p, the good share 24 -> 34 %,
            the drifting 33 -> 25 %) realistic Panda 1080p episodes on benchmark poses 0-3 ended 5.54e-4 rad /
            1.48 mm at 25 motions with 2 of 4 usable, against 4.45e-4 / 1.44 mm and 4 of 4 without
            (``docs/results/realistic-panda-1080p-4x1-floor0.002-ad2a563.json``): the fewer tracks cost more
            precision than the better ones gain accuracy.
        min_distance_px: least distance between two corners, and between a new corner and a live
            track when re-detecting; pixels. 10 -> 6 measured: on the saved realistic Panda sweeps scored against the
            simulator (``max_static_fraction``'s) 1080p 509 -> 701 tracks, good 122 -> 160, drifting 166 -> 261,
            spanning the sweep 126 -> 164; 720p 416 -> 594, good 91 -> 136 (``max_corners`` 400 or 800 alike).
            Rendered 1080p Panda poses 0-3 (bench-only commits d7f1a39, also 800 corners, and a3f2f75;
            ``docs/results/*-mindist6-*.json``), at 25 motions against 10 px: realistic 4.54e-4 rad / 1.26 mm, 4 of
            4 usable (4.45e-4 / 1.44, 4 of 4), 82 tracks per motion (58); as shipped with camera effects 1.36e-3 /
            3.38 mm, 2 of 4 usable (1.53e-3 / 3.33, 1 of 4; one of the two, pose 2, 6.05 mm off at a 1-sigma of
            2.55 mm); clean painted 4.3e-5 / 0.16 mm, 4 of 4 (5.41e-5 / 0.21, 4 of 4). Per run both ways, within
            what nearly identical trackers differ by, for about a quarter more tracking time: 10 stays.
        block_size: side of the window over which the structure tensor is summed; pixels, >= 3.
        win_size_px: side of the LK search window at every pyramid level; pixels, odd, >= 5.
        max_level: coarsest LK pyramid level (0 = no pyramid; each level halves the image); count.
        predicted_max_level: coarsest level for a track that has a last frame-to-frame step: LK starts
            where that step predicts (the joint turns smoothly: LK's result lies a median 0.19 px from the
            prediction, 99 % within 1.45 px, on a recorded clean 1080p episode; 0.36 / 2.59 px on realistic 720p)
            and searches this many levels, in a crop with a margin of (``win_size_px`` // 2 + 2) *
            2**level instead of 2**``max_level``; tracks without a step (new, found again, the first
            step) search from rest at ``max_level``. None: every track from rest. Plain LK
            (``affine_iterations`` 0) always starts from rest (``_lk_predicted``). None -> 1 measured:
            captured sweeps alone on the machine (12 clean 1080p: 14.2 -> 11.7 ms per frame, LK 5.8 -> 3.6
            ms, 2 894 -> 2 928 tracks; 8 realistic 720p: 7.4 -> 5.6 ms, LK 2.6 -> 1.5); against the
            simulator's truth on the same frames (``scripts/bench_tracking_truth.py --settings cold-lk,default
            --motions 6``, Panda pose 0) clean painted 1080p 213 -> 212 tracks, end error 0.25 -> 0.26 px, 78 %
            within 1 px both; realistic 720p 54 tracks both, median end error 2.84 -> 2.45 px (one motion of six
            4.11 -> 2.76 px, one 1.40 -> 1.48, the rest the same), 13 -> 15 %; two 8-motion realistic 720p
            episodes (poses 0, 1) 1.85 -> 1.87 px and 2.78 -> 2.75 px: no change in quality beyond single
            motions. Level 0 was as good on the clean sweeps (11.5 ms, 2 948 tracks) but leaves no room for a
            joint that speeds up.
        criteria: LK termination ``(type, max_iterations, epsilon_px)`` as ``cv2.TermCriteria``:
            type is a combination of ``cv2.TERM_CRITERIA_COUNT`` and ``cv2.TERM_CRITERIA_EPS``,
            epsilon is the update size in pixels below which the iteration stops.
        fb_max_px: forward–backward check: a point tracked frame k -> k+1 and back again must land
            within this distance of where it started, or its track ends at frame k; pixels.
        motion_threshold: a pixel moves if its grey level differs from the first frame's by more
            than this in at least ``mask_min_frames`` frames; grey levels (0..255).
        mask_min_frames: how many frames must show the change (more than one, so a single glitched
            frame does not mark the whole image as moving); frames, >= 1 (capped at F - 1).
        mask_open_px: side of the elliptical kernel that opens the thresholded mask (removes
            speckle narrower than this); pixels, 0 or 1 = no opening.
        mask_dilate_px: side of the elliptical kernel that then dilates the mask (fills uniform
            interiors, reaches corners on silhouettes); pixels, 0 or 1 = no dilation.
        redetect_every: every this many frames, detect new corners in moving regions farther than
            ``min_distance_px`` from every live track (up to ``max_corners`` live tracks); frames,
            0 = detect only in the first frame.
        min_track_frames: tracks with fewer frames than this are dropped; frames, >= 2.
        min_displacement_px: tracks whose points all stay within this distance of their first point
            are static and dropped; pixels.
        affine_iterations: most Gauss–Newton steps of the per-frame affine refinement against the
            track's first patch (a win_size_px square); count, 0 = plain LK (no refinement and no
            dissimilarity check; faster, but drifts on rotating links).
        affine_step_px: the affine refinement stops for a track once its translation step is below this;
            pixels, > 0. 0.03, not LK's 0.01 (``criteria``): a fitted patch errs by ~0.1 px per frame on
            clean painted sweeps, and 9 % of the tracks never got under 0.01 px and ran all
            ``affine_iterations``. On 12 captured clean 1080p sweeps the tracker took 8.4 -> 7.4 ms per
            frame; the truth figures of captured 720p sweeps did not move (clean painted: end error 0.56 ->
            0.55 px, within 1 px 59 % both; realistic: 2.71 -> 2.69 px, 16 % both).
        max_dissimilarity: a track ends when the RMS residual of its affine fit against its first
            patch, after removing the mean and the best gain (within ``max_gain_change``), exceeds
            this fraction of the first patch's standard deviation; dimensionless (0 = identical
            patches, about 1.4 = unrelated ones). 0.4, not the earlier 0.25: a
            casting turning under the light and the camera changes its look along the sweep, and
            measured on rendered Panda recordings with ground truth, 0.25 -> 0.4 kept 1.5x the tracks
            that follow a rigid point to < 1 px (realistic images: 109 -> 161 in 6 motions; clean
            painted: 932 -> 1413, their median error 0.034 -> 0.046 px), while 0.6 let corners on a
            turning plate's rim slide by up to 2.8 px (tests/arc_env/robot/test_tracking.py's sweeps).
        max_gain_change: the dissimilarity allows the patch's contrast to change by this factor either
            way (auto-exposure, a link turning under the light); dimensionless, >= 1 (1: no change).
        refind_frames: a track that LK loses or the forward-backward check ends is looked for again in
            this many frames (its own frame included), carried along by its neighbours' motion and
            fitted by the affine refinement (``_refind``); found, it continues with a gap. Frames, 0 =
            never (the default; needs ``affine_iterations`` > 0). Measured with ground truth on the first
            6 motions of rendered 1080p Panda recordings (tracks within 1 px of a rigid point / all kept),
            0 -> 3: realistic 161/368 -> 169/424, as shipped 193/565 -> 206/677, clean painted
            1413/1460 -> 1432/1485. On real surfaces a lost track is seldom a transient loss, so what
            comes back is mostly sliding points, which the solver's rigid check must drop; looking again
            for tracks the dissimilarity check ended was worse still (realistic 173/499).
        quadratic_warp: the refinement's patch map also has quadratic terms (12 parameters instead of the
            affine 6; the module doc says why). Measured on a textured cylinder rolling 0.6 rad
            (tests/arc_env/robot/test_tracking.py): signed error along the motion at the sweep's end,
            median -0.13 px affine, +0.002 px quadratic without the prior, -0.016 px with it; tracking
            time +17 %. Rendered 720p episodes, the same 25 motions re-rendered and tracked, translation
            error at 25 motions, affine / quadratic (0.1 prior, no bend check) / quadratic (0.1, 2 px):
            clean painted Panda pose 0 4.14 / 2.89 / 3.13 mm; realistic Panda pose 0 8.79 / 5.01 / 8.27,
            pose 1 1.16 / 2.00 / 0.84; realistic iiwa pose 0 9.48 / 8.78 / not run, pose 1 1.76 / 0.19 / not run;
            tracks per motion (realistic Panda) 53 / 54 / 25-30. Off by default until the bend check
            tells rim tracks from noisy ones.
        quadratic_ridge: strength of the prior pulling the quadratic terms towards 0, as a fraction of
            their mean Gauss–Newton curvature (0 = none). Without it, noisy realistic frames make the
            12-parameter fit unstable: on 4 rendered realistic 720p Panda sweeps the tracks kept were 240
            affine, 182 quadratic, 261 with 0.1 (the cylinder's lag: -0.016 px at 0.1, -0.08 at 1).
        max_bend_px: with the quadratic warp, a track ends when the quadratic part moves a corner of its
            patch by more than this; px. A patch on one smooth surface bends little (the rolling
            cylinder's curvature, radius 80 px turned 0.6 rad, bends a 21 px patch by about 0.4 px); one
            that straddles an edge bends to follow both sides and slides. On the test suite's in-plane and
            perspective plates, tracks kept / largest error: affine 92 / 0.58 px and 51 / 0.20 px;
            quadratic without the check 103 / 1.44 and 59 / 1.00 (tracks on the plate's rim); with 2 px
            91 / 0.34 and 51 / 0.33; with 1 px 83 / 0.20 and 48 / 0.26.
        window_sigma_px: the refinement weighs the patch's pixels by a Gaussian of this standard deviation
            about its centre (0 = a uniform window); px. The curvature lag grows with the window's second
            moment, so weighting the centre cuts it without new parameters (CPU per 1080p frame on 6 realistic
            sweeps: 8.9-9.2 ms against 8.0-8.3 ms uniform, on a busy machine). On the rolling cylinder
            (tests/arc_env/robot/test_tracking.py): median signed end error -0.132 px uniform, -0.087 at
            6 px, -0.060 at 4 px, -0.031 at 3 px. Rendered Panda 720p pose 0, 6 motions, against ray-cast truth
            (``scripts/bench_tracking_truth.py``), 0 -> 4 px: clean painted end error 1.23 -> 0.70 px, within 1 px
            38 -> 57 %, chord -4.63 -> -1.63 per mille; realistic 2.57 -> 2.79 px (the realistic error is mostly
            elsewhere: tracks on silhouettes). The same 25 motions re-rendered and tracked, error at 25 motions,
            0 -> 4 px: clean painted Panda 720p pose 0 4.14 -> 1.84 mm; realistic 720p Panda pose 0 9.54e-4 rad /
            8.79 mm -> 1.23e-3 / 2.82, pose 1 1.28e-3 / 1.16 -> 7.73e-4 / 1.28, iiwa pose 0 1.01e-3 / 9.48 ->
            2.03e-3 / 3.16, pose 1 8.45e-4 / 1.76 -> 6.82e-4 / 0.62, xArm6 pose 0 3.28e-3 / 5.58 -> 4.37e-3 / 4.77,
            pose 1 2.24e-3 / 1.30 -> 1.77e-3 / 1.16; realistic 1080p Panda poses 2-5 4.60e-4 / 0.94 -> 9.59e-4 /
            1.50, 4.34e-4 / 2.50 -> 4.26e-4 / 1.60, 4.69e-4 / 0.78 -> 1.65e-4 / 0.47, 7.34e-4 / 1.39 -> 6.43e-4 /
            0.15. Translation better on 8 of 10 realistic runs (worst 9.48 -> 4.77 mm), rotation on 6. (Those
            figures are without ``max_window_dissimilarity``; README "A Gaussian patch window" has the default's.)
        max_window_dissimilarity: with a Gaussian window, a track also ends when the dissimilarity of the whole
            window, unweighted, at the fitted map and gain exceeds this; dimensionless, as ``max_dissimilarity``.
            The weighted check weighs the rim little and misses a rim that slid onto other structure: on the
            plate sweeps with a 45 % contrast fall and with uneven steps single tracks ended 1.37 and 18.3 px
            off without it (tests/arc_env/robot/test_tracking.py); at 0.57 and 0.5 they pass, at 0.67 they do
            not. Judging the whole window alone at 0.4 instead kept fewer tracks on realistic 720p links (Panda
            poses 0-1, iiwa and xArm 6 pose 0: 48 / 38 / 42 / 33 per motion against 49 / 45 / 44 / 42 with the
            two checks); their calibrations at 25 motions (1.94 / 2.28 / 4.56 / 6.72 mm against 2.55 / 2.67 /
            6.64 / 4.47) differ by no more than single runs of nearly identical trackers do.
        max_static_fraction: a track is dropped whole when, once it has moved ``static_check_px`` from where it
            was detected, more than this fraction of its detection window (``win_size_px`` square, in place) shows
            the same grey levels as at detection (within 2.5 sigma of the frame pair's noise, estimated outside
            the moving mask; at least 1 grey level): the corner was not on a moving link but on what stays
            still, background or a link the joint does not move, next to an edge that passed (``static_fraction``).
            A window on a turning link changes where it has structure; one on a smooth casting has little, so
            this is a fraction, not a test that any pixel stayed. 1: no check (the default). Measured against
            the simulator's surface points on realistic Panda sweeps (benchmark pose 0, 8 motions, the same saved
            frames re-tracked; good: within 1.5 px all along, off: not on a moving link), 1 -> 0.6: at 1080p 509 ->
            434 tracks, good 122 -> 115, drifting over 3 px 166 -> 155, off the links 124 -> 68; at 720p 416 -> 327,
            good 91 -> 87, drifting 145 -> 126, off 101 -> 42; clean painted 720p (6 motions) unchanged. Yet the
            calibrations did not gain (bench-only commit 8294d3a, ``docs/results/*-still0.6-8294d3a.json``): realistic
            Panda 1080p poses 0-3 5.4e-4 rad / 1.53 mm at 25 motions, 3 of 4 usable, against 4.45e-4 / 1.44 and 4 of 4
            without; as shipped with camera effects 1.88e-3 / 2.31 mm, 0 of 4 usable, against 1.53e-3 / 3.33 and 1 of 4.
            The bundle adjustment's robust loss and per-track weights already make little of the off-link tracks; the
            few good tracks the check also drops are what counts.
        static_check_px: how far a track must have moved from its first point before ``max_static_fraction``
            judges it; pixels, > 0.
        shading_ramp: the patch fit also allows a linear brightness ramp across the patch (x and y, besides the
            offset and the gain) to change along the sweep: a link turning under a light changes its shading
            across a patch, and on weak texture that change pulls the fit along the shading's gradient
            (``_photometric_basis``). The whole window's check still compares at a plain offset: judged with the
            ramp too it let rim tracks slide (1.3 px on the test suite's contrast-change plate). Measured on nine
            realistic 720p sweep sets of 25 motions re-tracked both ways (benchmark poses: Panda 0-5, iiwa 1 and 3,
            xArm 6 1; the calibrator with the outlines, as the benchmark's; ``docs/realistic-imaging.md``, stop 50),
            off -> on: translation error at 25 motions better on 7, worse on 1 (median 0.46 -> 0.43 mm, mean 0.84 ->
            0.67), rotation better on 8 (median 0.69 -> 0.46 mrad); the tracks alone 1.65 -> 0.71 mm median (better
            on 8); against the simulator's surface points the median end error 2.37 -> 2.02 px, within 1 px all
            along 26 -> 31 %; tracks per motion 48 -> 39 (patches whose structure was mostly shading now fail the
            dissimilarity check: the spread it divides by has the ramp removed too).
        blas_threads: BLAS threads while ``track_keypoints`` works, restored after; None: leave BLAS as it is
            (``solver.threads``, where the measurement is).
    """

    max_corners: int = 400
    quality_level: float = 0.01
    min_eigenvalue: float = 0.0
    min_distance_px: float = 10.0
    block_size: int = 7
    win_size_px: int = 21
    max_level: int = 3
    predicted_max_level: int | None = 1
    criteria: tuple[int, int, float] = DEFAULT_CRITERIA
    fb_max_px: float = 0.5
    motion_threshold: int = 15
    mask_min_frames: int = 2
    mask_open_px: int = 3
    mask_dilate_px: int = 7
    redetect_every: int = 10
    min_track_frames: int = 10
    min_displacement_px: float = 3.0
    affine_iterations: int = 10
    affine_step_px: float = 0.03
    max_dissimilarity: float = 0.4
    max_gain_change: float = 1.5
    refind_frames: int = 0
    quadratic_warp: bool = False
    quadratic_ridge: float = 0.1
    max_bend_px: float = 2.0
    window_sigma_px: float = 4.0
    max_window_dissimilarity: float = 0.53
    max_static_fraction: float = 1.0
    static_check_px: float = 3.0
    shading_ramp: bool = True
    blas_threads: int | None = 1

    def __post_init__(self) -> None:
        check_blas_threads(self.blas_threads, "blas_threads")
        checks = [
            (self.max_corners >= 1, "max_corners must be >= 1"),
            (0.0 < self.quality_level < 1.0, "quality_level must be in (0, 1)"),
            (self.min_eigenvalue >= 0.0, "min_eigenvalue must be >= 0"),
            (self.min_distance_px >= 0.0, "min_distance_px must be >= 0"),
            (self.block_size >= 3, "block_size must be >= 3"),
            (self.win_size_px >= 5 and self.win_size_px % 2 == 1, "win_size_px must be odd and >= 5"),
            (0 <= self.max_level <= 8, "max_level must be in 0..8"),
            (self.predicted_max_level is None or 0 <= self.predicted_max_level <= self.max_level,
             "predicted_max_level must be None or in 0..max_level"),
            (self.fb_max_px > 0.0, "fb_max_px must be > 0"),
            (0 <= self.motion_threshold < 255, "motion_threshold must be in 0..254 grey levels"),
            (self.mask_min_frames >= 1, "mask_min_frames must be >= 1"),
            (self.mask_open_px >= 0, "mask_open_px must be >= 0"),
            (self.mask_dilate_px >= 0, "mask_dilate_px must be >= 0"),
            (self.redetect_every >= 0, "redetect_every must be >= 0 (0 = first frame only)"),
            (self.min_track_frames >= 2, "min_track_frames must be >= 2"),
            (self.min_displacement_px >= 0.0, "min_displacement_px must be >= 0"),
            (self.affine_iterations >= 0, "affine_iterations must be >= 0 (0 = plain LK)"),
            (self.affine_step_px > 0.0, "affine_step_px must be > 0"),
            (self.max_dissimilarity > 0.0, "max_dissimilarity must be > 0"),
            (self.max_window_dissimilarity > 0.0, "max_window_dissimilarity must be > 0"),
            (self.max_gain_change >= 1.0, "max_gain_change must be >= 1"),
            (self.refind_frames >= 0, "refind_frames must be >= 0 (0 = never look for lost tracks)"),
            (self.quadratic_ridge >= 0.0, "quadratic_ridge must be >= 0"),
            (self.max_bend_px > 0.0, "max_bend_px must be > 0"),
            (self.window_sigma_px >= 0.0, "window_sigma_px must be >= 0 (0 = a uniform window)"),
            (0.0 < self.max_static_fraction <= 1.0, "max_static_fraction must be in (0, 1] (1 = no check)"),
            (self.static_check_px > 0.0, "static_check_px must be > 0"),
        ]
        for ok, message in checks:
            if not ok:
                raise InvalidInputError(f"TrackerConfig: {message}")
        criteria = tuple(self.criteria)
        valid_types = cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS
        if (len(criteria) != 3 or not 0 < int(criteria[0]) <= valid_types or int(criteria[1]) < 1
                or not float(criteria[2]) >= 0.0):
            raise InvalidInputError(
                "TrackerConfig: criteria must be (type, max_iterations >= 1, epsilon_px >= 0) with type "
                f"a combination of cv2.TERM_CRITERIA_COUNT and cv2.TERM_CRITERIA_EPS, got {self.criteria}"
            )
        object.__setattr__(self, "criteria", (int(criteria[0]), int(criteria[1]), float(criteria[2])))


@dataclass(frozen=True)
class TrackingResult:
    """What ``track_keypoints`` found in one sweep.

    Every detected corner ends up in exactly one place: ``n_detected == len(tracks) + n_dropped_fb
    + n_dropped_dissimilar + n_dropped_short + n_dropped_static + n_dropped_background``.

    Attributes:
        tracks: the kept tracks, pixels (M, 2) float64 and delta (M,) float64 rad each, over
            frames in order (a track that was lost and found again skips the frames between).
        n_detected: corners detected (first frame and re-detections); count.
        n_dropped_fb: tracks ended by the forward–backward check (or LK failure, or leaving the
            image) before reaching ``min_track_frames``; count.
        n_dropped_dissimilar: tracks ended by the affine dissimilarity check before reaching
            ``min_track_frames``; count.
        n_dropped_short: tracks that reached the last frame but have fewer than ``min_track_frames``
            frames (late re-detections); count.
        n_dropped_static: long-enough tracks that never left ``min_displacement_px`` of their start; count.
        n_dropped_background: tracks whose detection window stayed still while they moved
            (``TrackerConfig.max_static_fraction``); count.
        n_truncated: kept tracks that a check ended before the last frame (their prefix is kept); count.
        seconds: wall-clock time of the whole call; seconds.
    """

    tracks: list[KeypointTrack]
    n_detected: int
    n_dropped_fb: int
    n_dropped_dissimilar: int
    n_dropped_short: int
    n_dropped_static: int
    n_truncated: int
    seconds: float
    n_dropped_background: int = 0


def _grey_frames(frames: Sequence[ImageArray]) -> list[ImageArray]:
    """Validate the frames and return them as C-contiguous (H, W) uint8 greyscale images."""
    try:
        n_frames = len(frames)
    except TypeError as exc:
        raise InvalidInputError(f"frames must be a sequence of images, got {type(frames).__name__}") from exc
    if n_frames < 2:
        raise InvalidInputError(f"need at least 2 frames to track, got {n_frames}")
    greys: list[ImageArray] = []
    shape: tuple[int, ...] | None = None
    for i, frame in enumerate(frames):
        image = np.asarray(frame)
        if image.dtype != np.uint8:
            raise InvalidInputError(f"frame {i} must be uint8, got {image.dtype}")
        if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
            raise InvalidInputError(f"frame {i} must be (H, W) grey or (H, W, 3) RGB, got shape {image.shape}")
        if image.shape[0] == 0 or image.shape[1] == 0:
            raise InvalidInputError(f"frame {i} is empty (shape {image.shape})")
        if shape is None:
            shape = image.shape
        elif image.shape != shape:
            raise InvalidInputError(f"frame {i} has shape {image.shape}, but frame 0 has shape {shape}")
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else np.ascontiguousarray(image)
        greys.append(grey)
    return greys


def _moving_mask_u8(greys: list[ImageArray], config: TrackerConfig) -> ImageArray:
    """(H, W) uint8 mask, 255 where the sweep changes the image (see ``moving_mask``)."""
    return changed_pixels(greys, config.motion_threshold, config.mask_min_frames, config.mask_open_px,
                          config.mask_dilate_px)


def moving_mask(frames: Sequence[ImageArray], config: TrackerConfig | None = None) -> MaskArray:
    """Pixels whose intensity changes during a sweep, from the images alone.

    A pixel moves if its grey level differs from the first frame's by more than
    ``config.motion_threshold`` in at least ``config.mask_min_frames`` frames; the mask is then opened
    (speckle removed) and dilated. It covers every place the moving links pass through, including
    background they uncover or cover (the tracker's checks drop corners found there).

    Args:
        frames: F >= 2 images of one sweep, each (H, W) uint8 grey or (H, W, 3) uint8 RGB.
        config: thresholds and kernel sizes; ``TrackerConfig()`` if None.

    Returns:
        (H, W) bool: True where the image changes.

    Raises:
        InvalidInputError: fewer than 2 frames, frames of different shapes, empty or non-uint8 images.
    """
    config = TrackerConfig() if config is None else config
    return _moving_mask_u8(_grey_frames(frames), config) > 0


def _detect(image: ImageArray, mask: ImageArray, live: NDArray[np.float32], n_max: int,
            config: TrackerConfig) -> NDArray[np.float32]:
    """(n, 2) float32 Shi–Tomasi corners in ``mask``, at least min_distance_px from the ``live`` points."""
    if n_max <= 0:
        return np.empty((0, 2), np.float32)
    if live.shape[0] and config.min_distance_px > 0:
        mask = mask.copy()
        radius = int(np.ceil(config.min_distance_px))
        for x, y in np.rint(live).astype(np.int32):
            cv2.circle(mask, (int(x), int(y)), radius, 0, thickness=-1)
    quality = config.quality_level
    if config.min_eigenvalue > 0:
        strongest = float(cv2.minMaxLoc(cv2.cornerMinEigenVal(image, config.block_size), mask)[1])
        if strongest < config.min_eigenvalue:
            return np.empty((0, 2), np.float32)
        quality = min(max(quality, config.min_eigenvalue / strongest), 1.0 - 1e-9)
    corners = cv2.goodFeaturesToTrack(image, maxCorners=n_max, qualityLevel=quality,
                                      minDistance=config.min_distance_px, mask=mask,
                                      blockSize=config.block_size)
    if corners is None:
        return np.empty((0, 2), np.float32)
    return corners.reshape(-1, 2).astype(np.float32)


def _box(x: int, y: int, w: int, h: int, shape: tuple[int, ...],
         config: TrackerConfig, level: int | None = None) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1): the box (x, y, w, h) grown by the LK window's reach at level ``level`` (None: max_level)."""
    scale = 1 << (config.max_level if level is None else level)
    margin = (config.win_size_px // 2 + 2) * scale
    # Start on a multiple of the coarsest scale so the crop's pyramid samples the same pixels as the frame's.
    x0 = max(0, x - margin) // scale * scale
    y0 = max(0, y - margin) // scale * scale
    return x0, y0, min(shape[1], x + w + margin), min(shape[0], y + h + margin)


def _roi(mask: ImageArray, config: TrackerConfig) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) crop holding the mask and the LK window's reach, or None for an empty mask."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        return None
    return _box(x, y, w, h, mask.shape, config)


def _lk_step(prev: ImageArray, nxt: ImageArray, pts: NDArray[np.float32], config: TrackerConfig,
             guess: NDArray[np.float32] | None = None) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Pyramidal LK from ``prev`` to ``nxt`` with the forward–backward check.

    Both images are cropped to the points' bounding box plus the window's reach first: OpenCV builds
    the pyramids of the whole image it is given, and the live points usually cover a fraction of it.
    With ``guess`` (n, 2), each point's predicted position in ``nxt``, LK starts there and searches only
    ``config.predicted_max_level`` levels (a smaller crop and fewer levels); the backward pass starts at
    the forward result minus the same predicted step, so it is as independent of the guess as the
    forward pass.

    Returns:
        (n, 2) float32 positions in ``nxt`` and (n,) bool: LK found the point both ways and the round
        trip closed within ``config.fb_max_px``.
    """
    level = config.max_level if guess is None or config.predicted_max_level is None else config.predicted_max_level
    reach = pts if guess is None else np.concatenate([pts, guess])
    lo = np.floor(reach.min(axis=0)).astype(int)
    hi = np.ceil(reach.max(axis=0)).astype(int)
    x0, y0, x1, y1 = _box(int(lo[0]), int(lo[1]), int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1,
                          prev.shape, config, level)
    offset = np.array([x0, y0], dtype=np.float32)
    local = pts - offset
    lk = {"winSize": (config.win_size_px, config.win_size_px), "maxLevel": level, "criteria": config.criteria}
    prev_crop, next_crop = prev[y0:y1, x0:x1], nxt[y0:y1, x0:x1]
    if guess is None:
        forward, status_f, _ = cv2.calcOpticalFlowPyrLK(prev_crop, next_crop, local, None, **lk)
        backward, status_b, _ = cv2.calcOpticalFlowPyrLK(next_crop, prev_crop, forward, None, **lk)
    else:
        start = np.ascontiguousarray(guess - offset, dtype=np.float32)
        forward, status_f, _ = cv2.calcOpticalFlowPyrLK(prev_crop, next_crop, local, start.copy(),
                                                        flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
        back_start = np.ascontiguousarray(forward.reshape(-1, 2) - (start - local), dtype=np.float32)
        backward, status_b, _ = cv2.calcOpticalFlowPyrLK(next_crop, prev_crop, forward, back_start,
                                                         flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **lk)
    forward, backward = forward.reshape(-1, 2), backward.reshape(-1, 2)
    ok = ((status_f.ravel() == 1) & (status_b.ravel() == 1)
          & (np.linalg.norm(backward - local, axis=1) <= config.fb_max_px))
    return forward + offset, ok


def _lk_predicted(prev: ImageArray, nxt: ImageArray, live: _LiveTracks,
                  config: TrackerConfig) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """``_lk_step`` for the live tracks, those with a last step (``_LiveTracks.step``) started where it predicts.

    A track's last frame-to-frame step predicts its next (the joint turns smoothly); tracks without one
    (new, found again, or the sweep's first step) search all ``config.max_level`` levels from rest. Plain LK
    (``affine_iterations`` 0) always starts from rest: started at the prediction, a search that does not move
    (on a frame with no structure) closes its round trip, so the forward-backward check, its only check, passes it.
    """
    if config.predicted_max_level is None or config.affine_iterations == 0:
        return _lk_step(prev, nxt, live.pts, config)
    warm = np.isfinite(live.step[:, 0])
    if not np.any(warm):
        return _lk_step(prev, nxt, live.pts, config)
    forward = np.empty_like(live.pts)
    ok = np.zeros(len(live), dtype=bool)
    forward[warm], ok[warm] = _lk_step(prev, nxt, live.pts[warm], config, live.pts[warm] + live.step[warm])
    if not np.all(warm):
        forward[~warm], ok[~warm] = _lk_step(prev, nxt, live.pts[~warm], config)
    return forward, ok


#: The affine refinement may move a point at most this far from its LK estimate; pixels. A farther
#: fit has slid onto another structure (one LK step errs by ~0.05 px, its rotation bias by ~0.1 px).
_MAX_REFINE_SHIFT_PX = 2.0

#: Largest area change of a patch the affine fit may report (a factor): det(A) must lie in [1/4, 4].
_MAX_AREA_RATIO = 4.0

#: A lost track is carried along by the affine motion of this many nearest live tracks (``_refind``).
_REFIND_NEIGHBOURS = 8

#: Why a track ended before the last frame (``_ENDED_BACKGROUND``: dropped whole, ``max_static_fraction``).
_RUNNING, _ENDED_FB, _ENDED_DISSIMILAR, _ENDED_BACKGROUND = 0, 1, 2, 3


@dataclass
class _LiveTracks:
    """The live tracks and, per track, its first-frame patch for the affine refinement (P pixels).

    Attributes:
        ids: (n,) int64: track ids.
        pts: (n, 2) float32, pixels in the crop: positions in the current frame.
        template: (n, P) float32, grey levels: the first patch minus its mean.
        scale: (n,) float32, grey levels: the first patch's standard deviation (weighted by the window).
        window_scale: (n,) float32, grey levels: the first patch's unweighted standard deviation.
        rim_template: (n, P) float32, grey levels: with ``TrackerConfig.shading_ramp``, the first patch minus its
            plain mean (the whole window's check compares against it); (n, 0) without.
        steepest: (n, 6, P) float32: steepest-descent images of the affine parameters
            (a11, a12, a21, a22, tx, ty) at the identity, mean removed.
        hessian_inv: (n, 6, 6) float64: inverse Gauss–Newton Hessians (with the quadratic warp: (n, 12, 12)
            for (a11, a12, a21, a22, tx, ty, qx_xx, qx_xy, qx_yy, qy_xx, qy_xy, qy_yy), steepest (n, 12, P)).
        A: (n, 2, 2) float64: current linear part of the patch's map (first frame -> current).
        Q: (n, 2, 3) float64, px: current quadratic part, the coefficients of ``_monomials`` (zeros unless
            ``TrackerConfig.quadratic_warp``).
        ridge: (n,) float64: strength of each track's prior pulling Q towards 0 (``quadratic_ridge``).
        step: (n, 2) float32, px: each track's last frame-to-frame step, NaN where it has none (new or
            found again); where it has one, LK starts from it (``_lk_predicted``).
        origin: (n, 2) float32, pixels in the crop: where each track was detected.
        born: (n,) int64: the frame each track was detected in.
        judged: (n,) bool: whether ``TrackerConfig.max_static_fraction`` has judged the track yet.
    """

    ids: NDArray[np.int64]
    pts: NDArray[np.float32]
    template: NDArray[np.float32]
    scale: NDArray[np.float32]
    window_scale: NDArray[np.float32]
    rim_template: NDArray[np.float32]
    steepest: NDArray[np.float32]
    hessian_inv: NDArray[np.float64]
    A: NDArray[np.float64]
    Q: NDArray[np.float64]
    ridge: NDArray[np.float64]
    step: NDArray[np.float32]
    origin: NDArray[np.float32]
    born: NDArray[np.int64]
    judged: NDArray[np.bool_]

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def select(self, keep: NDArray[np.bool_]) -> _LiveTracks:
        if np.all(keep):
            return self
        return _LiveTracks(**{f.name: getattr(self, f.name)[keep] for f in fields(self)})

    def extend(self, other: _LiveTracks) -> _LiveTracks:
        # An empty set's patch arrays may have other widths (none detected in a sweep's first frame): nothing to keep.
        if len(other) == 0:
            return self
        if len(self) == 0:
            return other
        return _LiveTracks(**{f.name: np.concatenate([getattr(self, f.name), getattr(other, f.name)])
                              for f in fields(self)})


def _patch_offsets(win_size_px: int) -> NDArray[np.float32]:
    """(P, 2) float32, pixels: the (x, y) offsets of a win_size_px square, row by row."""
    half = win_size_px // 2
    r = np.arange(-half, half + 1, dtype=np.float32)
    gx, gy = np.meshgrid(r, r)
    return np.column_stack([gx.ravel(), gy.ravel()])


def _new_tracks(image: ImageArray, pts: NDArray[np.float32], first_id: int, frame: int,
                config: TrackerConfig) -> _LiveTracks:
    """Tracks starting at ``pts`` in ``image``, frame number ``frame``, with their patches if the affine fit is on."""
    n = pts.shape[0]
    start = (pts.copy(), np.full(n, frame, np.int64), np.zeros(n, dtype=bool))
    ids = np.arange(first_id, first_id + n, dtype=np.int64)
    no_step = np.full((n, 2), np.nan, np.float32)
    A = np.tile(np.eye(2), (n, 1, 1))
    Q = np.zeros((n, 2, 3))
    if config.affine_iterations == 0 or n == 0:
        return _LiveTracks(ids, pts, np.zeros((n, 0), np.float32), np.ones(n, np.float32), np.ones(n, np.float32),
                           np.zeros((n, 0), np.float32),
                           np.zeros((n, 6, 0), np.float32), np.zeros((n, 6, 6)), A, Q, np.zeros(n), no_step, *start)
    w = config.win_size_px
    # Sample a one-pixel larger square so central differences cover the whole patch.
    r = np.arange(-(w // 2) - 1, w // 2 + 2, dtype=np.float32)
    gx, gy = np.meshgrid(r, r)
    map_x = (pts[:, 0, None, None] + gx).reshape(n * (w + 2), w + 2)
    map_y = (pts[:, 1, None, None] + gy).reshape(n * (w + 2), w + 2)
    big = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    big = big.reshape(n, w + 2, w + 2).astype(np.float32)
    patch = big[:, 1:-1, 1:-1].reshape(n, -1)
    dx = (0.5 * (big[:, 1:-1, 2:] - big[:, 1:-1, :-2])).reshape(n, -1)
    dy = (0.5 * (big[:, 2:, 1:-1] - big[:, :-2, 1:-1])).reshape(n, -1)
    offsets = _patch_offsets(w)
    x, y = offsets[:, 0], offsets[:, 1]
    rows = [dx * x, dx * y, dy * x, dy * y, dx, dy]
    if config.quadratic_warp:
        mono = _monomials(x, y, w // 2)
        rows += [dx * mono[:, i] for i in range(3)] + [dy * mono[:, i] for i in range(3)]
    steepest = np.stack(rows, axis=1)
    root = _root_weights(config)
    basis = _photometric_basis(config)
    steepest = _centred(steepest, root, basis)
    hessian = np.matmul(steepest, steepest.transpose(0, 2, 1)).astype(np.float64)
    p = hessian.shape[1]
    hessian += 1e-9 * np.trace(hessian, axis1=1, axis2=2)[:, None, None] * np.eye(p) + 1e-12 * np.eye(p)
    ridges = np.zeros(n)
    if p == 12 and config.quadratic_ridge > 0:
        ridges = config.quadratic_ridge * np.trace(hessian[:, 6:, 6:], axis1=1, axis2=2) / 6.0
        hessian[:, 6:, 6:] += ridges[:, None, None] * np.eye(6)
    template = _centred(patch, root, basis)
    # the patch's (weighted) standard deviation: the RMS of the centred, weighted template
    spread = np.sqrt(np.mean(template * template, axis=1))
    scale = np.maximum(spread, 1e-3).astype(np.float32)
    window_scale = scale if root is None else np.maximum(patch.std(axis=1), 1e-3).astype(np.float32)
    rim_template = (patch - patch.mean(axis=1, keepdims=True) if basis is not None and root is not None
                    else np.zeros((n, 0), np.float32))
    return _LiveTracks(ids, pts, template, scale, window_scale, rim_template, steepest, np.linalg.inv(hessian), A, Q,
                       ridges, no_step, *start)


def _root_weights(config: TrackerConfig) -> NDArray[np.float32] | None:
    """(P,) float32: square roots of the patch pixels' Gaussian weights (mean 1), or None for a uniform window."""
    if config.window_sigma_px <= 0:
        return None
    return _gaussian_root_weights(config.win_size_px, config.window_sigma_px)


@functools.lru_cache(maxsize=8)
def _gaussian_root_weights(win_size_px: int, sigma_px: float) -> NDArray[np.float32]:
    """``_root_weights`` of a Gaussian window, computed once per (window, sigma) (read-only: it is shared)."""
    offsets = _patch_offsets(win_size_px)
    weights = np.exp(-0.5 * np.sum(offsets * offsets, axis=1) / sigma_px**2)
    root = np.sqrt(weights / weights.mean()).astype(np.float32)
    root.flags.writeable = False
    return root


def _photometric_basis(config: TrackerConfig) -> NDArray[np.float32] | None:
    """(P, 3) float32 orthonormal columns spanning the root weights times (1, x, y) over the patch, or None.

    What the patch fit leaves out of every patch with ``TrackerConfig.shading_ramp`` (projecting it out eliminates a
    brightness offset and a linear ramp as free parameters of the fit); None without it (only the offset goes, by
    ``_centred``'s mean).
    """
    if not config.shading_ramp:
        return None
    return _ramp_basis(config.win_size_px, config.window_sigma_px)


@functools.lru_cache(maxsize=8)
def _ramp_basis(win_size_px: int, sigma_px: float) -> NDArray[np.float32]:
    """``_photometric_basis``'s (P, 3) columns for a window and Gaussian sigma (0: uniform), once (read-only)."""
    offsets = _patch_offsets(win_size_px).astype(np.float64)
    root = np.ones(len(offsets)) if sigma_px <= 0 else _gaussian_root_weights(win_size_px, sigma_px).astype(np.float64)
    q, _ = np.linalg.qr(root[:, None] * np.column_stack([np.ones(len(offsets)), offsets]))
    basis = q.astype(np.float32)
    basis.flags.writeable = False
    return basis


def _centred(values: NDArray[np.float32], root: NDArray[np.float32] | None,
             basis: NDArray[np.float32] | None = None) -> NDArray[np.float32]:
    """Patches (..., P) minus their (weighted) mean, times the root weights: invariant to a brightness offset.

    With a ``_photometric_basis`` (P, k): the (weighted) patches minus their projection on it: invariant to an
    offset and a linear brightness ramp.
    """
    if basis is not None:
        u = values if root is None else values * root
        return (u - (u @ basis) @ basis.T).astype(np.float32, copy=False)
    if root is None:
        return values - values.mean(axis=-1, keepdims=True)
    weights = root * root
    return ((values - (values @ weights / weights.sum())[..., None]) * root).astype(np.float32, copy=False)


def _bend_px(Q: FloatArray, half: int) -> FloatArray:
    """(n,) px: the largest displacement the quadratic part Q (n, 2, 3) gives a corner of the patch."""
    return half * np.max(np.sum(np.abs(Q), axis=2), axis=1)


def _monomials(x: FloatArray, y: FloatArray, half: int) -> FloatArray:
    """(..., 3): (x^2, xy, y^2) / half of offsets x, y (...) px: the quadratic warp's basis, O(half) at the rim."""
    return np.stack([x * x, x * y, y * y], axis=-1) / float(half)



def _refine_affine(image: ImageArray, live: _LiveTracks, guess: NDArray[np.float32],
                   config: TrackerConfig) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Fit each track's first patch to ``image`` by an affine map, or a quadratic one (inverse-compositional LK).

    Args:
        image: (h, w) uint8 crop of the current frame.
        live: the tracks; ``live.A`` is the previous frame's fit and is updated in place.
        guess: (n, 2) float32, pixels: LK positions in ``image`` (the translation's start value).
        config: iterations, window and the translation step (``affine_step_px``) that counts as converged.

    Returns:
        (n, 2) float64 refined positions, (n,) float64 dissimilarities, (n,) bool fit succeeded.
    """
    n = len(live)
    w = config.win_size_px
    offsets = _patch_offsets(w)
    t = guess.astype(np.float64)
    A = live.A.copy()
    rms = np.full(n, np.inf)
    valid = np.ones(n, dtype=bool)
    active = np.arange(n)
    eps = config.affine_step_px
    x, y = offsets[:, 0], offsets[:, 1]
    quadratic = live.steepest.shape[1] == 12
    root = _root_weights(config)
    photometric = _photometric_basis(config)
    Q = live.Q.copy()
    if quadratic:
        half = w // 2
        mono = _monomials(x, y, half).astype(np.float32)
    # The patch's map as one product: rows (m, k) of map coefficients times the (k, P) basis (x, y, 1[, monomials]).
    basis = np.vstack([x, y, np.ones_like(x)] + ([mono.T] if quadratic else []))
    energy = np.maximum(np.sum(live.template * live.template, axis=1), 1e-6)  # (n,): the gain's denominator
    for iteration in range(config.affine_iterations):
        if active.size == 0:
            break
        m = active.size
        every = m == n  # index only once some points have converged: fancy indexing copies
        template = live.template if every else live.template[active]
        steepest = live.steepest if every else live.steepest[active]
        hessian_inv = live.hessian_inv if every else live.hessian_inv[active]
        coefficients = np.empty((2, m, basis.shape[0]), np.float32)  # map_x's rows, then map_y's
        coefficients[:, :, :2] = np.transpose(A[active], (1, 0, 2))
        coefficients[:, :, 2] = t[active].T
        if quadratic:
            coefficients[:, :, 3:] = np.transpose(Q[active], (1, 0, 2))
        maps = coefficients.reshape(2 * m, -1) @ basis  # (2m, P): map_x, then map_y
        warped = cv2.remap(image, maps[:m].reshape(m * w, w), maps[m:].reshape(m * w, w), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REPLICATE)
        raw = warped.reshape(m, -1).astype(np.float32)
        warped = _centred(raw, root, photometric)
        # The patch's contrast may have changed (exposure, shading): compare at the best gain.
        gain = np.sum(warped * template, axis=1) / (energy if every else energy[active])
        gain = np.clip(gain, 1.0 / config.max_gain_change, config.max_gain_change)[:, None]
        error = warped / gain - template
        gradient = np.matmul(steepest, error[..., None]).astype(np.float64)
        if quadratic and config.quadratic_ridge > 0:  # the prior pulls the quadratic part towards 0
            gradient[:, 6:, 0] += (live.ridge if every else live.ridge[active])[:, None] * Q[active].reshape(-1, 6)
        step = np.matmul(hessian_inv, gradient)[..., 0]
        sane = (np.all(np.isfinite(step), axis=1) & np.all(np.abs(step[:, :4]) < 0.5, axis=1)
                & np.all(np.abs(step[:, 6:]) < 0.5, axis=1)
                & np.all(np.abs(step[:, 4:]) < w / 2, axis=1))
        # The dissimilarity at this map, of the tracks that stop here (failed, converged, or out of iterations).
        converged = np.max(np.abs(step[:, 4:6]), axis=1) < eps  # the translation's step
        leaving = ~sane | converged | (iteration == config.affine_iterations - 1)
        if np.any(leaving):
            going = active[leaving]
            whole = None
            if live.rim_template.shape[1]:  # the whole window against the first patch at a plain offset and the gain
                rim = raw[leaving]
                whole = (rim - rim.mean(axis=1, keepdims=True)) / gain[leaving] - live.rim_template[going]
            rms[going] = _dissimilarity(error[leaving], live.scale[going], live.window_scale[going], root, config,
                                        whole)
        valid[active[~sane]] = False
        active, step, converged = active[sane], step[sane], converged[sane]
        if quadratic:
            # W <- W o W_step^-1 to first order in the step (the exact inverse of a quadratic map is not
            # quadratic): W(x - s(x)) = W(x) - (A + Q dm/dx) s(x), s(x) = d + D x + E m(x), cubic terms dropped.
            D, d, E = step[:, :4].reshape(-1, 2, 2), step[:, 4:6], step[:, 6:].reshape(-1, 2, 3)
            a, q = A[active], Q[active]
            zero = np.zeros(active.size)
            # Q (dm/dx) d = Q M_d x / half and Q (dm/dx) D x = Q M_D m(x), m(x) = (x^2, xy, y^2) / half.
            M_d = np.stack([np.stack([2 * d[:, 0], zero], 1), np.stack([d[:, 1], d[:, 0]], 1),
                            np.stack([zero, 2 * d[:, 1]], 1)], 1) / half
            M_D = np.stack([np.stack([2 * D[:, 0, 0], 2 * D[:, 0, 1], zero], 1),
                            np.stack([D[:, 1, 0], D[:, 0, 0] + D[:, 1, 1], D[:, 0, 1]], 1),
                            np.stack([zero, 2 * D[:, 1, 0], 2 * D[:, 1, 1]], 1)], 1)
            t[active] -= np.matmul(a, d[..., None])[..., 0]
            A[active] = a - np.matmul(a, D) - np.matmul(q, M_d)
            Q[active] = q - np.matmul(a, E) - np.matmul(q, M_D)
            active = active[~converged]
            continue
        # Compose with the inverse of the increment: A <- A (I + D)^-1, t <- t - A_new d.
        A_new = np.matmul(A[active], _inverse_2x2(np.eye(2) + step[:, :4].reshape(-1, 2, 2)))
        t[active] -= np.matmul(A_new, step[:, 4:, None])[..., 0]
        A[active] = A_new
        active = active[~converged]
    det = np.linalg.det(A)
    valid &= ((det > 1.0 / _MAX_AREA_RATIO) & (det < _MAX_AREA_RATIO)
              & (np.linalg.norm(t - guess, axis=1) <= _MAX_REFINE_SHIFT_PX))
    if quadratic:  # a patch bent this far is not on one smooth surface: it straddles an edge
        valid &= _bend_px(Q, w // 2) <= config.max_bend_px
    live.A = A
    live.Q = Q
    return t, rms, valid


def _dissimilarity(error: NDArray[np.float32], scale: NDArray[np.float32], window_scale: NDArray[np.float32],
                   root: NDArray[np.float32] | None, config: TrackerConfig,
                   whole: NDArray[np.float32] | None = None) -> FloatArray:
    """(m,) the patches' dissimilarities (``TrackerConfig.max_dissimilarity``) from their fit residuals (m, P).

    The RMS of the (weighted) residual over the first patch's spread ``scale`` (m,); with a Gaussian window also the
    whole window's, unweighted, over ``window_scale`` (m,), scaled to the same threshold: a rim that slid. That
    residual is ``whole`` (m, P) when given (the window compared at a plain offset, though the fit allowed a shading
    ramp: a slid rim is a ramp-like change the weighted fit would absorb), else ``error`` unweighted.
    """
    rms = np.sqrt(np.mean(error * error, axis=1)) / scale.astype(np.float64)
    if root is None:
        return rms
    if whole is None:
        whole = error / root
        whole -= whole.mean(axis=1, keepdims=True)
    rim = np.sqrt(np.mean(whole * whole, axis=1)) / window_scale
    return np.maximum(rms, rim * (config.max_dissimilarity / config.max_window_dissimilarity))


def _inverse_2x2(M: FloatArray) -> FloatArray:
    """(n, 2, 2) inverses of (n, 2, 2) matrices, in closed form (``np.linalg.inv`` costs more on a stack of 2x2)."""
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    inverse = np.empty_like(M)
    inverse[:, 0, 0], inverse[:, 1, 1] = M[:, 1, 1] / det, M[:, 0, 0] / det
    inverse[:, 0, 1], inverse[:, 1, 0] = -M[:, 0, 1] / det, -M[:, 1, 0] / det
    return inverse


def _refind(image: ImageArray, lost: _LiveTracks, lost_at: NDArray[np.int64], moved_from: FloatArray,
            moved_to: FloatArray, config: TrackerConfig
            ) -> tuple[_LiveTracks, NDArray[np.int64], _LiveTracks, NDArray[np.int64]]:
    """Look for lost tracks in ``image``: (found, their loss frames, still lost, their loss frames).

    A lost track is carried along by the affine map that moves its ``_REFIND_NEIGHBOURS`` nearest live
    tracks this frame (least squares; ``moved_from`` (m, 2) -> ``moved_to`` (m, 2), pixels in the crop;
    the moving links turn rigidly, so nearby points move alike), then its first patch is fitted there by the affine
    refinement. It is found when the fit converges within ``_MAX_REFINE_SHIFT_PX`` of the prediction with
    a dissimilarity within ``config.max_dissimilarity`` and inside the image; found tracks carry the
    refined position in ``pts``, the rest the prediction.
    """
    predicted = lost.pts.astype(np.float64)
    if moved_from.shape[0] >= 3:
        # An affine map of the nearest live tracks' motion (exact for a turn in the image plane).
        n = min(_REFIND_NEIGHBOURS, moved_from.shape[0])
        distance = np.linalg.norm(predicted[:, None, :] - moved_from[None, :, :], axis=2)
        nearest = np.argpartition(distance, n - 1, axis=1)[:, :n]  # (l, n)
        centre = moved_from[nearest].mean(axis=1, keepdims=True)  # (l, 1, 2) conditions the fit
        design = np.concatenate([moved_from[nearest] - centre, np.ones(nearest.shape + (1,))], axis=2)  # (l, n, 3)
        normal = np.einsum("lni,lnj->lij", design, design) + 1e-6 * np.eye(3)
        maps = np.linalg.solve(normal, np.einsum("lni,lnj->lij", design, moved_to[nearest]))  # (l, 3, 2)
        predicted = np.einsum("li,lij->lj", np.append(predicted - centre[:, 0], np.ones((len(lost), 1)), axis=1),
                              maps)
    previous_A, previous_Q = lost.A.copy(), lost.Q.copy()
    refined, dissimilarity, ok = _refine_affine(image, lost, predicted.astype(np.float32), config)
    h, w = image.shape[:2]
    ok &= ((dissimilarity <= config.max_dissimilarity) & np.all(refined >= 0, axis=1)
           & (refined[:, 0] <= w - 1) & (refined[:, 1] <= h - 1))
    lost.A[~ok] = previous_A[~ok]
    lost.Q[~ok] = previous_Q[~ok]
    lost.pts = np.where(ok[:, None], refined, predicted).astype(np.float32)
    return lost.select(ok), lost_at[ok], lost.select(~ok), lost_at[~ok]


#: Most pixels outside the moving mask that estimate a frame pair's noise (``_still_sample``).
_NOISE_SAMPLES = 20_000


def _still_sample(mask: ImageArray) -> NDArray[np.int64]:
    """(s,) int64: flat indices of up to ``_NOISE_SAMPLES`` pixels outside ``mask`` (H, W) uint8, evenly spread."""
    outside = np.flatnonzero(mask.ravel() == 0)
    return outside[::max(1, outside.size // _NOISE_SAMPLES)]


def static_tolerance(first: ImageArray, current: ImageArray, still: NDArray[np.int64]) -> float:
    """Grey levels: the largest change of a pixel that stays still between two frames (H, W) uint8.

    2.5 sigma of the pair's noise, sigma from the median absolute difference at the pixels ``still`` (flat
    indices, outside the moving mask; ``solver.schur.robust_sigma``, 1.4826 x MAD), and at least 1 (noise-free
    renders: a still pixel is equal).
    """
    if still.size == 0:
        return 1.0
    difference = np.abs(current.ravel()[still].astype(np.int16) - first.ravel()[still].astype(np.int16))
    return max(1.0, 2.5 * robust_sigma(difference))


def static_fraction(first: ImageArray, current: ImageArray, centres: FloatArray, half: int,
                    tolerance: float) -> FloatArray:
    """(m,) the fraction of each window whose grey level did not change between two frames.

    Args:
        first: (H, W) uint8: the frame the windows were taken in.
        current: (H, W) uint8: a later frame.
        centres: (m, 2) pixels: the windows' centres (rounded), each a (2 half + 1) square, cut at the image's edge.
        half: the windows' half side; pixels.
        tolerance: grey levels: a pixel is unchanged if it differs by less than this (``static_tolerance``).
    """
    h, w = first.shape
    out = np.zeros(centres.shape[0])
    for i, (x, y) in enumerate(np.rint(centres).astype(np.int64)):
        ya, yb, xa, xb = max(y - half, 0), min(y + half + 1, h), max(x - half, 0), min(x + half + 1, w)
        if ya >= yb or xa >= xb:
            continue
        change = cv2.absdiff(first[ya:yb, xa:xb], current[ya:yb, xa:xb])
        out[i] = float(np.mean(change < tolerance))
    return out


def _judge_background(greys: list[ImageArray], k: int, origin: tuple[int, int], live: _LiveTracks,
                      still: NDArray[np.int64], tolerances: dict[tuple[int, int], float],
                      config: TrackerConfig) -> NDArray[np.bool_]:
    """(n,) bool: the live tracks that ``TrackerConfig.max_static_fraction`` drops in frame ``k``.

    Judges once each track that has now moved ``static_check_px`` from its first point (marking it judged):
    its detection window, in place, in its first frame against frame ``k``. ``origin`` (x0, y0): the crop's
    corner in the frame; ``tolerances`` caches ``static_tolerance`` per (first frame, k).
    """
    drop = np.zeros(len(live), dtype=bool)
    due = ~live.judged & (np.linalg.norm(live.pts - live.origin, axis=1) >= config.static_check_px)
    if not np.any(due):
        return drop
    live.judged = live.judged | due
    offset = np.asarray(origin, dtype=np.float64)
    for born in np.unique(live.born[due]):
        rows = np.flatnonzero(due & (live.born == born))
        pair = (int(born), k)
        if pair not in tolerances:
            tolerances[pair] = static_tolerance(greys[pair[0]], greys[k], still)
        fraction = static_fraction(greys[pair[0]], greys[k], live.origin[rows] + offset, config.win_size_px // 2,
                                   tolerances[pair])
        drop[rows] = fraction > config.max_static_fraction
    return drop


def track_keypoints(frames: Sequence[ImageArray], delta: FloatArray,
                    config: TrackerConfig | None = None) -> TrackingResult:
    """Track corners on the moving links through one sweep.

    Shi–Tomasi corners are detected in the first frame inside ``moving_mask`` and followed frame to
    frame with pyramidal Lucas–Kanade. Each step is checked forward and backward: a point whose round
    trip misses by more than ``config.fb_max_px`` (or that LK loses, or that leaves the image) ends its
    track there. The survivors' positions are then refined by fitting their first-frame patch with an
    affine map, and a track whose fit residual is too large ends too. An ended track keeps its prefix
    if it is long enough. Every ``config.redetect_every`` frames new corners are added in moving regions
    not covered by live tracks. Tracks shorter than ``config.min_track_frames`` or that never move more
    than ``config.min_displacement_px`` are dropped.

    Args:
        frames: F >= 2 images of one sweep, each (H, W) uint8 grey or (H, W, 3) uint8 RGB.
        delta: (F,) float64, radians: the joint's offset from its start value in each frame.
        config: tracker settings; ``TrackerConfig()`` if None.

    Returns:
        The kept tracks (pixels (M, 2) float64, delta (M,) float64 rad, frames in order, with gaps where
        a lost track was found again) and counts of what was dropped and why. A sweep where nothing moves
        gives no tracks, not an error.

    Raises:
        InvalidInputError: fewer than 2 frames, frames of different shapes, empty or non-uint8 images,
            a delta that is not (F,) or not finite.
    """
    config = TrackerConfig() if config is None else config
    with limited_blas(config.blas_threads):
        return _track_keypoints(frames, delta, config)


def _track_keypoints(frames: Sequence[ImageArray], delta: FloatArray, config: TrackerConfig) -> TrackingResult:
    start_time = time.perf_counter()
    greys = _grey_frames(frames)
    n_frames = len(greys)
    delta = np.asarray(delta, dtype=np.float64)
    if delta.ndim != 1 or delta.shape[0] != n_frames:
        raise InvalidInputError(f"delta must be ({n_frames},) like the {n_frames} frames, got shape {delta.shape}")
    if not np.all(np.isfinite(delta)):
        raise InvalidInputError("delta contains NaN or infinite values")

    mask_full = _moving_mask_u8(greys, config)
    roi = _roi(mask_full, config)
    if roi is None:
        return TrackingResult([], 0, 0, 0, 0, 0, 0, time.perf_counter() - start_time, 0)
    x0, y0, x1, y1 = roi
    mask = np.ascontiguousarray(mask_full[y0:y1, x0:x1])
    still = _still_sample(mask_full) if config.max_static_fraction < 1.0 else np.empty(0, np.int64)
    tolerances: dict[tuple[int, int], float] = {}
    width, height = x1 - x0, y1 - y0

    # Per frame: the ids and positions of the tracks alive in it. Per track: why it ended.
    record_ids: list[NDArray[np.int64]] = []
    record_pts: list[FloatArray] = []
    ended: list[int] = []

    prev = greys[0][y0:y1, x0:x1]
    live = _new_tracks(prev, _detect(prev, mask, np.empty((0, 2), np.float32), config.max_corners, config),
                       0, 0, config)
    ended.extend([_RUNNING] * len(live))
    record_ids.append(live.ids)
    record_pts.append(live.pts.astype(np.float64))
    lost = live.select(np.zeros(len(live), dtype=bool))  # tracks a check ended, still being looked for
    lost_at = np.empty(0, dtype=np.int64)  # the frame each lost track was lost in
    for k in range(1, n_frames):
        nxt = greys[k][y0:y1, x0:x1]
        positions = np.empty((0, 2))
        dropped = live.select(np.zeros(len(live), dtype=bool))
        moved_from, moved_to = np.empty((0, 2)), np.empty((0, 2))
        if len(live):
            before = live.pts.astype(np.float64)
            forward, ok = _lk_predicted(prev, nxt, live, config)
            for track_id in live.ids[~ok]:
                ended[track_id] = _ENDED_FB
            dropped, live, forward, before = live.select(~ok), live.select(ok), forward[ok], before[ok]
            positions = forward.astype(np.float64)
            if config.affine_iterations and len(live):
                positions, dissimilarity, ok = _refine_affine(nxt, live, forward, config)
                ok &= dissimilarity <= config.max_dissimilarity
                for track_id in live.ids[~ok]:
                    ended[track_id] = _ENDED_DISSIMILAR
                live, positions, before = live.select(ok), positions[ok], before[ok]
            inside = (np.all(positions >= 0, axis=1) & (positions[:, 0] <= width - 1)
                      & (positions[:, 1] <= height - 1))
            for track_id in live.ids[~inside]:
                ended[track_id] = _ENDED_FB
            live, positions = live.select(inside), positions[inside]
            moved_from, moved_to = before[inside], positions
            live.pts = positions.astype(np.float32)
            live.step = (positions - moved_from).astype(np.float32)
            if config.max_static_fraction < 1.0 and len(live):
                background = _judge_background(greys, k, (x0, y0), live, still, tolerances, config)
                for track_id in live.ids[background]:
                    ended[track_id] = _ENDED_BACKGROUND
                keep = ~background
                live, positions = live.select(keep), positions[keep]
                moved_from, moved_to = moved_from[keep], moved_to[keep]
        if config.refind_frames and config.affine_iterations:
            lost, lost_at = lost.extend(dropped), np.concatenate([lost_at, np.full(len(dropped), k)])
            keep = k - lost_at < config.refind_frames
            lost, lost_at = lost.select(keep), lost_at[keep]
            if len(lost):
                found, found_at, lost, lost_at = _refind(nxt, lost, lost_at, moved_from, moved_to, config)
                for track_id in found.ids:
                    ended[track_id] = _RUNNING
                found.step = np.full((len(found), 2), np.nan, np.float32)
                live = live.extend(found)
                positions = np.concatenate([positions, found.pts.astype(np.float64)])
        if config.redetect_every and k % config.redetect_every == 0 and n_frames - k >= config.min_track_frames:
            taken = np.concatenate([live.pts, lost.pts]) if len(lost) else live.pts
            corners = _detect(nxt, mask, taken, config.max_corners - len(live), config)
            new = _new_tracks(nxt, corners, len(ended), k, config)
            ended.extend([_RUNNING] * len(new))
            live = live.extend(new)
            positions = np.concatenate([positions, corners.astype(np.float64)])
        record_ids.append(live.ids)
        record_pts.append(positions)
        prev = nxt
    return _assemble(record_ids, record_pts, ended, delta, (x0, y0), config, start_time)


def _assemble(record_ids: list[NDArray[np.int64]], record_pts: list[FloatArray], ended: list[int],
              delta: FloatArray, origin: tuple[int, int], config: TrackerConfig,
              start_time: float) -> TrackingResult:
    """Regroup the per-frame records into tracks, drop the short and static ones, and count."""
    counts = {"fb": 0, "dissimilar": 0, "short": 0, "static": 0, "truncated": 0, "background": 0}
    tracks: list[KeypointTrack] = []
    if ended:
        all_ids = np.concatenate(record_ids)
        all_frames = np.concatenate([np.full(ids.shape[0], k) for k, ids in enumerate(record_ids)])
        all_pts = np.concatenate(record_pts) + np.asarray(origin, dtype=np.float64)
        order = np.argsort(all_ids, kind="stable")  # records are in frame order, so each track stays sorted
        for rows in np.split(order, np.flatnonzero(np.diff(all_ids[order])) + 1):
            reason = ended[int(all_ids[rows[0]])]
            pixels = all_pts[rows]
            if reason == _ENDED_BACKGROUND:
                counts["background"] += 1
            elif rows.shape[0] < config.min_track_frames:
                counts[{_RUNNING: "short", _ENDED_FB: "fb", _ENDED_DISSIMILAR: "dissimilar"}[reason]] += 1
            elif np.max(np.linalg.norm(pixels - pixels[0], axis=1)) <= config.min_displacement_px:
                counts["static"] += 1
            else:
                counts["truncated"] += reason != _RUNNING
                tracks.append(KeypointTrack(pixels, delta[all_frames[rows]]))
    return TrackingResult(tracks, len(ended), counts["fb"], counts["dissimilar"], counts["short"], counts["static"],
                          counts["truncated"], time.perf_counter() - start_time, counts["background"])
