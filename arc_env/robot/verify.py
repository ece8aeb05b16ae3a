"""Check a calibration against a fresh recording: does ``T_camera_base`` still explain what the camera sees?

The check a user runs after someone bumps the camera (``arc-calib verify``). The pose is held fixed; every
usable motion of the recording is tracked exactly as ``calibrate`` tracks it
(``arc_env.robot.session.track_recorded``), and two things are measured per motion:

* **Reprojection residuals.** Each track's point is triangulated at the fixed pose and fitted alone
  (``solver.fixed_pose.fit_points``: the bundle adjustment with the pose held, points only); what is left
  is each track's RMS error per coordinate, px. A track on the moving link fits to its noise at the right
  pose; at a wrong one the predicted arcs bend away from the observed ones. Tracks that slide or sit on
  the background fit badly at any pose, so the figure judged is a robust one: the *median* over every
  track of the recording.
* **Mask IoU.** The moving links' outline, projected from the robot model at every frame's joint
  positions through the fixed pose (``arc_env.robot.overlay.RobotProjector``, no rendering) and united
  over the sweep, against the pixels the frames themselves show changing (``arc_env.robot.tracking.
  moving_mask``, the tracker's own segmentation); the model's union is dilated like the segmentation.
  Coarse (shadows and uniform surfaces keep it well below 1 at the right pose), but it does not depend on
  tracking and sees a camera that moved a lot.

Verdict (``VerifyCriteria``): *consistent* when the median residual is at most ``max_residual_px`` and the
median IoU over motions at least ``min_mask_iou``; otherwise *inconsistent*, with the reasons. The
thresholds were measured (README, "Checking a calibration"): simulated recordings verified against their
true pose, against poses moved by 5 mm / 5 mrad and by 2 cm / 20 mrad.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from arc_env.robot.overlay import RobotProjector, mask_iou
from arc_env.robot.recording import RecordedMotion, Recording
from arc_env.robot.session import CalibrationSession, SessionConfig, track_recorded
from arc_env.robot.tracking import TrackerConfig, moving_mask
from solver.arrays import FloatArray, MaskArray, evenly_spaced
from solver.camera import normalized_from_pixels
from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.fixed_pose import fit_points
from solver.frames import check_transform
from solver.observations import KeypointTrack
from solver.refinement import RefinementConfig, build_track_set

#: Verdicts.
CONSISTENT, INCONSISTENT = "consistent", "inconsistent"
#: The model masks united for the IoU: evenly spaced frames (first and last included), one per this turn of
#: the joint, rad (a point 0.8 m from the axis moves 4.8 cm between two), ...
MASK_STEP_RAD = 0.06
#: ... and at most this many per sweep.
MASK_FRAMES = 24


@dataclass(frozen=True)
class VerifyCriteria:
    """When a recording is consistent with a calibration.

    Attributes:
        max_residual_px: px; the ``residual_quantile`` quantile over all tracks of each track's RMS residual
            (per coordinate) at the fixed pose must be at most this.
        residual_quantile: which quantile of the tracks' residuals is judged, in (0, 1]. Not the median:
            on realistic images most tracks slide or sit on edges and fit badly at any pose, so the median
            measures the tracker; the best-fitting quarter measures the pose.
        min_mask_iou: the median over motions of the model-outline IoU must be at least this; in [0, 1].
        min_tracks: fewest tracks (over all motions) needed to judge at all; count.
    """

    max_residual_px: float = 0.5
    residual_quantile: float = 0.25
    min_mask_iou: float = 0.6
    min_tracks: int = 10

    def __post_init__(self) -> None:
        if not self.max_residual_px > 0:
            raise InvalidInputError(f"max_residual_px must be > 0, got {self.max_residual_px}")
        if not 0 < self.residual_quantile <= 1:
            raise InvalidInputError(f"residual_quantile must be in (0, 1], got {self.residual_quantile}")
        if not 0 <= self.min_mask_iou <= 1:
            raise InvalidInputError(f"min_mask_iou must be in [0, 1], got {self.min_mask_iou}")
        if self.min_tracks < 1:
            raise InvalidInputError(f"min_tracks must be >= 1, got {self.min_tracks}")


@dataclass
class MotionCheck:
    """What one motion says about the pose.

    Attributes:
        motion: the motion's name.
        joint: the joint that turned (None when pruned).
        frames: its frame count.
        tracks: tracks fitted at the fixed pose.
        track_rms_px: (tracks,) float64, px: each fitted track's RMS residual per coordinate.
        residual_sq_sum: px^2: summed squared residuals of its observations; ``observations``: their count.
        mask_iou: IoU of the model's swept outline and the segmentation (None: not measured).
        note: "" or why the motion gave no figure (pruned, no tracks).
    """

    motion: str
    joint: str | None
    frames: int
    tracks: int = 0
    track_rms_px: FloatArray = field(default_factory=lambda: np.zeros(0))
    residual_sq_sum: float = 0.0
    observations: int = 0
    mask_iou: float | None = None
    note: str = ""

    @property
    def median_px(self) -> float | None:
        """Median of the tracks' RMS residuals, px (None without tracks)."""
        return float(np.median(self.track_rms_px)) if self.track_rms_px.size else None

    @property
    def rms_px(self) -> float | None:
        """RMS residual per coordinate over all observations, px (None without tracks)."""
        return float(np.sqrt(self.residual_sq_sum / (2 * self.observations))) if self.observations else None

    def quantile_px(self, q: float) -> float | None:
        """The q-quantile (0..1) of the tracks' RMS residuals, px (None without tracks)."""
        return float(np.quantile(self.track_rms_px, q)) if self.track_rms_px.size else None


@dataclass
class VerifyReport:
    """The check of one recording against one pose (``verify_recording``)."""

    T_camera_base: FloatArray
    criteria: VerifyCriteria
    motions: list[MotionCheck]
    time_offset_s: float = 0.0

    @property
    def track_rms_px(self) -> FloatArray:
        """Every fitted track's RMS residual, px."""
        return np.concatenate([m.track_rms_px for m in self.motions]) if self.motions else np.zeros(0)

    @property
    def median_px(self) -> float | None:
        """Median over all tracks of their RMS residuals, px."""
        rms = self.track_rms_px
        return float(np.median(rms)) if rms.size else None

    def quantile_px(self, q: float) -> float | None:
        """The q-quantile (0..1) over all tracks of their RMS residuals, px (None without tracks)."""
        rms = self.track_rms_px
        return float(np.quantile(rms, q)) if rms.size else None

    @property
    def judged_px(self) -> float | None:
        """The residual the verdict reads: the ``criteria.residual_quantile`` quantile of the tracks' RMS, px."""
        return self.quantile_px(self.criteria.residual_quantile)

    @property
    def rms_px(self) -> float | None:
        """RMS residual per coordinate over all observations, px (outlier tracks included)."""
        n = sum(m.observations for m in self.motions)
        return float(np.sqrt(sum(m.residual_sq_sum for m in self.motions) / (2 * n))) if n else None

    @property
    def mask_iou(self) -> float | None:
        """Median over motions of the outline IoU (what the verdict reads)."""
        ious = [m.mask_iou for m in self.motions if m.mask_iou is not None]
        return float(np.median(ious)) if ious else None

    @property
    def reasons(self) -> list[str]:
        """Why the recording is inconsistent with the pose (empty: consistent)."""
        c, why = self.criteria, []
        judged, iou = self.judged_px, self.mask_iou
        if judged is not None and judged > c.max_residual_px:
            why.append(f"reprojection residual {judged:.3f} px (the best-fitting {c.residual_quantile:.0%} of tracks "
                       f"fit within it) > {c.max_residual_px:g} px")
        if iou is not None and iou < c.min_mask_iou:
            why.append(f"median mask IoU {iou:.3f} < {c.min_mask_iou:g}")
        return why

    @property
    def verdict(self) -> str:
        """``CONSISTENT`` or ``INCONSISTENT``."""
        return INCONSISTENT if self.reasons else CONSISTENT

    def as_dict(self) -> dict[str, Any]:
        """The JSON report (docs/verify.md lists its keys)."""
        def rounded(x: float | None, digits: int = 4) -> float | None:
            return None if x is None else round(float(x), digits)

        return {
            "verdict": self.verdict,
            "reasons": self.reasons,
            "threshold_px": self.criteria.max_residual_px,
            "residual_px": {
                "judged": rounded(self.judged_px), "quantile": self.criteria.residual_quantile,
                "median": rounded(self.median_px), "rms": rounded(self.rms_px), "tracks": int(self.track_rms_px.size),
                "per_motion": [{"motion": m.motion, "joint": m.joint, "tracks": m.tracks,
                                "judged": rounded(m.quantile_px(self.criteria.residual_quantile)),
                                "median": rounded(m.median_px), "rms": rounded(m.rms_px)} for m in self.motions],
            },
            "mask_iou": {
                "median": rounded(self.mask_iou), "threshold": self.criteria.min_mask_iou,
                "per_motion": [{"motion": m.motion, "iou": rounded(m.mask_iou)} for m in self.motions],
            },
            "motions": [{"motion": m.motion, "joint": m.joint, "frames": m.frames, "note": m.note}
                        for m in self.motions],
            "T_camera_base": np.asarray(self.T_camera_base).tolist(),
            "time_offset_s": self.time_offset_s,
        }


def swept_model_mask(projector: RobotProjector, motion: RecordedMotion, T_camera_base: FloatArray,
                     tracker: TrackerConfig) -> MaskArray:
    """The moving links' pixels at the fixed pose, united over the sweep and dilated like ``moving_mask``: (H, W) bool.

    Args:
        projector: the recording's robot and camera.
        motion: a usable motion (its Q, joint and per-frame turn).
        T_camera_base: (4, 4) float64, metres: the pose to project with.
        tracker: the segmentation's settings (its dilation is applied here too).
    """
    assert motion.joint is not None
    robot = projector.robot
    bodies = set(robot.moving_bodies(motion.joint))
    union = np.zeros((projector.intrinsics.height, projector.intrinsics.width), bool)
    n = int(np.clip(np.ceil(np.ptp(motion.delta) / MASK_STEP_RAD) + 1, 2, MASK_FRAMES))
    for k in evenly_spaced(motion.n_frames, n):
        q = motion.q_start.copy()
        q[motion.joint] += motion.delta[k]
        union |= projector.mask(q, T_camera_base, bodies, fast=True)
    if tracker.mask_dilate_px > 1:
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (tracker.mask_dilate_px, tracker.mask_dilate_px))
        union = cv2.dilate(union.astype(np.uint8), kernel) > 0
    return union


@dataclass(frozen=True)
class TrackedMotion:
    """What the frames of one motion show, whatever the pose: its tracks and its segmentation.

    Attributes:
        motion: the recorded motion.
        tracks: its keypoint tracks (``track_recorded``, as ``calibrate`` tracks).
        segmentation: (H, W) bool, the pixels that change during the sweep (``moving_mask``); None when pruned.
    """

    motion: RecordedMotion
    tracks: tuple[KeypointTrack, ...] = ()
    segmentation: MaskArray | None = None


def track_motion(recording: Recording, session: CalibrationSession, motion: RecordedMotion) -> TrackedMotion:
    """Decode and track one motion (nothing for a pruned one)."""
    if motion.pruned:
        return TrackedMotion(motion)
    frames = recording.frames(motion)
    tracks = track_recorded(session, frames, motion)
    return TrackedMotion(motion, tuple(tracks), moving_mask(frames, session.config.tracker))


def check_motion(recording: Recording, projector: RobotProjector, tracked: TrackedMotion,
                 T_camera_base: FloatArray, tracker: TrackerConfig) -> MotionCheck:
    """One tracked motion's residuals and outline IoU at the fixed pose T_camera_base (4, 4, metres)."""
    motion = tracked.motion
    names = recording.joint_names
    check = MotionCheck(motion.name, names[motion.joint] if motion.joint is not None else None, motion.n_frames)
    if motion.pruned:
        check.note = motion.pruned
        return check
    assert motion.joint is not None and tracked.segmentation is not None
    if tracked.segmentation.any():
        check.mask_iou = mask_iou(swept_model_mask(projector, motion, T_camera_base, tracker), tracked.segmentation)
    if not tracked.tracks:
        check.note = "no keypoint tracks: nothing moved in the images (is the robot in view?)"
        return check
    axis, point = recording.kinematics(motion.q_start, motion.joint)
    intrinsics = recording.intrinsics
    observed = [(normalized_from_pixels(t.pixels, intrinsics), t.delta) for t in tracked.tracks]
    try:
        track_set = build_track_set([(axis, point, observed)], intrinsics.focal, RefinementConfig().min_track_frames)
    except InsufficientMotionsError:
        check.note = "no track long enough to fit"
        return check
    fit = fit_points(track_set, T_camera_base)
    rms = fit.track_rms_px[fit.ok]
    check.tracks = int(rms.size)
    check.track_rms_px = rms
    kept = fit.ok[track_set.track]
    check.residual_sq_sum = float(np.sum(fit.residuals[kept] ** 2))
    check.observations = int(kept.sum())
    if not rms.size:
        check.note = "no track could be triangulated in front of the camera at this pose"
    return check


def check_same_robot(result_joints: Sequence[str], recording: Recording, result_name: str) -> None:
    """Refuse a recording of another robot than the result's (the joints its motions turned).

    Raises:
        InvalidInputError: a joint the result's motions name is not a joint of the recording's robot.
    """
    foreign = sorted({j for j in result_joints if j not in recording.joint_names})
    if foreign:
        raise InvalidInputError(f"{result_name} was calibrated on a robot with joint(s) {foreign}, which "
                                f"{recording.model_path.name} (the recording's robot) does not have; its joints: "
                                f"{list(recording.joint_names)}. Verify with a recording of the same robot")


def track_recording(recording: Recording, tracker: TrackerConfig | None = None,
                    on_motion: Callable[[str], None] | None = None) -> list[TrackedMotion]:
    """Track every motion of ``recording`` (pruned ones stay, empty), as ``calibrate`` tracks them.

    Raises:
        InvalidInputError: a frame does not decode.
    """
    session = CalibrationSession(recording.robot, recording.intrinsics,
                                 config=SessionConfig(tracker=tracker or TrackerConfig()))
    tracked = []
    for m in recording.motions:
        tracked.append(track_motion(recording, session, m))
        if on_motion is not None:
            on_motion(f"motion {m.name}: {m.pruned[:60] if m.pruned else f'{len(tracked[-1].tracks)} tracks'}")
    return tracked


def check_tracked(recording: Recording, tracked: Sequence[TrackedMotion], T_camera_base: FloatArray,
                  criteria: VerifyCriteria | None = None, tracker: TrackerConfig | None = None) -> VerifyReport:
    """Check the tracked motions of ``recording`` against the fixed pose ``T_camera_base`` (4, 4, metres).

    ``tracker``: the settings the motions were tracked with (the model mask is dilated like their
    segmentation).

    Raises:
        InvalidInputError: the pose is not a rigid transform, or the recording gives fewer than
            ``criteria.min_tracks`` tracks (nothing to judge by: is the robot in view?).
    """
    criteria = criteria or VerifyCriteria()
    tracker = tracker or TrackerConfig()
    T_camera_base = check_transform(np.asarray(T_camera_base, dtype=np.float64), "T_camera_base")
    projector = RobotProjector(recording.robot, recording.intrinsics)
    checks = [check_motion(recording, projector, t, T_camera_base, tracker) for t in tracked]
    report = VerifyReport(T_camera_base, criteria, checks, recording.time_offset_s)
    n = int(report.track_rms_px.size)
    if n < criteria.min_tracks:
        notes = "; ".join(f"motion {c.motion}: {c.note}" for c in checks if c.note)
        raise InvalidInputError(f"{recording.path}: only {n} keypoint track(s) in {len(recording.usable)} usable "
                                f"motion(s) (need {criteria.min_tracks} to judge; is the robot in view?)"
                                + (f"; {notes}" if notes else ""))
    return report


def verify_recording(recording: Recording, T_camera_base: FloatArray, criteria: VerifyCriteria | None = None,
                     tracker: TrackerConfig | None = None,
                     on_motion: Callable[[str], None] | None = None) -> VerifyReport:
    """Track ``recording`` and check it against the fixed pose (``track_recording``, then ``check_tracked``)."""
    T_camera_base = check_transform(np.asarray(T_camera_base, dtype=np.float64), "T_camera_base")
    return check_tracked(recording, track_recording(recording, tracker, on_motion), T_camera_base, criteria, tracker)


__all__ = ["CONSISTENT", "INCONSISTENT", "MASK_FRAMES", "MASK_STEP_RAD", "MotionCheck", "TrackedMotion",
           "VerifyCriteria", "VerifyReport", "check_motion", "check_same_robot", "check_tracked", "swept_model_mask",
           "track_motion", "track_recording", "verify_recording"]
