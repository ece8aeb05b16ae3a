"""The calibrator: motions in, T_camera_base out, updated after every motion (paper Algorithm 1).

For each new motion: stage-one pruning and its axis and reference plane (``solver.motion``); then
an update: the robust linear calibration over the motions that passed stage one, pruning those
inconsistent with it (§V-C-2, ``solver.calibration``); the bundle adjustment over every motion whose
tracks moved, starting from the previous refined pose or the linear one (``solver.refinement``);
the convergence monitor over the refined estimates (§V-D), each entering its window only after a motion
that informs it (``ConvergenceConfig.min_leverage``). A motion that stage one found ambiguous
still informs the bundle adjustment: the rigid-rotation model with a known pose has no ambiguity.
Before the first refined pose, when there is no linear one to start from (fewer than three axes, no
consensus) or the adjustment cannot run from it, it starts from the poses that two or more axes allow
(``pose_family``: the rotation and the translation up to a ray from the camera), sampled along that ray
and screened by short robust passes (ours: ``CalibratorConfig.family_start``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray, evenly_spaced
from solver.calibration import (
    MIN_OBSERVABILITY,
    AxisCorrespondence,
    ConsensusResult,
    family_offsets,
    pose_family,
    solve_consensus,
)
from solver.camera import normalized_from_pixels
from solver.convergence import ConvergenceConfig, ConvergenceMonitor
from solver.errors import (
    ArcCalibError,
    DegenerateMotionError,
    InsufficientMotionsError,
    InvalidInputError,
    NonRigidTracksError,
    OutlineDisagreementError,
    OutlineMismatchError,
    OutlineReachError,
    UnobservablePoseError,
)
from solver.frames import pose_difference, transform_from_rt
from solver.kinematics import AxisFunction
from solver.mask_start import ChangeMask, MaskStartConfig, MaskView, MovingSurface, mask_starts
from solver.motion import MotionConfig, MotionGeometry, estimate_motion_geometry, track_moved
from solver.observations import CameraIntrinsics, KeypointTrack, MotionObservation
from solver.one_axis import OneAxisSearch, search_one_axis
from solver.outline_fusion import (
    ContourRenderer,
    OutlineAdjustment,
    OutlineFusion,
    OutlineFusionConfig,
    OutlineImage,
    consistent_prior_scale,
)
from solver.refinement import (
    RefinementConfig,
    RefinementResult,
    TrackSet,
    build_track_set,
    conservative_covariance,
    newest_motion_leverage,
    refine,
    refine_increment,
    reprojection_residuals,
    screen_start,
    track_observability,
)
from solver.rigid_axis import RigidAxisConfig, RigidAxisFit, geometry_from_rigid_fit, rigid_axis_of_motion
from solver.threads import check_blas_threads, limited_blas

Stage = Literal["none", "linear", "refined"]
Start = Literal["", "previous", "linear", "family", "outlines"]


@dataclass(frozen=True)
class CalibratorConfig:
    """Settings of the whole calibration.

    Attributes:
        motion: per-motion estimation and stage-one pruning (the paper's conic front end).
        rigid_axis: the rigid front end (``solver.rigid_axis``): each motion's axis from the rigid
            motion of all its tracks by the known angles, and the tracks that do not move rigidly
            (sliding on silhouettes, highlights, drift) dropped before the bundle adjustment. Its
            axis is used when it has one, else the conics'; None: the paper's conic front end only.
        rigid_always: run the rigid front end on every motion (the default); False: only on the
            motions to which the conics give no axis. Measured with ``calibrate_recording`` on
            rendered 12-motion 1080p Panda recordings (conics only / rigid where the conics fail /
            rigid on every motion): realistic real0 3.67e-3 rad / 2.50 mm, 3.72e-3 / 2.62 mm,
            7.96e-4 / 0.89 mm; as-shipped ship1 3.24e-3 / 2.83, 3.30e-3 / 3.09, 8.78e-4 / 3.50 mm;
            realistic real2 no pose in all three; clean painted paint0 1.90e-4 / 0.11 mm (conics
            only) against 4.84e-4 / 0.32 mm (every motion): it wins on realistic images, where most
            tracks slide, and costs some accuracy on painted ones, where nearly all are rigid.
        conics_always: run the paper's conic front end on every motion, also where the rigid front end does
            not need it (its fit from the predicted axis was taken: ``CONICS_NOT_RUN``), for its report
            (``MotionReport.conics``; the benchmarks count the motions each front end gives an axis). The
            estimate is the same either way; it costs about 0.8 s CPU per 25-motion realistic episode, summed in
            ``Calibrator.report_seconds``.
        predicted_start: once there is a refined pose, the rigid front end first tries the motion's axis and
            reference ray that the pose predicts (R @ axis_base, R @ point_base + t) as its start, and skips its
            searches when the tracks' own fit from there stays near it (``fit_rigid_axis``'s ``predicted``,
            ``RigidAxisConfig.predicted_angle``); a wrong prediction falls back to the searches.
        refinement: bundle adjustment.
        convergence: the sliding-window monitor.
        refine: run the bundle adjustment (off: the paper's linear method only).
        max_eps_a: rad; stage-two pruning threshold on the axis error (Eq. 23).
        max_eps_d: m; stage-two pruning threshold on the plane distance (Eq. 24).
        fit_eps_a: rad; the linear pose is refitted on the motions within this axis error and
            ``fit_eps_d`` (``solve_consensus``'s ``fit_eps``); None fits all unpruned motions.
            On scripts/bench_solver.py's synthetic episodes the linear stage at 25 motions goes
            from 5.6 mrad / 5.7 mm (all unpruned) to 3.9 mrad / 4.3 mm (20 episodes).
        fit_eps_d: m; see ``fit_eps_a``.
        max_tracks_per_motion: tracks beyond this are subsampled for the bundle adjustment; None (the
            default): every track (full information: the incremental update keeps it affordable).
        max_frames_per_track: frames beyond this are subsampled evenly for the bundle adjustment; None
            (the default): every frame.
        max_std_rotation: rad; a refined pose whose 1-sigma rotation uncertainty exceeds this is
            not reported (the motions do not fix it); also required for convergence below the
            monitor's thresholds.
        max_std_translation: m; the same for translation.
        seed: seed of every random choice (RANSAC, subsampling).
        family_start: with the refinement on and no refined pose yet, when there is no linear pose
            (fewer than three motions with an axis, or no consensus) or the bundle adjustment could
            not run from it, start it from the poses that the motions' axes allow (``pose_family``:
            two non-parallel axes fix the rotation and the translation up to a ray from the camera,
            along which the tracks of every motion, with an axis or not, can fix it). Not when the
            adjustment ran from the linear pose and its covariance was too wide: no start changes that.
            A chain begun this way is adjusted again beside an adjustment from the linear pose at every
            update once there is one, and the better fit goes on (``_rival_linear``). On by default:
            realistic 1080p Panda episodes (benchmark poses 0-2, seed 0, 25 random motions) gave the same
            results with it on poses 0 and 1, and on pose 2 (camera 2.5 m away) the first pose at motion
            4 instead of 6 and a usable result (8.6e-4 rad / 1.44 mm, 1-sigma 1.5 mm) instead of an
            unusable one (3.1e-4 rad / 3.11 mm, 1-sigma 3.04 mm); eight cached 12-motion 1080p recordings
            and a clean painted 960x540 episode (pose 0, seed 0) were unchanged. That episode was the reason
            it was off (at an earlier commit, without the comparison, it ended unusable with it only).
        family_distances: m; the family is sampled where the motions' joints lie between these
            distances from the camera (log-spaced)...
        family_samples: ... at this many distances (each can give two members, both in front).
        rescue_wide: when the tracks' adjustment gives a pose too uncertain for the outlines to pair with
            (``OutlineReachError``), search its weakest direction with the outlines as the rescue does when the tracks
            give no pose, and take the result when the rescue's own tests pass (``Calibrator._rescue_wide``).
        refuse_refuted: a first pose (no refined pose before it) that the outlines disagree with
            (``OutlineDisagreementError``), or whose wide rescue found them fitting their edges too loosely all along
            the tracks' weakest direction or disagreeing with the tracks' pose there (``OutlineReachError.refuted``),
            is refused as a first pose they cannot fit near is: neither reported nor chained from (measured on the
            as-shipped five-motion captures: every such pose 18-296 mm off, one at a chi-square of 2 750 under its
            covariance; ``docs/realistic-imaging.md``, "Stop 66").
        incremental: once there is a refined pose, an update that adds one motion solves only its tracks'
            points and the pose, the earlier motions entering through their marginalized information
            (``solver.refinement.refine_increment``); every motion is solved again (relinearized) when
            the pose has moved from where a motion was last linearized by more than ``relinearize_sigma``
            of the 1-sigma it had there (Mahalanobis), every ``relinearize_every`` motions, and whenever the
            increment fails. False: every update solves every motion (``refine``). On synthetic 25-motion
            episodes (200 tracks per motion) increments alone from motion 3 to 25, never relinearized, stayed
            within 0.01 sigma of the batch estimate and 1 % of its 1-sigma: the summaries' linearization is
            far from limiting, and the pose moving by several of its new 1-sigma when an informative motion
            arrives is no reason to relinearize.
        relinearize_sigma: see ``incremental``.
        relinearize_every: see ``incremental``.
        outlines: the outline stage (``solver.outline_fusion``), when the calibrator is given a contour renderer
            and motions bring outline images: every update with a refined pose combines it with the robot's
            outlines in those images (from where the last update's combination ended), and the state reports the
            combined pose and covariance (``CalibrationState.outline``); the tracks' own chain of estimates, which
            the next update starts from, is not changed by it.
        hold_outlines: when the outlines, fused (or rescued) at the last update, now disagree with the tracks' pose
            (``OutlineDisagreementError``), adjust them again with the tracks' covariance scaled by the least factor
            that makes the two consistent (``Calibrator._hold_outlines``) and report that pose when it is the last
            update's (at most ``HOLD_MAX_UPDATES`` updates in a row, not counting holds whose factor is at most
            ``HOLD_FREE_SCALE``); such an update never declares convergence.
            False: the tracks' pose alone, as before.
        one_axis: when the tracks give no pose, no rescued pose holds, the outlines' rescue from the linear pose
            or the pose family fails or has none to start from, and so does ``mask_start``, but a motion has an axis
            (or a weak one: ``OneAxisSearch.weak_share``), the family of poses that axis allows is searched with every
            motion's tracks and then the outlines (``solver.one_axis``), and the outlines are adjusted from the best
            member; the result is taken on the rescue's own tests (``Calibrator._one_axis_rescue``). None: off.
        mask_start: when the tracks give no pose, no rescued pose holds, the outlines' rescue from the linear pose
            or the pose family fails or has none to start from, and three motions' outline images carry
            change masks (``OutlineImage.changed``) and the contour renderer is also a ``MovingSurface``: poses that
            draw the moving links where the motions changed the image (``solver.mask_start``), and the outlines
            adjusted alone from each; the result is taken on the rescue's own tests (``Calibrator._mask_rescue``).
            None: off.
        blas_threads: BLAS threads while the calibrator works (``add_motion``, ``update``, ``focal_check``,
            ``batch_refinement``), restored after; None: leave BLAS as it is (``solver.threads``, where the
            measurement is).
    """

    motion: MotionConfig = field(default_factory=MotionConfig)
    rigid_axis: RigidAxisConfig | None = field(default_factory=RigidAxisConfig)
    rigid_always: bool = True
    conics_always: bool = False
    predicted_start: bool = True
    refinement: RefinementConfig = field(default_factory=RefinementConfig)
    convergence: ConvergenceConfig = field(default_factory=ConvergenceConfig)
    refine: bool = True
    max_eps_a: float = 0.1
    max_eps_d: float = 0.05
    fit_eps_a: float | None = 0.02
    fit_eps_d: float = 0.005
    max_tracks_per_motion: int | None = None
    max_frames_per_track: int | None = None
    max_std_rotation: float = 0.05
    max_std_translation: float = 0.05
    seed: int = 0
    family_start: bool = True
    family_distances: tuple[float, float] = (0.3, 5.0)
    family_samples: int = 12
    rescue_wide: bool = True
    refuse_refuted: bool = True
    incremental: bool = True
    relinearize_sigma: float = 2.0
    relinearize_every: int = 20
    outlines: OutlineFusionConfig = field(default_factory=OutlineFusionConfig)
    hold_outlines: bool = True
    one_axis: OneAxisSearch | None = field(default_factory=OneAxisSearch)
    mask_start: MaskStartConfig | None = field(default_factory=MaskStartConfig)
    blas_threads: int | None = 1

    def __post_init__(self) -> None:
        lo, hi = self.family_distances
        if not 0 < lo < hi or self.family_samples < 2:
            raise InvalidInputError(f"need 0 < family_distances[0] < family_distances[1] and family_samples >= 2, "
                                    f"got {self.family_distances}, {self.family_samples}")
        check_blas_threads(self.blas_threads, "blas_threads")


@dataclass
class MotionReport:
    """What became of one motion (updated at every calibration update).

    Attributes:
        index: position in the order motions were added.
        joint: the joint that turned (0-based).
        n_tracks: tracks received.
        accepted: True when the motion informs the current estimate.
        reason: why it is rejected ("" when accepted).
        linear: True when the linear stage used it.
        eps_a: rad, the axis error against the current estimate (None without axis or estimate).
        eps_d: m, the plane distance against the current estimate (None likewise).
        stage_one: "" or why stage one (no estimate needed) rejected its axis.
        n_inlier_tracks: tracks the bundle adjustment kept.
        front_end: which front end gave the axis: "rigid", "conics" or "" (none).
        conics: "" or why the conic front end gave no axis (``CONICS_NOT_RUN`` when it was not needed).
        rigid: "" or why the rigid front end gave no axis (also "" when it did not run: off, or the
            conics gave an axis and ``CalibratorConfig.rigid_always`` is False).
        n_inconsistent_tracks: tracks the rigid front end dropped (they do not move rigidly with the
            others by the known angles).
        rigid_predicted: the rigid front end's fit came from the start the refined pose predicted, with no
            search (``CalibratorConfig.predicted_start``).
        leverage: the largest share (0..1) of the refined pose's information it brought in any direction when
            it was added (``solver.refinement.newest_motion_leverage``); None when it did not inform a refined
            estimate then or the backend gave no motion summaries. Below ``ConvergenceConfig.min_leverage`` the
            estimate after it does not enter the convergence window.
    """

    index: int
    joint: int
    n_tracks: int
    accepted: bool = False
    reason: str = ""
    linear: bool = False
    eps_a: float | None = None
    eps_d: float | None = None
    stage_one: str = ""
    n_inlier_tracks: int = 0
    front_end: str = ""
    conics: str = ""
    rigid: str = ""
    n_inconsistent_tracks: int = 0
    rigid_predicted: bool = False
    leverage: float | None = None


@dataclass(frozen=True)
class CalibrationState:
    """The calibration after an update.

    Attributes:
        T_camera_base: (4, 4) float64 or None: the best estimate: refined; linear only with the
            refinement off (with it on, a linear pose that the refinement fails on is withheld).
        stage: which stage produced it.
        T_linear: (4, 4) or None: the linear estimate.
        covariance: (6, 6) or None: covariance of (omega rad, tau m) from the refinement.
        std: (6,) or None: square roots of its diagonal.
        gamma: (6,) or None: the monitor's range over the last h estimates that entered its window.
        converged: the monitor fired and the uncertainty is within the thresholds.
        n_accepted: motions informing the estimate.
        n_rejected: motions not informing it.
        rms_px: RMS reprojection error of the refinement, px.
        message: why there is no estimate, or "".
        seconds: wall time of this update's stages, {"linear": s, "refined": s}.
        start: where the bundle adjustment that gave the refined pose started: "previous" (the last
            refined pose), "linear", "family" (a member of the motions' pose family:
            ``CalibratorConfig.family_start``), "outlines" (the tracks leave a direction free, e.g. the
            depth of the Panda's joints 1-3 alone, and the robot's outlines fixed it: ``outline`` holds the
            adjustment; such a pose never declares convergence), or "" (no refined pose).
        time_offset_s: s, the time offset the bundle adjustment estimated between the joint and camera
            clocks, on top of the one the joint values were read with (``solver.refinement``); None when
            not estimated (``RefinementConfig.estimate_time_offset``) or no refined pose.
        time_offset_std_s: s, its 1-sigma (the covariance's, like ``std``); None likewise.
        outline: the joint adjustment with the robot's outlines that gave ``T_camera_base`` and ``covariance``
            (``solver.outline_fusion``); None when the estimate is the tracks' alone (``outline_note`` says why).
        outline_note: why the outlines were not used, or "" (also "" when there are none: no renderer or images).
    """

    T_camera_base: FloatArray | None
    stage: Stage
    T_linear: FloatArray | None
    covariance: FloatArray | None
    std: FloatArray | None
    gamma: FloatArray | None
    converged: bool
    n_accepted: int
    n_rejected: int
    rms_px: float | None
    message: str
    seconds: dict[str, float] = field(default_factory=dict)
    start: Start = ""
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    outline: OutlineFusion | None = None
    outline_note: str = ""


@dataclass
class _Motion:
    obs: MotionObservation
    axis_base: FloatArray
    point_base: FloatArray
    geometry: MotionGeometry | None
    # (uv normalized, delta rad, joint velocity rad/s or None) subsampled, moving only
    tracks: list[tuple[FloatArray, FloatArray, FloatArray | None]]
    points: FloatArray | None = None  # (len(tracks), 3) last refined points, NaN where unknown
    weak: MotionGeometry | None = None  # a rigid fit too few tracks follow: for the one-axis search alone

    @property
    def search_axis(self) -> MotionGeometry | None:
        """The axis the one-axis search starts from: the motion's, else its weak one (None: neither)."""
        return self.geometry if self.geometry is not None else self.weak


#: ``MotionReport.conics`` of a motion whose conics did not run: with ``CalibratorConfig.rigid_always`` they
#: serve as the rigid front end's start and fallback, and its fit from the refined pose's prediction needs neither.
CONICS_NOT_RUN = "not run: the rigid front end's fit from the predicted axis was taken"
#: ``MotionReport.conics`` when the conics gave an axis that the rigid front end, started from it, found the tracks
#: do not follow (``NonRigidTracksError``): not used. On captured realistic episodes (ten of 25 motions and eight of
#: 8) the conics' axes where the rigid fit failed so were 7, 80 and 104 degrees off (where it failed for other
#: reasons: 4 and 41), and on a 720p iiwa episode the 104-degree axis seeded a pose family that the adjustment
#: turned into a pose 2.5 rad / 1.1 m off with a 1-sigma of 17 mm.
CONICS_NOT_RIGID = "its axis is not used: the rigid front end found the tracks do not turn rigidly about it"


#: Focal-length scales at which ``Calibrator.focal_check`` repeats the bundle adjustment.
FOCAL_SCAN_SCALES = (0.96, 0.98, 1.0, 1.02, 1.04)
#: The focal lengths are flagged when the tracks fit best at a scale this far from 1 ...
FOCAL_SCALE_TOLERANCE = 0.01
#: ... and the RMS residual there is lower than with the given ones by at least this fraction. Measured on
#: a 12-motion 1280x720 recording: the true focal length fits best at 0.997 (RMS 0.167 px either way);
#: fx and fy 2 % low / high fit best at 1.017 / 0.972 (RMS 1.2 % / 4 % lower), 5 % low / high at 1.040 /
#: 0.960 (RMS 19 % / 20 % lower) -- while the poses were 15-39 mm off with 1-sigma of about 1 mm (each scale
#: judged on its own kept tracks then). With one common track set, on the 9-motion 960x540 round-trip recording:
#: the true focal lengths fit best at 0.998, 2 % low / high at 1.015 / 0.981, 5 % low / high at 1.045 / 0.948.
FOCAL_RMS_GAIN = 0.005


#: Short robust pass per member of the pose family (``Calibrator._family_start``): evaluations at most ...
FAMILY_SCREEN_NFEV = 10
#: ... over at most this many tracks per motion ...
FAMILY_SCREEN_TRACKS = 12
#: ... of at most this many frames each ...
FAMILY_SCREEN_FRAMES = 10
#: ... scored by residuals truncated at this many px (a track behind the camera costs it on every frame).
FAMILY_CAP_PX = 3.0
#: Other local minima along the family scoring within this fraction of the best are adjusted in full too ...
FAMILY_RIVAL_RATIO = 0.25
#: ... at most this many of them.
FAMILY_MAX_RIVALS = 2
#: Two adjusted members are the same pose when xi^T (C_1 + C_2)^-1 xi is below this (chi^2_6, 0.999) ...
FAMILY_SAME_CHI2 = 22.46
#: ... else the better-fitting one is kept only when the other's score is this fraction higher.
FAMILY_MARGIN = 0.1
#: The family chain and the linear start's adjustment reached the same minimum when their poses differ by less than
#: this many of the chain's 1-sigma (Mahalanobis): the chain is kept and counts as confirmed (``_rival_linear``).
#: Comparing their fits there compares round-off (seen: 1.1e-8 sigma apart, the winner flipping when unrelated code
#: changed its arithmetic, and the later updates 0.46 sigma apart for a few motions).
RIVAL_SAME_SIGMA = 0.01
#: ``Calibrator._hold_outlines``: the tracks' covariance is scaled at most this much (their 1-sigma 10x) ...
HOLD_MAX_SCALE = 100.0
#: ... by the least factor that brings the outlines' disagreement with them to this (chi^2_6, 0.95); for at most
#: this many updates in a row (outlines that had settled on a wrong pose with the tracks must not hold it for good).
HOLD_TARGET_CHI2 = 12.59
HOLD_MAX_UPDATES = 3
#: A hold whose scale is at most this (the tracks' 1-sigma at most doubled) does not count towards
#: ``HOLD_MAX_UPDATES``: the tracks' covariance from slipping tracks on castings is that much too narrow routinely, and
#: outlines held against tracks that leave them for a better pose need ever larger scales as the tracks firm up (seen:
#: an as-shipped 720p xArm 6 held 1.0-1.1 mm off at motions 19-21 with a scale of 1.9-2.0, then the tracks' pose
#: alone 26-33 mm off at 22-25, chi-square 23-26, its 1-sigma 16-24 mm).
HOLD_FREE_SCALE = 4.0
#: ``Calibrator._outlines_alone``: the prior on its start, 1-sigma (rad, m): as wide as the one-axis search's first
#: outline round (``solver.one_axis``), so the outlines alone place the pose.
OUTLINES_ALONE_PRIOR_STD = (0.05, 0.05)
#: A pose from one motion's axis (``_one_axis_rescue``) must draw the robot at least this large against its tracks: the
#: 5-95 % box of its contour points' normalized coordinates, as a share of the tracks' (``_spread``). Measured: 0.91
#: and 1.07 at rescued as-shipped iiwa 1080p poses (poses 1 and 5, 0.1 mm off); 0.16 at a 720p pose 9 rescued 5.4 m
#: off, the robot drawn small on a few edges with a residual scale under 1 px.
MIN_OUTLINE_SPREAD = 0.5
#: A pose from the change masks (``Calibrator._mask_rescue``) must have at least this share of the robot's contour
#: points seen in the images within this many px of an edge (``OutlineAdjustment.paired_share``): the residual scale
#: is judged on the pairs alone, and a pose far off can fit a few edges closely. Measured on the first three to five
#: motions of 40 as-shipped 720p captures (30 iiwa, 5 xArm 6, 5 Panda): 0.64-0.75 at the true pose, 0.10-0.36 at 20 mrad
#: and 20 mm from it; a test's spheres fused 0.36 rad off from masks seen by another camera at a residual scale of
#: 0.64 px had 0.11.
MASK_MIN_PAIRED = 0.5
MASK_PAIR_PX = 3.0
#: Poses along the tracks' free direction that ``Calibrator._outline_rescue`` first scores with the outlines: where
#: the motions' joints lie this many log-spaced distances from the camera within ``family_distances`` (0.3-5 m: 7 %
#: apart; ``OutlineAdjustment.search_along`` then searches between the best one's neighbours).
OUTLINE_SEARCH_SAMPLES = 40


def _geometric_std(refined: RefinementResult) -> FloatArray:
    """(6,) the refined pose's 1-sigmas (rad, m) before the motion jackknife; NaN where a variance is negative."""
    covariance = refined.covariance if refined.sandwich_covariance is None else refined.sandwich_covariance
    with np.errstate(invalid="ignore"):
        return np.sqrt(np.diag(covariance))


def _pose_chi2(a: RefinementResult, b: RefinementResult, covariance: FloatArray) -> float:
    """``_transform_chi2`` of two refinements' poses."""
    return _transform_chi2(a.T_camera_base, b.T_camera_base, covariance)


def _transform_chi2(T_a: FloatArray, T_b: FloatArray, covariance: FloatArray) -> float:
    """xi^T C^-1 xi (inf if C is singular) of xi (6,) = pose_difference(T_a, T_b) (4, 4) in ``covariance`` C (6, 6)."""
    xi = pose_difference(T_a, T_b)
    try:
        d2 = float(xi @ np.linalg.solve(covariance, xi))
    except np.linalg.LinAlgError:
        return np.inf
    return d2 if np.isfinite(d2) else np.inf


def _fit_score(tracks: TrackSet, refined: RefinementResult, cap_px: float) -> float:
    """How well a refinement fits all of ``tracks``, px^2 (comparable between refinements of the same tracks).

    The mean squared residual per coordinate, every observation of a track it dropped counted as cap_px^2.
    """
    kept = refined.track_inliers[tracks.track]
    return float((refined.rms_px**2 * kept.sum() + cap_px**2 * (~kept).sum()) / kept.size)


@dataclass(frozen=True)
class FocalCheck:
    """Whether the camera's focal lengths fit the tracks (``Calibrator.focal_check``).

    Attributes:
        scales: (S,) the focal-length scales tried.
        rms_px: (S,) RMS residual of the bundle adjustment at each, over the tracks that every scale's adjustment
            kept (NaN where it failed).
        best_scale: the scale that fits best (vertex of a parabola through the scan, else the best sample).
        rms_given_px: RMS with the given focal lengths (scale 1).
        rms_best_px: RMS at the best sample.
        fits: False when the best scale is more than ``FOCAL_SCALE_TOLERANCE`` from 1 and fits better by
            ``FOCAL_RMS_GAIN`` or more.
    """

    scales: FloatArray
    rms_px: FloatArray
    best_scale: float
    rms_given_px: float
    rms_best_px: float
    fits: bool

    @classmethod
    def from_scan(cls, scales: FloatArray, rms: FloatArray) -> FocalCheck:
        """Judge a scan: scales (S,) containing 1.0 and their RMS (S,) px."""
        ok = np.isfinite(rms)
        given = float(rms[np.argmin(np.abs(scales - 1.0))])
        if ok.sum() < 3 or not np.isfinite(given):
            return cls(scales, rms, 1.0, given, given, True)
        a, b, _ = np.polyfit(scales[ok], rms[ok] ** 2, 2)
        best_sample = int(np.nanargmin(rms))
        best = -b / (2 * a) if a > 0 else float(scales[best_sample])
        best = float(np.clip(best, 0.8, 1.25))
        rms_best = float(rms[best_sample])
        fits = not (abs(best - 1.0) > FOCAL_SCALE_TOLERANCE and rms_best < (1 - FOCAL_RMS_GAIN) * given)
        return cls(scales, rms, best, given, rms_best, fits)

    @property
    def message(self) -> str:
        """"" when the focal lengths fit, else what the tracks say."""
        if self.fits:
            return ""
        return (f"the camera's focal lengths do not fit the tracks: they fit best scaled by {self.best_scale:.3f} "
                f"(RMS {self.rms_best_px:.3f} px against {self.rms_given_px:.3f} px with the given ones); "
                "check the intrinsics (fx, fy)")


class Calibrator:
    """Incremental ARC-Calib: ``add_motion`` after each exploratory motion, read ``state``.

    Args:
        intrinsics: the camera.
        kinematics: Gamma(q, joint) -> (axis_base, point_base), e.g. ``DHChain.axis_and_point``.
        config: settings; defaults to ``CalibratorConfig()``.
        contours: the robot's occluding contour at a configuration from a camera pose (``ContourRenderer``, e.g.
            ``arc_env.robot.contours.RobotContours``), for the outline stage (``CalibratorConfig.outlines``);
            None: the tracks alone. One that is also a ``solver.mask_start.MovingSurface`` (``RobotContours`` is)
            serves the mask rescue (``CalibratorConfig.mask_start``).
    """

    def __init__(self, intrinsics: CameraIntrinsics, kinematics: AxisFunction,
                 config: CalibratorConfig | None = None, contours: ContourRenderer | None = None):
        self.intrinsics = intrinsics
        self.kinematics = kinematics
        self.config = config or CalibratorConfig()
        self.outlines = (OutlineAdjustment(contours, intrinsics, self.config.outlines)
                         if contours is not None else None)
        self.reports: list[MotionReport] = []
        self._motions: list[_Motion | None] = []
        self._rng = np.random.default_rng(self.config.seed)
        self._monitor = ConvergenceMonitor(self.config.convergence)
        self._window_motions = 0  # motions taken when an estimate last entered the monitor's window
        self._refined: RefinementResult | None = None
        self._refined_live: list[int] = []  # the motions behind _refined, in its summaries' order (if it has them)
        self._inlier_counts: dict[int, int] = {}  # tracks the bundle adjustment kept, per motion
        self._lin_information: dict[int, FloatArray] = {}  # per motion: inverse pose covariance where linearized
        self._since_batch = 0  # increments since every motion was last solved
        self._from_family = False  # the refined pose descends from a family start no linear start has beaten
        self._held_updates = 0  # updates in a row whose outlines held the pose against the tracks' (_hold_outlines)
        self._one_axis_tries: dict[int, int] = {}  # per motion, one-axis searches from its axis (_one_axis_rescue)
        self._surface = contours if isinstance(contours, MovingSurface) else None  # for _mask_rescue
        self._changes: dict[int, tuple[ChangeMask, list[FloatArray]]] = {}  # per motion: its mask, its images' q
        self._outlines_placed = False  # the last pose: the outlines' alone, or held by them since (_confirm_outlines)
        self.relinearized = 0  # updates that solved every motion (for benchmarks)
        self.report_seconds = 0.0  # s spent on the conic front end for its report alone (``conics_always``)
        self.state = CalibrationState(None, "none", None, None, None, None, False, 0, 0, None,
                                      "no motion yet")

    def add_motion(self, obs: MotionObservation, update: bool = True,
                   outlines: Sequence[OutlineImage] = ()) -> MotionReport:
        """Take one motion's observation, prune or keep it, and (by default) update the estimate.

        ``outlines``: images of the motion for the outline stage (their ``group`` becomes the motion's index);
        kept only when the calibrator has a contour renderer.

        Raises:
            InvalidInputError: the kinematics function rejects the motion's configuration or
                returns a non-finite or non-unit axis.
        """
        with limited_blas(self.config.blas_threads):
            return self._add_motion(obs, update, outlines)

    def _add_motion(self, obs: MotionObservation, update: bool, outlines: Sequence[OutlineImage]) -> MotionReport:
        axis, point = self.kinematics(obs.q_start, obs.joint)
        axis, point = np.asarray(axis, float), np.asarray(point, float)
        if (axis.shape != (3,) or point.shape != (3,) or not np.all(np.isfinite(axis))
                or not np.all(np.isfinite(point)) or abs(np.linalg.norm(axis) - 1) > 1e-6):
            raise InvalidInputError(  # before anything is stored: reports and motions stay in step
                f"kinematics returned an invalid axis {axis} / point {point} for joint {obs.joint}"
            )
        report = MotionReport(index=len(self.reports), joint=obs.joint, n_tracks=len(obs.tracks))
        self.reports.append(report)
        if self.outlines is not None:
            for image in outlines:
                self.outlines.add(replace(image, group=report.index))
            changed = [image.changed for image in outlines if image.changed is not None]
            if changed and self._surface is not None:
                union = changed[0]
                for mask in changed[1:]:
                    union = union.union(mask)
                self._changes[report.index] = (union, [image.q for image in outlines])
        mcfg = self.config.motion
        moving = [t for t in obs.tracks
                  if len(t) >= self.config.refinement.min_track_frames and track_moved(t, mcfg)]
        if len(moving) < mcfg.min_tracks:
            report.reason = (f"nothing moved: {len(moving)} of {len(obs.tracks)} tracks moved "
                             f"{mcfg.min_pixel_motion} px over {mcfg.min_delta_span} rad "
                             f"(need {mcfg.min_tracks})")
            self._motions.append(None)
        else:
            found: list[MotionGeometry | None] = []

            def conics() -> MotionGeometry | None:  # the conic front end, run once and only when asked
                if not found:
                    found.append(self._conic_front_end(obs, report))
                return found[0]

            weak: MotionGeometry | None = None
            if self.config.rigid_axis is not None and self.config.rigid_always:
                moving, geometry, weak = self._rigid_front_end(obs, moving, conics, report, axis, point)
                if not found and self.config.conics_always:  # for the report only: the rigid axis stays
                    t0 = time.perf_counter()
                    conics()
                    self.report_seconds += time.perf_counter() - t0
                elif not found:
                    report.conics = CONICS_NOT_RUN
            else:
                geometry = conics()
                if self.config.rigid_axis is not None and geometry is None:
                    moving, geometry, weak = self._rigid_front_end(obs, moving, conics, report, axis, point)
            if geometry is not None and report.front_end != "rigid":
                report.front_end = "conics"
            if geometry is None:
                report.stage_one = "; ".join(r for r in (report.conics, report.rigid) if r)
            cap_tracks, cap_frames = self.config.max_tracks_per_motion, self.config.max_frames_per_track
            if cap_tracks is not None and len(moving) > cap_tracks:
                pick = self._rng.choice(len(moving), cap_tracks, replace=False)
                moving = [moving[k] for k in sorted(pick)]
            tracks = []
            for t in moving:
                idx = np.arange(len(t)) if cap_frames is None else evenly_spaced(len(t), cap_frames)
                tracks.append((normalized_from_pixels(t.pixels[idx], self.intrinsics), t.delta[idx],
                               None if t.velocity is None else t.velocity[idx]))
            self._motions.append(_Motion(obs, axis, point, geometry, tracks, weak=weak))
        if update:
            self._update()
        return report

    def update(self) -> CalibrationState:
        """Recompute the estimate from every motion so far; returns (and stores) the new state."""
        with limited_blas(self.config.blas_threads):
            return self._update()

    def _update(self) -> CalibrationState:
        cfg = self.config
        t_start = time.perf_counter()
        live = [k for k, m in enumerate(self._motions) if m is not None]
        with_axis = [k for k in live if self._motions[k].geometry is not None]
        linear: ConsensusResult | None = None
        message = ""
        if len(with_axis) >= 3:
            cors = [self._correspondence(k) for k in with_axis]
            try:
                linear = solve_consensus(cors, cfg.max_eps_a, cfg.max_eps_d, self._rng,
                                         fit_eps=None if cfg.fit_eps_a is None else (cfg.fit_eps_a, cfg.fit_eps_d))
            except (InsufficientMotionsError, UnobservablePoseError) as exc:
                message = str(exc)
                if len(with_axis) < len(live):  # the motions that would fix it may be the ones without an axis
                    message += (f" ({len(live) - len(with_axis)} of {len(live)} motions gave no axis; "
                                "their reports say why)")
        else:
            message = (f"{len(with_axis)} motion(s) with an axis; the linear calibration needs 3")

        t_linear = time.perf_counter()
        refined: RefinementResult | None = None
        start_kind: Start = ""
        start = self._refined.T_camera_base if self._refined is not None else None
        # After an update the outlines rescued, the tracks' adjustment starts from the rescued pose (which fit the
        # edges closely), not from the linear pose (seen: a realistic 720p iiwa rescued 0.5 mm off at motion 4, its
        # linear pose at 5 then refused outside the rescued region, and no pose at 5).
        rescued = self._rescued_pose()
        rescued_start = start is None and rescued is not None
        if rescued_start:
            start = rescued
        elif start is None and linear is not None:
            start = linear.T_camera_base
        tracks: TrackSet | None = None
        ran = False  # an adjustment from the previous, rescued or linear pose converged (its covariance may be wide)
        if cfg.refine and start is not None and self._from_family and linear is not None:
            # A family start's chain against the linear start, on every motion: the better fit goes on.
            tracks = self._track_set(live)
            refined, why, ran = self._rival_linear(tracks, live, linear.T_camera_base)
            if refined is None:
                message = why or message
            start_kind = "previous" if self._from_family else "linear"
        elif cfg.refine and start is not None:
            refined = self._increment(live) if self._refined is not None else None
            if refined is None:
                tracks = self._track_set(live)
                refined, why, ran = self._refine_checked(tracks, start, self._warm_points(live))
                message = why or message
                if refined is not None:
                    self._store_batch(live, tracks, refined)
            else:
                ran = True
            start_kind = "previous" if self._refined is not None or rescued_start else "linear"
        # The family when there is no pose to start from, or the adjustment could not run from the linear one
        # (e.g. a wrong branch that puts the tracks behind the camera); not when it ran and the motions do not
        # fix the pose: no other start changes that.
        if cfg.refine and cfg.family_start and self._refined is None and not ran and live:
            tracks = tracks if tracks is not None else self._track_set(live)
            refined, why = self._family_start(live, with_axis, tracks)
            start_kind = "family" if refined is not None else start_kind
            if refined is None:
                message = f"{message}; {why}" if message else why
            else:
                self._store_batch(live, tracks, refined)
                self._from_family = True
        t_refined = time.perf_counter()
        outline: OutlineFusion | None = None
        outline_note = ""
        confirmed = False  # the outlines alone held a pose they had placed (_confirm_outlines)
        if refined is not None:
            refined = self._without_weak_motions(refined)
            t_refined = time.perf_counter()
            outline, failure = self._fuse_outlines(refined)
            if (isinstance(failure, OutlineDisagreementError) and cfg.hold_outlines and self.state.outline is not None
                    and self._held_updates < HOLD_MAX_UPDATES):
                outline, failure = self._hold_outlines(refined, failure)
            if isinstance(failure, OutlineReachError) and cfg.rescue_wide:
                tracks = tracks if tracks is not None else self._track_set(live)
                outline, failure, refined = self._rescue_wide(refined, live, tracks, failure)
            unconfirmed = ""
            if (outline is None and isinstance(failure, (OutlineDisagreementError, OutlineReachError))
                    and cfg.hold_outlines and self._outlines_placed and self.state.outline is not None):
                outline, unconfirmed = self._confirm_outlines()
                confirmed = outline is not None
                failure = None if confirmed else failure
            first = self._refined is None  # a first pose: from the linear pose, the family or a rescued pose
            outline_note = "" if failure is None else f"{type(failure).__name__}: {failure}" + (
                f"; {unconfirmed}" if unconfirmed else "")
            rescued_cov = self.state.covariance  # the last update's: the rescued pose's, when there is one
            rescued_apart = (rescued is not None and rescued_cov is not None
                             and _transform_chi2(refined.T_camera_base, rescued, rescued_cov) > FAMILY_SAME_CHI2)
            refuted = cfg.refuse_refuted and (isinstance(failure, OutlineDisagreementError) or (
                isinstance(failure, OutlineReachError) and failure.refuted))
            if first and failure is not None and (isinstance(failure, OutlineMismatchError) or refuted
                                                  or rescued_apart):
                # A first pose the outlines cannot fit near: refused, neither reported nor chained from
                # (``_fuse_outlines``; from six motions on, the fusion's residual scale read here: seen, a realistic
                # 720p iiwa's family start 347 mm off at motion 6 fused with a 1-sigma of 0.6 mm); the outlines'
                # rescue may then try. After an update the outlines rescued,
                # a first pose they do not vouch for (they disagree with it, or cannot judge it yet) that lies
                # outside the rescued pose's region (its covariance: a wide first pose may hold the rescued pose in
                # its own, 338 mm off) is refused too: the rescue goes on from its
                # last pose (seen: a realistic 720p iiwa rescued 0.6 mm off at motion 3, then a family start 341 mm
                # off at 4 with the outlines 14.9 sigma away, chained from to motion 7; a realistic 720p Panda
                # rescued 0.9 mm off to motion 6, a linear start 338 mm off at 7). One inside that region goes on.
                # A first pose the outlines disagree with, or too wide for them whose search along its weakest
                # direction found them loose or disagreeing everywhere, is refused too (``refuse_refuted``; seen: an
                # as-shipped 720p iiwa's family start 296 mm off at motions 4 and 5 with a 1-sigma of 34 mm).
                source = ("the two-axis pose family" if start_kind == "family"
                          else "the tracks' adjustment from the rescued pose" if rescued_start
                          else "the linear calibration")
                why = f"the first pose, from {source}, is refused by the robot's outlines: {failure}"
                refined, self._from_family, outline_note = None, False, ""
                message = f"{message}; {why}" if message else why
        if refined is not None:
            self._refined = refined
        rescued, rescue_note = None, ""
        if refined is None and cfg.refine and self.outlines is not None and live:
            rescued, rescue_note = self._outline_rescue(live, with_axis, linear, tracks)
        self._update_reports(live, with_axis, linear, refined,
                             np.array([self._inlier_counts.get(k, 0) for k in live]) if refined is not None else None)

        T: FloatArray | None
        if refined is not None:
            T, stage = refined.T_camera_base, "refined"
        elif rescued is not None:
            T, stage, start_kind = rescued.T_camera_base, "refined", "outlines"
        elif linear is not None and not cfg.refine:
            T, stage = linear.T_camera_base, "linear"
        else:
            # With the bundle adjustment on, a linear pose it cannot confirm is not reported: from
            # a few motions the consensus can settle on a wrong branch (seen: 2.2 rad off from four
            # motions, which the tracks then did not fit). T_linear keeps it for diagnosis.
            T, stage = None, "none"
            if linear is not None:
                message = f"the linear estimate is not confirmed by the bundle adjustment: {message}"
        if refined is None:
            outline, outline_note = rescued, rescue_note
        elif outline is not None:
            T = outline.T_camera_base
        t_outline = time.perf_counter()
        if T is not None and rescued is None and self._enters_window(refined, live):
            self._monitor.push(T)
            self._window_motions = len(self._motions)
        cov = outline.covariance if outline is not None else refined.covariance if refined is not None else None
        std = np.sqrt(np.diag(cov)) if cov is not None else None
        # the tracks disagree (or cannot be paired with the outlines): not a pose to stop at
        held = outline is not None and (outline.prior_scale > 1.0 or confirmed)
        if outline is None or not held:
            self._held_updates = 0
        elif confirmed or outline.prior_scale > HOLD_FREE_SCALE:
            self._held_updates += 1  # a hold within HOLD_FREE_SCALE neither counts nor ends the run of holds
        self._outlines_placed = T is not None and (rescued is not None or (held and self._outlines_placed))
        converged = rescued is None and not held and self._monitor.converged and (
            stage == "linear" and not cfg.refine
            or stage == "refined" and std is not None
            and bool(np.all(std[:3] < cfg.convergence.max_rotation_range)
                     and np.all(std[3:] < cfg.convergence.max_translation_range)))
        n_acc = sum(r.accepted for r in self.reports)
        self.state = CalibrationState(
            T_camera_base=T, stage=stage,
            T_linear=linear.T_camera_base if linear is not None else None,
            covariance=cov, std=std, gamma=self._monitor.gamma, converged=bool(converged),
            n_accepted=n_acc, n_rejected=len(self.reports) - n_acc,
            rms_px=refined.rms_px if refined is not None else None,
            message="" if T is not None else message,
            seconds={"linear": t_linear - t_start, "refined": t_refined - t_linear, "outlines": t_outline - t_refined},
            start=start_kind if T is not None and stage == "refined" else "",
            time_offset_s=refined.time_offset_s if refined is not None else None,
            time_offset_std_s=refined.time_offset_std_s if refined is not None else None,
            outline=outline, outline_note=outline_note,
        )
        return self.state

    def _outline_rescue(self, live: list[int], with_axis: list[int], linear: ConsensusResult | None,
                        tracks: TrackSet | None) -> tuple[OutlineFusion | None, str]:
        """The outlines' fix of the direction the tracks leave free, when the tracks give no refined pose.

        From the last update's rescued pose when there is one (``_rescue_from``; an update that rescued keeps its
        pose for the next, which may otherwise start on another branch: seen, a realistic 720p xArm 6 rescued
        0.42 mm off at motion 5 and 1.19 m off, from a start 1 rad off, at motion 6), else or then from the linear
        pose, or else a member of the motions' pose family. Measured on realistic Panda episodes whose first motions
        turned joints 1-3 only: ``docs/realistic-imaging.md``. When those fail: the outlines alone from the last
        update's pose if the outlines fused or rescued it (``_outlines_alone``), then, with no rescued pose, the
        poses that draw the moving links where the motions changed the image (``_mask_rescue``) and last the family
        one motion's axis allows (``_one_axis_rescue``).

        ``tracks``: every live motion's track set if this update built one, else None (built here when there is a
        start to try).

        Returns:
            (the fusion, "") when it fixes the pose within ``max_std_*``; (None, why the last start failed) when it
            was tried and failed; (None, "") when there is nothing to try it with.
        """
        cfg = self.config
        assert self.outlines is not None
        if self.outlines.n_groups < self.outlines.config.min_groups_along:
            return None, ""
        joints = np.array([self._motions[k].point_base for k in live])
        rescued = self._rescued_pose()
        starts = [] if rescued is None else [rescued]
        if linear is not None:
            starts.append(linear.T_camera_base)
        elif len(with_axis) >= 2:
            try:
                R, t0, u = pose_family([self._correspondence(k) for k in with_axis])
                offsets = family_offsets(R, t0, u, joints, np.array([np.sqrt(np.prod(cfg.family_distances))]))
                if offsets.size:
                    starts.append(transform_from_rt(R, t0 + offsets[0] * u))
            except ArcCalibError:
                pass
        why = ""
        for T in starts:
            tracks = tracks if tracks is not None else self._track_set(live)
            fused, why, _ = self._rescue_from(T, live, joints, tracks)
            if fused is not None:
                return fused, ""
        if rescued is not None and tracks is not None:
            fused, why = self._rescue_near(rescued, tracks)
            if fused is not None:
                return fused, ""
        outlined = self.state.T_camera_base if self.state.outline is not None else None
        if outlined is not None:
            # The tracks could neither fix the pose nor agree with the outlines near the last pose, which the outlines
            # fused or rescued (the tracks' pose wide and biased by sliding tracks: seen, as-shipped iiwas rescued
            # 1.31 and 0.45 mm off at motion 4, at 5 the tracks' pose 18 and 37 sigma from the outlines'; an
            # as-shipped xArm 6 fused 0.41 mm off at 4, at 5 the tracks' 1-sigma 73 mm): the outlines alone, from it.
            fused, why_alone = self._outlines_alone(outlined, "the outlines alone could not hold the last pose")
            if fused is not None:
                return fused, ""
            why = f"{why}; {why_alone}" if why else why_alone
        # The change masks before the one-axis search: on replays of 48 as-shipped captures the same runs had a pose
        # by motion 5 and the replays took 30 % less CPU (docs/realistic-imaging.md, stop 64).
        if rescued is None and cfg.mask_start is not None and len(self._changes) >= cfg.mask_start.min_motions:
            fused, why_mask = self._mask_rescue(live)
            if fused is not None:
                return fused, ""
            why = f"{why}; {why_mask}" if why else why_mask
        if rescued is None and cfg.one_axis is not None and any(self._motions[k].search_axis is not None
                                                                for k in live):
            fused, why_one = self._one_axis_rescue(live, with_axis)
            if fused is not None:
                return fused, ""
            why = f"{why}; {why_one}" if why else why_one
        return None, why

    def _mask_rescue(self, live: list[int]) -> tuple[OutlineFusion | None, str]:
        """The outlines' rescue from where the moving links changed the image (``CalibratorConfig.mask_start``).

        Every motion whose outline images carry change masks (pruned ones too: a mask needs no tracks) is drawn from
        the robot's surface (``MovingSurface``) at its images' configurations; ``mask_starts`` gives the poses that
        cover the masks best, and the outlines are adjusted alone from each (``_outlines_alone``). A fusion is taken
        on the rescue's tests (the outlines' residual scale, the 1-sigma bounds), if the robot's outline there spans
        at least ``MIN_OUTLINE_SPREAD`` of the live motions' tracks' spread (as ``_one_axis_rescue``), and if at least
        ``MASK_MIN_PAIRED`` of its contour points seen in the images have an edge within ``MASK_PAIR_PX``
        (``OutlineAdjustment.paired_share``); of those taken, the one with the largest such share.

        Returns:
            (the fusion, "") or (None, why not).
        """
        assert self.outlines is not None and self.config.mask_start is not None and self._surface is not None
        prefix = "no start from the change masks"
        views = []
        for k, (change, qs) in sorted(self._changes.items()):
            joint = self.reports[k].joint
            views.append(MaskView(change, np.stack([self._surface.moving_points(q, joint) for q in qs])))
        try:
            starts = mask_starts(views, self.intrinsics, self.config.mask_start)
        except ArcCalibError as exc:
            return None, f"{prefix}: {type(exc).__name__}: {exc}"
        best: tuple[float, OutlineFusion] | None = None
        why = ""
        for rank, (iou, T) in enumerate(starts, 1):
            which = f"{prefix} (start {rank} of {len(starts)}, covering {iou:.2f})"
            fused, why_here = self._outlines_alone(T, which)
            if fused is not None and (small := self._outline_too_small(fused.T_camera_base, live)):
                fused, why_here = None, f"{which}: {small}"
            if fused is not None:
                share = self.outlines.paired_share(fused.T_camera_base, MASK_PAIR_PX)
                if share < MASK_MIN_PAIRED:
                    fused, why_here = None, (f"{which}: {share:.2f} of the robot's outline there lies within "
                                             f"{MASK_PAIR_PX:g} px of an edge (at least {MASK_MIN_PAIRED:g}): a pose "
                                             "far off")
            if fused is None:
                why = why or why_here
            elif best is None or share > best[0]:
                best = (share, fused)
        return (best[1], "") if best is not None else (None, why)

    def _outlines_alone(self, T: FloatArray, prefix: str) -> tuple[OutlineFusion | None, str]:
        """The outlines adjusted alone from T (4, 4): (the fusion, "") or (None, why not).

        Their prior is too wide to hold them (``OUTLINES_ALONE_PRIOR_STD``); the fusion is taken when it passes the
        rescue's tests (``_accepted_rescue``).
        """
        assert self.outlines is not None
        prior = np.diag(np.repeat(np.square(OUTLINES_ALONE_PRIOR_STD), 3))
        try:
            fused = self.outlines.fuse(T, prior, T, max_prior_px=float("inf"))
        except (ArcCalibError, np.linalg.LinAlgError) as exc:
            return None, f"{prefix}: {type(exc).__name__}: {exc}"
        return self._accepted_rescue(fused, prefix)

    def _one_axis_rescue(self, live: list[int], with_axis: list[int]) -> tuple[OutlineFusion | None, str]:
        """The outlines' rescue from the family of poses one motion's axis allows (``CalibratorConfig.one_axis``).

        The motion whose axis the most tracks follow, of those searched fewer than ``OneAxisSearch.max_tries`` times
        (and while fewer than ``max_searches`` searches ran in all), else of the motions with a weak axis
        (``OneAxisSearch.weak_share``) the one the most tracks follow; its family searched with a subsample of every
        live motion's tracks and then the outlines (``search_one_axis``); the outlines adjusted alone from the best
        member (``_outlines_alone``: the axis's direction is free again), taken on the rescue's tests (the outlines'
        residual scale, the 1-sigma bounds) and if the robot's outline there spans at least ``MIN_OUTLINE_SPREAD`` of
        its tracks' spread.

        Returns:
            (the fusion, "") or (None, why not).
        """
        assert self.outlines is not None and self.config.one_axis is not None
        prefix = "no start from one motion's axis"
        most, every = self.config.one_axis.max_tries, self.config.one_axis.max_searches
        left = [j for j in with_axis if self._one_axis_tries.get(j, 0) < most]
        weak = [j for j in live if self._motions[j].weak is not None and self._one_axis_tries.get(j, 0) < most]
        if not left + weak or sum(self._one_axis_tries.values()) >= every:
            return None, f"{prefix}: searched {most} times from each axis or {every} in all"
        k = max(left or weak, key=lambda j: int(np.sum(self._motions[j].search_axis.track_inliers)))
        self._one_axis_tries[k] = self._one_axis_tries.get(k, 0) + 1
        m = self._motions[k]
        geometry = m.search_axis
        assert geometry is not None
        which = f"motion {k + 1}" + ("" if m.geometry is not None else
                                     f", a weak axis: {int(np.sum(geometry.track_inliers))} of "
                                     f"{len(geometry.track_inliers)} tracks")
        try:
            T, _ = search_one_axis(self._screen_track_set(live), m.axis_base, m.point_base, geometry.axis_cam,
                                   geometry.reference_cam, self.intrinsics, self.outlines, self.config.one_axis)
        except ArcCalibError as exc:
            return None, f"{prefix} ({which}): {type(exc).__name__}: {exc}"
        fused, why = self._outlines_alone(T, f"{prefix} ({which})")
        if fused is None:
            return None, why
        small = self._outline_too_small(fused.T_camera_base, live)
        return (None, f"{prefix} ({which}): {small}") if small else (fused, "")

    def _outline_too_small(self, T: FloatArray, live: list[int]) -> str:
        """Why the robot's outline seen from T (4, 4) is too small to be its pose, or "" when it is not.

        Too small: its contour points span less than ``MIN_OUTLINE_SPREAD`` of the live motions' tracks' spread (a pose
        far off draws the robot small on a few edges). With no tracks nothing is compared.
        """
        assert self.outlines is not None
        tracks = np.concatenate([np.zeros((0, 2))] + [uv for j in live for uv, _, _ in self._motions[j].tracks])
        if not len(tracks):
            return ""
        spread = _spread(self.outlines.contour_rays(T)) / max(_spread(tracks), 1e-12)
        if spread >= MIN_OUTLINE_SPREAD:
            return ""
        return (f"the robot's outline there spans {spread:.2f} of its tracks' spread (at least "
                f"{MIN_OUTLINE_SPREAD:g}): a pose far off")

    def _rescue_from(self, T: FloatArray, live: list[int], joints: FloatArray, tracks: TrackSet,
                     max_prior_px: float | None = None) -> tuple[OutlineFusion | None, str, bool]:
        """The outlines' rescue (``_outline_rescue``) from T (4, 4): (the fusion, "", False) or (None, why, refuted).

        Refuted: the search ran and the outlines fit their edges too loosely at its best pose, or their pose disagreed
        with the tracks' held along the direction (not: the tracks or the outlines could not be judged there).

        A short pass of the bundle adjustment (``screen_start``); there the tracks' weakest direction
        (``track_observability``: the translation in units of the points' depth, so the rotation and translation
        compare as the image sees them), which must be a translation u; the bundle adjustment held along u by a weak
        prior (``refine``'s ``free_direction``: its covariance is the honest one elsewhere); the outlines' search
        along u where the motions' joints (``joints`` (M, 3), base frame) lie ``family_distances`` from the camera
        (``OutlineAdjustment.search_along``) and their adjustment from there with the tracks' pose and covariance as
        the prior (``fuse``; ``max_prior_px``: its reach instead of ``OutlineFusionConfig.max_prior_px``). The
        outlines must fit their edges there (residual scale at most ``OutlineFusionConfig.max_early_sigma_px``, however
        many motions: nothing else vouches for a rescued pose).
        """
        cfg = self.config
        assert self.outlines is not None
        prefix = "the outlines could not fix what the tracks leave free"
        T, score = screen_start(self._screen_track_set(live), T, cfg.refinement, cfg.refinement.max_nfev, FAMILY_CAP_PX)
        if not np.isfinite(score):
            return None, f"{prefix}: the tracks cannot be triangulated from the start", False
        _, weakest = track_observability(tracks, T)
        if np.linalg.norm(weakest[3:]) < 0.9:
            return None, f"{prefix}: the tracks' weakest direction is a rotation", False
        u = weakest[3:] / np.linalg.norm(weakest[3:])
        try:
            held = refine(tracks, T, cfg.refinement, free_direction=np.concatenate([np.zeros(3), u]))
            offsets = family_offsets(held.T_camera_base[:3, :3], held.T_camera_base[:3, 3], u, joints,
                                     np.geomspace(*cfg.family_distances, OUTLINE_SEARCH_SAMPLES))
            if offsets.size < 2:
                return None, f"{prefix}: no pose along it puts the robot in front of the camera", False
            start, _ = self.outlines.search_along(held.T_camera_base, u, offsets)
            fused = self.outlines.fuse(held.T_camera_base, held.covariance, start, free_direction=u,
                                       max_prior_px=max_prior_px)
        except (OutlineMismatchError, OutlineDisagreementError) as exc:
            return None, f"{prefix}: {type(exc).__name__}: {exc}", True
        except (ArcCalibError, np.linalg.LinAlgError) as exc:
            return None, f"{prefix}: {type(exc).__name__}: {exc}", False
        accepted, why = self._accepted_rescue(fused, prefix)
        return accepted, why, accepted is None and bool(self._loose_fit(fused))

    def _rescue_wide(self, refined: RefinementResult, live: list[int], tracks: TrackSet, failure: OutlineReachError
                     ) -> tuple[OutlineFusion | None, Exception | None, RefinementResult]:
        """The outlines' rescue from a tracks' pose too wide for them to pair with (``CalibratorConfig.rescue_wide``).

        The tracks' adjustment gave a pose whose 1-sigma moves the contour points too far for the nearest edges to be
        theirs (``failure``): its weakest direction is searched with the outlines and the adjustment goes on from the
        best pose there, as when the tracks give no pose (``_rescue_from``, from the tracks' pose), with the reach
        ``OutlineFusionConfig.max_rescue_prior_px`` in the other directions. The rescue's own tests decide (the
        outlines' residual scale, their agreement with the tracks' pose held along the searched direction, the
        1-sigma bounds), not the tracks' covariance: from a few motions it can be far too narrow (seen: an as-shipped
        iiwa's family start at motion 5, 0.18 rad and 217 mm off with a 1-sigma of 142 mm, the rescue 0.09 mm off
        at a chi-square of 34 under it). The tracks are then adjusted again from the rescued pose: when that fits
        them at least as well (RMS) and holds the rescued pose in its region (chi-square at most
        ``FAMILY_SAME_CHI2``), their chain goes on from it (it was in another basin: that iiwa's, from the rescued
        pose, 15.8 mm off at an RMS of 0.743 px against 0.781) and the outlines are adjusted with it as their prior.
        Costs an outline search (about 9 s of CPU for 15 images at 1080p) each update it runs.

        Returns:
            (the fusion, None, the tracks' pose) or (None, the reach failure with the rescue's reason and whether the
            rescue refuted the pose, ``refined``).
        """
        assert self.outlines is not None
        joints = np.array([self._motions[k].point_base for k in live])
        fused, why, refuted = self._rescue_from(refined.T_camera_base, live, joints, tracks,
                                                self.outlines.config.max_rescue_prior_px)
        if fused is None:
            return None, OutlineReachError(f"{failure}; searched along the tracks' weakest direction: {why}",
                                           refuted), refined
        again, _, _ = self._refine_checked(tracks, fused.T_camera_base, None)
        if (again is None or again.rms_px > refined.rms_px
                or _transform_chi2(fused.T_camera_base, again.T_camera_base, again.covariance) > FAMILY_SAME_CHI2):
            return fused, None, refined
        self._store_batch(live, tracks, again)
        try:
            joint = self.outlines.fuse(again.T_camera_base, again.covariance, fused.T_camera_base,
                                       start_covariance=fused.covariance)
        except (ArcCalibError, np.linalg.LinAlgError):
            return fused, None, again
        accepted, _ = self._accepted_rescue(joint, "")
        return accepted or fused, None, again

    def _rescue_near(self, T: FloatArray, tracks: TrackSet) -> tuple[OutlineFusion | None, str]:
        """The outlines' rescue from the last rescued pose T (4, 4): (the fusion, "") or (None, why not).

        Tried when the rescue along one free direction (``_rescue_from``) fails from every start. The tracks'
        adjustment held at T by a weak prior in every direction (``refine``'s ``free_direction``: the identity), so
        whatever the kept tracks leave free stays free in its covariance (when they leave nothing free, nothing to
        rescue: their own pose was judged); the outlines' adjustment from T with that pose and covariance as the
        prior, their pairing's reach judged by T's covariance (it fit the edges). Seen: a realistic 720p xArm 6
        rescued under 1 mm off at motion 9 whose tracks' adjustment dropped every track of its two joint-5 motions
        at 10 as outliers, leaving three directions free: the one-direction rescue then had singular equations, and
        no pose came until the linear one at 13.
        """
        assert self.outlines is not None
        prefix = "the outlines could not fix what the tracks leave free from the rescued pose"
        cfg = self.config
        try:
            held = refine(tracks, T, cfg.refinement, free_direction=np.eye(6))
            if self._within_std_bounds(np.sqrt(np.diag(held.covariance))):
                # every 1-sigma within the usable bounds: nothing is left free
                return None, f"{prefix}: the tracks leave no direction free there (their own pose was judged)"
            fused = self.outlines.fuse(held.T_camera_base, held.covariance, T, start_covariance=self.state.covariance)
        except (ArcCalibError, np.linalg.LinAlgError) as exc:
            return None, f"{prefix}: {type(exc).__name__}: {exc}"
        return self._accepted_rescue(fused, prefix)

    def _accepted_rescue(self, fused: OutlineFusion, prefix: str) -> tuple[OutlineFusion | None, str]:
        """A rescue's fusion with its covariance bounded below by the outlines' own, or (None, why it is refused)."""
        loose = self._loose_fit(fused)
        if loose:
            return None, f"{prefix}: they fit their edges too loosely there ({loose})"
        # From three to five motions the tracks' covariance is too narrow in the directions they fix best (their
        # motion clusters are too few; measured: chi-square of the truth 11-44 over 5 dof): the outlines' own
        # covariance bounds the rescued pose's from below (then 0.8-5.9 over 6 dof where the fusion's was 1-40).
        fused = replace(fused, covariance=conservative_covariance(fused.covariance, fused.outline_covariance))
        std = np.sqrt(np.diag(fused.covariance))
        if not self._within_std_bounds(std):
            return None, f"{prefix}: together they leave a 1-sigma of {np.round(std, 4).tolist()} (rad, m)"
        return fused, ""

    def _rescued_pose(self) -> FloatArray | None:
        """The last update's pose (4, 4) when the outlines rescued it (``_outline_rescue``), else None."""
        return self.state.T_camera_base if self.state.start == "outlines" else None

    def _loose_fit(self, fusion: OutlineFusion) -> str:
        """Why ``fusion``'s outlines fit their edges too loosely to vouch for a pose alone, or "" when they do not.

        Every fusion the calibrator takes needs this, at any motion count (the fusion checks it below
        ``trusted_groups`` only): their residuals' robust scale at most ``OutlineFusionConfig.max_early_sigma_px``.
        """
        assert self.outlines is not None
        most = self.outlines.config.max_early_sigma_px
        return "" if fusion.sigma_px <= most else f"residual scale {fusion.sigma_px:.2f} px, at most {most:g}"

    def _store_batch(self, live: list[int], tracks: TrackSet, refined: RefinementResult) -> None:
        """Keep a bundle adjustment over every motion ``live``: its points, inlier counts and summaries' order."""
        counts = np.bincount(tracks.motion[refined.track_inliers], minlength=len(live))
        offsets = np.cumsum([0] + [len(self._motions[k].tracks) for k in live])
        for slot, k in enumerate(live):
            self._motions[k].points = refined.points_base[offsets[slot]:offsets[slot + 1]]
            self._inlier_counts[k] = int(counts[slot])
            self._lin_information[k] = np.linalg.inv(refined.covariance)
        # a backend without motion summaries (the Ceres one) adjusted every motion given
        self._refined_live = [live[m.motion] for m in refined.summaries] if refined.summaries else list(live)
        self._since_batch = 0
        self.relinearized += 1

    def _increment(self, live: list[int]) -> RefinementResult | None:
        """The refined pose with the one motion added since the last, the others summarized.

        ``CalibratorConfig.incremental``.

        None when it does not apply (off, not exactly one new motion, no summaries, time for a relinearization)
        or fails, or when the pose moved too far from where the earlier motions were linearized: the caller
        then solves every motion.
        """
        cfg = self.config
        prev = self._refined
        new = [k for k in live if k not in self._inlier_counts]
        if (not cfg.incremental or prev is None or not prev.summaries or len(new) != 1
                or self._since_batch + 1 >= cfg.relinearize_every
                or set(live) - set(new) != set(self._inlier_counts)):
            return None
        k = new[0]
        tracks = self._track_set([k])
        try:
            refined = refine_increment(tracks, prev.T_camera_base, prev.summaries,
                                       prev.robust_sigma_px or prev.sigma_px, cfg.refinement, prev.time_offset_s)
        except (ArcCalibError, np.linalg.LinAlgError):
            return None
        if not self._fixes_pose(refined):
            return None
        moved = max(float(np.sqrt(max(xi @ self._lin_information[j] @ xi, 0.0))) for j, xi in
                    zip(self._refined_live, (pose_difference(m.T_lin, refined.T_camera_base)
                                             for m in prev.summaries), strict=True))
        if moved > cfg.relinearize_sigma:
            return None
        self._motions[k].points = refined.points_base
        self._inlier_counts[k] = int(refined.track_inliers.sum())
        self._lin_information[k] = np.linalg.inv(refined.covariance)
        self._refined_live.append(k)
        self._since_batch += 1
        return refined

    def _enters_window(self, refined: RefinementResult | None, live: list[int]) -> bool:
        """Whether this update's estimate enters the convergence monitor's window.

        Only after a motion taken since the last entry that informs it (``MotionReport.accepted``), and for a
        refined estimate only when that motion brings at least ``ConvergenceConfig.min_leverage`` of the pose
        information in some direction (a backend without motion summaries counts every accepted motion).
        """
        newest = len(self._motions) - 1
        if len(self._motions) <= self._window_motions or not self.reports[newest].accepted:
            return False
        if refined is None or len(refined.summaries) != len(live) or live[-1] != newest:
            return True
        try:
            self.reports[newest].leverage = newest_motion_leverage(refined.summaries)
        except InvalidInputError:
            return True
        return self.reports[newest].leverage >= self.config.convergence.min_leverage

    def _fixes_pose(self, refined: RefinementResult) -> bool:
        """Whether the motions fix the refined pose: every 1-sigma finite and within the ``max_std_*`` bounds.

        Judged on the covariance before the motion jackknife (``RefinementResult.sandwich_covariance``):
        with a few motions the jackknife measures how much they disagree, not what they leave free, and it
        would hold back a pose the geometry fixes. The reported covariance and convergence keep it.
        """
        return self._within_std_bounds(_geometric_std(refined))

    def _within_std_bounds(self, std: FloatArray) -> bool:
        """Whether a 1-sigma (6,) (rad, m) is finite and within ``max_std_rotation`` / ``max_std_translation``."""
        return bool(np.all(np.isfinite(std)) and np.all(std[:3] <= self.config.max_std_rotation)
                    and np.all(std[3:] <= self.config.max_std_translation))

    def _without_weak_motions(self, refined: RefinementResult) -> RefinementResult:
        """The adjustment again without the motions it used whose kept tracks are fewer than ``motion.min_tracks``.

        Their reports say they do not inform the estimate (``MotionReport.accepted``), and a few tracks of one
        motion that alone fix a direction cannot be checked by the others: measured on a captured realistic xArm 6
        1080p episode (pose 5), a wrist motion with 2 of 8 tracks kept shrank the translation 1-sigma from 4.3 to
        1.2 mm and put the truth at chi-square 107. Such a motion stays live: the next adjustment of every motion
        (``relinearize_every``) takes it back if enough of its tracks then agree. Returns ``refined`` when there is
        none, or when the adjustment without them does not fix the pose.
        """
        min_tracks = self.config.motion.min_tracks
        used = self._refined_live
        weak = [k for k in used if 0 < self._inlier_counts.get(k, 0) < min_tracks]
        if not weak:
            return refined
        kept = [k for k in used if k not in weak]
        tracks = self._track_set(kept)
        again, _, _ = self._refine_checked(tracks, refined.T_camera_base, self._warm_points(kept))
        if again is None:
            return refined
        counts = {k: self._inlier_counts[k] for k in weak}
        self._store_batch(kept, tracks, again)
        self._inlier_counts.update(counts)  # what the weak motions' tracks did when they were in
        return again

    def _refine_checked(self, tracks: TrackSet, start: FloatArray, points_init: FloatArray | None
                        ) -> tuple[RefinementResult | None, str, bool]:
        """The bundle adjustment from ``start``.

        Returns:
            (the result, "", True) if the motions fix its pose (1-sigma within max_std_*); else (None, why,
            whether the adjustment ran: False when it failed before giving a pose and covariance).
        """
        cfg = self.config
        try:
            refined = refine(tracks, start, cfg.refinement, points_init=points_init)
        except ArcCalibError as exc:
            return None, f"refinement failed: {exc}", False
        except np.linalg.LinAlgError:  # numpy's words ("leading minor not positive definite") mean nothing here
            return None, ("refinement failed: its equations are singular (tracks or motions that leave a point "
                          "or the pose free)"), False
        if not self._fixes_pose(refined):
            std = _geometric_std(refined)
            return None, (f"the motions do not fix the pose: 1-sigma uncertainty "
                          f"{np.round(std, 4).tolist()} (rad, m) is too large"), True
        return refined, "", True

    def _rival_linear(self, tracks: TrackSet, live: list[int], linear: FloatArray
                      ) -> tuple[RefinementResult | None, str, bool]:
        """The adjustment of every motion from the family chain's pose and from the linear pose; the better fit.

        A family start is rough (one ray's worth of members, scored on a subsample) and every later update
        starts from the previous pose, so the chain can stay in a worse minimum; once the motions' axes give
        a linear pose, both starts are adjusted on every motion and the one that explains the tracks better
        (``_fit_score``) goes on. When the linear start wins, or both reach the same pose
        (``RIVAL_SAME_SIGMA``: the chain's result is kept), the chain is an ordinary one from then on.

        Returns:
            (the kept result, "", True), or (None, why, whether an adjustment ran) when neither passes its checks.
        """
        assert self._refined is not None
        warm = self._warm_points(live)
        chain, why, ran = self._refine_checked(tracks, self._refined.T_camera_base, warm)
        rival, why_rival, ran_rival = self._refine_checked(tracks, linear, None)
        if rival is not None and chain is not None and _pose_chi2(chain, rival, chain.covariance) < RIVAL_SAME_SIGMA**2:
            self._from_family = False
        elif rival is not None and (chain is None or _fit_score(tracks, rival, FAMILY_CAP_PX)
                                    < _fit_score(tracks, chain, FAMILY_CAP_PX)):
            chain, self._from_family = rival, False
        if chain is None:
            return None, why or why_rival, ran or ran_rival
        self._store_batch(live, tracks, chain)
        return chain, "", True

    def _family_start(self, live: list[int], with_axis: list[int], tracks: TrackSet
                      ) -> tuple[RefinementResult | None, str]:
        """The bundle adjustment started from the motions' pose family (``CalibratorConfig.family_start``).

        The axes fix the rotation and the translation up to a line t0 + s u (``pose_family``). Members
        are placed where the motions' joints lie ``family_distances`` from the camera; each takes a
        short robust pass of the bundle adjustment over a subsample of every motion's tracks
        (``screen_start``), scored alike. The full adjustment then runs from the best, and from every
        other local minimum along s that scores within ``FAMILY_RIVAL_RATIO`` of it; when those that
        succeed end at poses that differ (beyond their covariances) and fit all tracks about equally
        (``FAMILY_MARGIN``), the family is ambiguous and no pose is given.

        Returns:
            (the checked refinement, "") or (None, why not).
        """
        cfg = self.config
        prefix = "no start from the two-axis pose family"
        if len(with_axis) < 2:
            return None, f"{prefix}: it needs 2 motions with non-parallel axes, {len(with_axis)} have an axis"
        try:
            R, t0, u = pose_family([self._correspondence(k) for k in with_axis])
        except ArcCalibError as exc:
            return None, f"{prefix}: {exc}"
        joints = np.array([self._motions[k].point_base for k in live])
        offsets = family_offsets(R, t0, u, joints, np.geomspace(*cfg.family_distances, cfg.family_samples))
        if offsets.size == 0:
            return None, (f"{prefix}: no member puts the robot {cfg.family_distances[0]}-"
                          f"{cfg.family_distances[1]} m in front of the camera")
        sample = self._screen_track_set(live)
        screened = [screen_start(sample, transform_from_rt(R, t0 + s * u), cfg.refinement, FAMILY_SCREEN_NFEV,
                                 FAMILY_CAP_PX) for s in offsets]
        scores = np.array([score for _, score in screened])
        if not np.isfinite(scores).any():
            return None, f"{prefix}: no member sees the tracks in front of the camera"
        best = int(np.argmin(scores))
        padded = np.concatenate([[np.inf], scores, [np.inf]])
        minima = [i for i in range(len(scores)) if padded[i + 1] <= min(padded[i], padded[i + 2])
                  and i != best and scores[i] <= (1 + FAMILY_RIVAL_RATIO) * scores[best]]
        candidates = [best] + sorted(minima, key=lambda i: scores[i])[:FAMILY_MAX_RIVALS]
        results: list[tuple[RefinementResult, float]] = []
        for i in candidates:
            polished, _ = screen_start(sample, screened[i][0], cfg.refinement, cfg.refinement.max_nfev, FAMILY_CAP_PX)
            refined, why, _ = self._refine_checked(tracks, polished, None)
            if refined is not None:
                ratio, direction = track_observability(tracks, refined.T_camera_base, refined.track_inliers)
                if ratio < MIN_OBSERVABILITY:  # noise-free tracks give a small covariance along a free direction
                    refined, why = None, (f"the tracks cannot fix the pose: (omega, tau / depth) along "
                                          f"{np.round(direction, 3).tolist()} is free (observability {ratio:.1e} "
                                          f"< {MIN_OBSERVABILITY})")
            if refined is None and not results:  # the best member fails: its rivals only serve to judge it
                return None, f"{prefix}: {why}"
            if refined is not None:
                results.append((refined, _fit_score(tracks, refined, FAMILY_CAP_PX)))
        results.sort(key=lambda r: r[1])
        chosen, score = results[0]
        for other, other_score in results[1:]:
            same = _pose_chi2(chosen, other, chosen.covariance + other.covariance) < FAMILY_SAME_CHI2
            if not same and other_score < (1 + FAMILY_MARGIN) * score:
                xi = pose_difference(chosen.T_camera_base, other.T_camera_base)
                er, et = float(np.linalg.norm(xi[:3])), float(np.linalg.norm(xi[3:]))
                return None, (f"{prefix}: two of its members fit the tracks about equally well ({score:.3g} and "
                              f"{other_score:.3g} px^2) {er:.3g} rad / {et:.3g} m apart; add motions")
        return chosen, ""

    def _hold_outlines(self, refined: RefinementResult, failure: OutlineDisagreementError
                       ) -> tuple[OutlineFusion | None, Exception | None]:
        """The outlines fused (or rescued) at the last update, now in disagreement with the tracks' pose ``refined``.

        The outlines fitted the images before, so the robot model matches them; a new disagreement is the tracks'
        covariance that is too narrow for where their pose went (on as-shipped castings most tracks slide:
        seen, an xArm 6 fused 0.2 mm off for three updates, then the tracks' pose 54 mm and 7 mrad off at motion 7,
        5.8 sigma from the outlines', and 64 mm off reported for two updates). The outlines are adjusted again from
        the last fused pose with the tracks' covariance scaled by the least factor that brings the disagreement to
        ``HOLD_TARGET_CHI2`` (``consistent_prior_scale``, at most ``HOLD_MAX_SCALE``); the result is taken when it
        passes the disagreement test and is the last update's pose (chi-square at most ``FAMILY_SAME_CHI2`` under
        the sum of their covariances): the outlines hold where they were while the tracks went. Its ``prior_scale``
        says so, and the update declares no convergence. At most ``HOLD_MAX_UPDATES`` updates in a row: outlines
        that had settled on a wrong pose together with the tracks would otherwise hold it when the tracks leave it
        (holds whose factor is at most ``HOLD_FREE_SCALE`` do not count: tracks that leave for a better pose need
        ever larger factors as they firm up).

        Returns:
            (the held fusion, None), or (None, the disagreement, with why it was not held).
        """
        assert self.outlines is not None and self.state.T_camera_base is not None
        scale = consistent_prior_scale(failure, HOLD_TARGET_CHI2, HOLD_MAX_SCALE)
        if scale is None:
            return None, OutlineDisagreementError(
                f"{failure}; not held: the tracks' covariance would need more than {HOLD_MAX_SCALE:g}x", failure.chi2)
        held, why = self._fuse_outlines(refined, scale)
        if held is None:
            return None, OutlineDisagreementError(f"{failure}; not held: {why}", failure.chi2)
        moved = self._moved_from_last(held)
        if moved > FAMILY_SAME_CHI2:
            return None, OutlineDisagreementError(
                f"{failure}; not held: with the tracks' covariance {scale:.1f}x the outlines' pose moved "
                f"{np.sqrt(moved):.1f} sigma from the last update's", failure.chi2)
        return held, None

    def _confirm_outlines(self) -> tuple[OutlineFusion | None, str]:
        """The outlines alone hold a pose they placed, when the tracks' pose cannot be combined with them.

        For a chain the outlines began alone (a rescue, e.g. from one motion's axis) and held since: the tracks'
        pose disagrees with them beyond what the hold allows (``HOLD_MAX_UPDATES`` in a row, or a scale over
        ``HOLD_MAX_SCALE``), or is too uncertain to pair them with. On as-shipped castings the tracks that slide
        bias it (seen: an xArm 6 rescued 0.08 mm off from one axis at motion 5, held at 6-8, then the tracks' pose
        69, 64 and 75 mm off at 9-11, its 1-sigma 19-46 mm). The outlines are adjusted alone from the last
        update's pose (``_outlines_alone``) and kept when they pass the rescue's tests and stay in that pose's
        region (chi-square at most ``FAMILY_SAME_CHI2`` under the sum of the covariances); never converged.

        Returns:
            (the fusion, "") or (None, why not).
        """
        assert self.state.T_camera_base is not None
        fused, why = self._outlines_alone(self.state.T_camera_base,
                                          "the outlines alone could not hold the pose they placed")
        if fused is None:
            return None, why
        moved = self._moved_from_last(fused)
        if moved > FAMILY_SAME_CHI2:
            return None, (f"the outlines alone moved {np.sqrt(moved):.1f} sigma from the pose they placed: "
                          "not held")
        return fused, ""

    def _moved_from_last(self, fusion: OutlineFusion) -> float:
        """The chi-square of ``fusion``'s pose from the last update's, under the sum of their covariances."""
        assert self.state.T_camera_base is not None and self.state.covariance is not None
        return _transform_chi2(fusion.T_camera_base, self.state.T_camera_base,
                               self.state.covariance + fusion.covariance)

    def _fuse_outlines(self, refined: RefinementResult, prior_scale: float = 1.0
                       ) -> tuple[OutlineFusion | None, Exception | None]:
        """The outlines adjusted with the tracks' pose ``refined``: (the fusion, None) or (None, why they could not be).

        Without outline images: (None, None). The adjustment goes on from where the last one ended, with the tracks'
        covariance taken ``prior_scale`` times (``OutlineAdjustment.fuse``; ``_hold_outlines``). Outlines that fit
        their edges loosely (``_loose_fit``) are refused at any count (``OutlineMismatchError``): paired with other
        edges, they pull the pose to a wrong minimum with a narrow covariance (seen: an as-shipped xArm 6 at 720p,
        after an update whose tracks' pose the outlines disagreed with, fused 21 mm off with a 1-sigma of 0.5 mm at a
        residual scale of 2.81 px, where its good fusions had 0.2-0.4 px; another fused 65-110 mm off at 2.6-3.0 px).
        Its ``OutlineMismatchError`` refuses a first pose in ``update``: from the first few motions the linear
        calibration and the pose family can settle on a wrong branch that the tracks then fit (seen: a realistic
        720p Panda 1.84 rad and 379 mm off for three motions from the family, 1-sigma 0.03 rad and 62 mm; a 720p
        iiwa 115 mm off from the linear pose, chi-square of the truth 35). Any other failure refuses a first pose
        only when it lies outside a pose the outlines rescued in the last update (``update``).
        """
        if self.outlines is None or not self.outlines.n_images:
            return None, None
        last = self.state.outline
        # From the last fused (or rescued) pose the pairing's reach is judged by that pose's covariance: the tracks'
        # own may still be too wide for it (seen: a realistic 720p iiwa's 8.2 px RMS at motion 5, where the pose the
        # outlines rescued at 4 was 0.5 mm off; and 8.8 px at 13 after a fused pose 0.7 mm off at 12).
        try:
            fused = self.outlines.fuse(refined.T_camera_base, refined.covariance,
                                       last.T_camera_base if last is not None else None,
                                       start_covariance=self.state.covariance if last is not None else None,
                                       prior_scale=prior_scale)
        except (ArcCalibError, np.linalg.LinAlgError) as exc:
            return None, exc
        loose = self._loose_fit(fused)
        if loose:
            return None, OutlineMismatchError(f"from {fused.n_groups} motions the outlines fit their edges too loosely "
                                              f"({loose}): paired with other edges than the robot's")
        return fused, None

    def _screen_track_set(self, live: list[int]) -> TrackSet:
        """A subsample of motions ``live``'s tracks for ``screen_start``: evenly spaced tracks and frames."""
        motions = []
        for k in live:
            m = self._motions[k]
            tracks = []
            for uv, delta, _ in (m.tracks[j] for j in evenly_spaced(len(m.tracks), FAMILY_SCREEN_TRACKS)):
                frames = evenly_spaced(len(delta), FAMILY_SCREEN_FRAMES)
                tracks.append((uv[frames], delta[frames]))
            motions.append((m.axis_base, m.point_base, tracks))
        return build_track_set(motions, self.intrinsics.focal, self.config.refinement.min_track_frames)

    def focal_check(self, scales: Sequence[float] = FOCAL_SCAN_SCALES) -> FocalCheck | None:
        """Whether the camera's focal lengths fit the tracks (None without a refined estimate).

        The final bundle adjustment is repeated with both focal lengths scaled by each of ``scales``
        (the tracks re-normalized accordingly, from the refined pose and points); a parabola through
        the RMS residual against the scale gives the best-fitting scale. Wrong intrinsics bias the pose
        far beyond its 1-sigma while the RMS barely moves (fx 5 % high: 39 mm off, 1-sigma 1.2 mm,
        RMS 0.208 against 0.167 px at the true fx), so this is the test that catches them.
        """
        with limited_blas(self.config.blas_threads):
            return self._focal_check(scales)

    def _focal_check(self, scales: Sequence[float]) -> FocalCheck | None:
        if self._refined is None or self.state.stage != "refined":
            return None
        live = [k for k, m in enumerate(self._motions) if m is not None]
        warm = self._warm_points(live)
        fits = []
        for scale in scales:
            tracks = self._track_set(live, scale)
            try:
                fits.append((tracks, refine(tracks, self._refined.T_camera_base, self.config.refinement,
                                            points_init=warm)))
            except (ArcCalibError, np.linalg.LinAlgError):
                fits.append(None)
        # Every scale judged on the same observations: the tracks that all its adjustments kept (each
        # drops its own outliers, and a scan over different track sets is not smooth near its minimum).
        common = np.logical_and.reduce([fit[1].track_inliers for fit in fits if fit is not None])
        rms = np.full(len(scales), np.nan)
        for i, fit in enumerate(fits):
            if fit is not None and common.any():
                residuals = reprojection_residuals(*fit)[common[fit[0].track]]
                rms[i] = float(np.sqrt(np.mean(residuals**2)))
        return FocalCheck.from_scan(np.asarray(scales, dtype=np.float64), rms)

    def batch_refinement(self) -> RefinementResult | None:
        """The bundle adjustment of every motion, from the current refined pose, leaving the state as it is.

        What an update that relinearizes would give (``CalibratorConfig.incremental``): the reference the
        incremental estimate is compared with. None without a refined pose.

        Raises:
            ArcCalibError: the adjustment fails (``refine``).
        """
        if self._refined is None or self.state.stage != "refined":
            return None
        live = [k for k, m in enumerate(self._motions) if m is not None]
        with limited_blas(self.config.blas_threads):
            return refine(self._track_set(live), self._refined.T_camera_base, self.config.refinement,
                          points_init=self._warm_points(live))

    def _track_set(self, live: list[int], focal_scale: float = 1.0) -> TrackSet:
        """The bundle adjustment's observations of motions ``live``, for focal lengths scaled by focal_scale.

        The normalized coordinates are divided by the scale: exact without distortion, first order with it
        and for a fisheye. Re-undistorting a fisheye's pixels with the scaled K instead was tried: a 3 % high
        focal length came out best at 0.963 either way (8 noise-free motions), so the simple form stays.
        """
        motions = [(self._motions[k].axis_base, self._motions[k].point_base,
                    self._motions[k].tracks if focal_scale == 1.0 else
                    [(uv / focal_scale, *rest) for uv, *rest in self._motions[k].tracks]) for k in live]
        return build_track_set(motions, self.intrinsics.focal * focal_scale, self.config.refinement.min_track_frames)

    def _warm_points(self, live: list[int]) -> FloatArray:
        """(T, 3) m: the last refined point of every track of motions ``live``, NaN where unknown."""
        return np.concatenate([self._motions[k].points if self._motions[k].points is not None
                               else np.full((len(self._motions[k].tracks), 3), np.nan) for k in live])

    def motion_geometry(self, index: int) -> MotionGeometry | None:
        """Stage one's axis and reference plane of motion ``index`` (None: pruned or no axis)."""
        if not 0 <= index < len(self._motions):
            raise InvalidInputError(f"no motion {index}: {len(self._motions)} added")
        m = self._motions[index]
        return m.geometry if m is not None else None

    def _conic_front_end(self, obs: MotionObservation, report: MotionReport) -> MotionGeometry | None:
        """Stage one's conics (``estimate_motion_geometry``): the motion's geometry, or None and ``report.conics`` why.

        Whether its geometry becomes the motion's (``report.front_end``) is ``add_motion``'s to say.

        Its random choices come from a generator of the seed and the motion's index alone, so whether the conics
        ran on the motions before (``CONICS_NOT_RUN``) does not change them.
        """
        rng = np.random.default_rng([self.config.seed, report.index])
        try:
            geometry = estimate_motion_geometry(obs, self.intrinsics, self.config.motion, rng)
        except DegenerateMotionError as exc:
            report.conics = str(exc)
            return None
        return geometry

    def _rigid_front_end(self, obs: MotionObservation, moving: list[KeypointTrack],
                         conics: Callable[[], MotionGeometry | None], report: MotionReport, axis_base: FloatArray,
                         point_base: FloatArray
                         ) -> tuple[list[KeypointTrack], MotionGeometry | None, MotionGeometry | None]:
        """Run the rigid front end: (the tracks that move rigidly, the motion's geometry, a weak axis).

        ``conics`` gives the conic front end's geometry (or None), running it when first called: its axis is a
        start of the rigid fit, and the fallback when the fit fails. ``axis_base`` (3,) unit and ``point_base``
        (3,) m: the motion's joint axis in the base frame, whose image under the refined pose (if any, and
        ``CalibratorConfig.predicted_start``) is tried first; when the fit from it is taken, the conics are not
        needed. Without a fit (too few tracks, no shared frames, an unfixed axis) the tracks and the conics'
        geometry stay as they are and ``report.rigid`` says why; when the fit found that the tracks do not turn
        rigidly (from every start, the conics' axis among them) the conics' axis is not used either
        (``CONICS_NOT_RIGID``), and the best such fit is the weak axis when its share of the tracks reaches
        ``OneAxisSearch.weak_share`` (else None).
        """

        def starts() -> list[tuple[FloatArray, FloatArray]]:
            geometry = conics()
            return [] if geometry is None else [(geometry.axis_cam, geometry.reference_cam)]

        predicted = None
        if self.config.predicted_start and self._refined is not None:
            T = self._refined.T_camera_base
            predicted = (T[:3, :3] @ axis_base, T[:3, :3] @ point_base + T[:3, 3])
        try:
            fit = rigid_axis_of_motion(MotionObservation(obs.q_start, obs.joint, tuple(moving)), self.intrinsics,
                                       self.config.rigid_axis, starts, predicted)
        except NonRigidTracksError as exc:  # the conics' axis was one of the starts: it does not explain the tracks
            report.rigid = str(exc)
            if conics() is not None:
                report.conics = CONICS_NOT_RIGID
            search, best = self.config.one_axis, exc.fit
            weak = (geometry_from_rigid_fit(best) if isinstance(best, RigidAxisFit) and search is not None
                    and search.weak_share is not None and best.track_inliers.mean() >= search.weak_share else None)
            return moving, None, weak
        except DegenerateMotionError as exc:
            report.rigid = str(exc)
            return moving, conics(), None
        report.n_inconsistent_tracks = int(np.sum(~fit.track_inliers))
        report.rigid_predicted = fit.from_prediction
        report.front_end = "rigid"
        kept = [t for t, ok in zip(moving, fit.track_inliers, strict=True) if ok]
        return kept, geometry_from_rigid_fit(fit), None

    def _correspondence(self, k: int) -> AxisCorrespondence:
        m = self._motions[k]
        return AxisCorrespondence(m.axis_base, m.point_base, m.geometry.axis_cam,
                                  m.geometry.plane_normal)

    def _update_reports(self, live: list[int], with_axis: list[int], linear: ConsensusResult | None,
                        refined: RefinementResult | None, inlier_tracks: NDArray[np.int64] | None) -> None:
        min_tracks = self.config.motion.min_tracks
        for slot, k in enumerate(live):
            r = self.reports[k]
            i = with_axis.index(k) if linear is not None and k in with_axis else None
            r.linear = i is not None and bool(linear.used[i])
            if i is not None:
                r.eps_a, r.eps_d = float(linear.eps_a[i]), float(linear.eps_d[i])
            if refined is not None:
                r.n_inlier_tracks = int(inlier_tracks[slot])
                r.accepted = r.n_inlier_tracks >= min_tracks
                r.reason = "" if r.accepted else (
                    f"only {r.n_inlier_tracks} of {len(self._motions[k].tracks)} tracks agree with "
                    f"the refined pose (need {min_tracks})")
            elif linear is not None:
                r.accepted = i is not None and bool(linear.inliers[i])
                r.reason = "" if r.accepted else (
                    r.stage_one or f"inconsistent with the estimate: eps_a = {r.eps_a:.3g} rad, "
                    f"eps_d = {r.eps_d:.3g} m (limits {self.config.max_eps_a}, {self.config.max_eps_d})")
            else:
                r.accepted = False
                r.reason = r.stage_one or "waiting: no estimate yet"


def _spread(xy: FloatArray) -> float:
    """The diagonal of the 5-95 % box of points (N, 2) (0.0 for none)."""
    if len(xy) == 0:
        return 0.0
    lo, hi = np.percentile(xy, [5.0, 95.0], axis=0)
    return float(np.linalg.norm(hi - lo))
