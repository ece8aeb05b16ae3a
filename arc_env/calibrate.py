"""``arc-calib calibrate``: a recording in, ``T_camera_base`` with its uncertainty and ROS exports out.

For each motion of the recording (``arc_env.recording``): decode its frames, track keypoints on the moving
links (``arc_env.tracking``), and hand the tracks with the joint offset of every frame to the calibrator
(``solver.Calibrator``: per-motion axis estimation and pruning, linear calibration with RANSAC over
motions, bundle adjustment), which updates its estimate after every motion (the paper's Algorithm 1, so
the convergence monitor sees the sequence of estimates).

A result is *usable* -- written, exit code 0 -- only when all of these hold:

* the bundle adjustment produced it (``stage == "refined"``): a pose and a covariance;
* at least ``min_motions`` motions inform it;
* every 1-sigma rotation component is at most ``max_std_deg`` and every translation one at most
  ``max_std_mm`` (the convergence monitor's thresholds are tighter, so a converged estimate qualifies).

Otherwise nothing is written and the exit code is 1: never a pose from too little evidence.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from arc_env.exports import DEFAULT_CAMERA_FRAME, ParentChild, export_paths, export_texts, write_files_atomic
from arc_env.overlay import RobotProjector, draw_overlay
from arc_env.progress import Progress
from arc_env.recording import Recording, read_recording
from arc_env.tracking import TrackerConfig, track_keypoints
from solver.errors import ArcCalibError, InvalidInputError
from solver.frames import check_transform, pose_errors, quaternion_xyzw_from_matrix
from solver.observations import MotionObservation
from solver.pipeline import CalibrationState, Calibrator, CalibratorConfig, MotionReport

#: Result file format written by ``calibrate``.
RESULT_FORMAT = "arc-calib result 1"


@dataclass(frozen=True)
class UsableCriteria:
    """When a calibration result is usable (see the module docstring).

    Attributes:
        min_motions: fewest motions that must inform the estimate.
        max_std_deg: degrees; largest 1-sigma of each rotation component.
        max_std_mm: mm; largest 1-sigma of each translation component.
    """

    min_motions: int = 4
    max_std_deg: float = 0.25
    max_std_mm: float = 3.0

    def __post_init__(self) -> None:
        if self.min_motions < 3 or not self.max_std_deg > 0 or not self.max_std_mm > 0:
            raise InvalidInputError("need min_motions >= 3, max_std_deg > 0 and max_std_mm > 0")


@dataclass
class MotionDiagnostic:
    """What became of one recorded motion."""

    motion: str
    joint: str | None
    frames: int
    tracks: int = 0
    accepted: bool = False
    reason: str = ""
    inlier_tracks: int = 0
    axis_error_rad: float | None = None
    plane_distance_m: float | None = None
    linear: bool = False
    note: str = ""
    seconds: float = 0.0


@dataclass
class CalibrationRun:
    """A finished calibration: of a recording, or online through a driver.

    Attributes:
        source: what was calibrated (the recording's path, or the driver).
        calibrator: the calibrator after its last update.
        diagnostics: one per motion, in order.
        seconds: wall time per part of the work.
        recording: the recording (None online).
    """

    source: str
    calibrator: Calibrator
    diagnostics: list[MotionDiagnostic]
    seconds: dict[str, float] = field(default_factory=dict)
    recording: Recording | None = None

    @property
    def n_accepted(self) -> int:
        """Motions informing the estimate."""
        return sum(d.accepted for d in self.diagnostics)


def calibrate_recording(recording: Recording, tracker: TrackerConfig | None = None,
                        config: CalibratorConfig | None = None, progress: bool = True) -> CalibrationRun:
    """Track every usable motion and calibrate; motions pruned on the way keep their reasons.

    Raises:
        InvalidInputError: a frame or video does not decode (the message names it).
    """
    tracker = tracker or TrackerConfig()
    calibrator = Calibrator(recording.intrinsics, recording.kinematics, config or CalibratorConfig())
    names = recording.joint_names
    diagnostics: list[MotionDiagnostic] = []
    by_report: dict[int, MotionDiagnostic] = {}
    seconds = {"decode": 0.0, "tracking": 0.0, "solver": 0.0}
    started = time.perf_counter()
    n = len(recording.motions)
    updated = False
    with Progress(max(n, 1), "motions", enabled=progress) as bar:
        for m in recording.motions:
            diag = MotionDiagnostic(m.name, names[m.joint] if m.joint is not None else None, m.n_frames)
            diagnostics.append(diag)
            t0 = time.perf_counter()
            if m.pruned:
                diag.reason = m.pruned
            else:
                frames = recording.frames(m)
                t1 = time.perf_counter()
                result = track_keypoints(frames, m.delta, tracker)
                del frames
                t2 = time.perf_counter()
                diag.tracks = len(result.tracks)
                if not result.tracks:
                    diag.reason = "no keypoint tracks: nothing moved in the images (is the robot in view?)"
                else:
                    try:  # checked here: a motion the kinematics reject must not reach the calibrator
                        recording.kinematics(m.q_start, m.joint)
                    except ArcCalibError as exc:
                        diag.reason = f"the robot model rejects this motion: {exc}"
                    else:
                        obs = MotionObservation(q_start=m.q_start, joint=m.joint, tracks=tuple(result.tracks))
                        update = len(calibrator.reports) >= 2  # Algorithm 1: update once 3 motions are in
                        report = calibrator.add_motion(obs, update=update)
                        by_report[report.index] = diag
                        updated = update
                seconds["decode"] += t1 - t0
                seconds["tracking"] += t2 - t1
                seconds["solver"] += time.perf_counter() - t2
            diag.seconds = time.perf_counter() - t0
            what = diag.reason[:60] if diag.reason and not diag.tracks else f"{diag.tracks} tracks"
            bar.step(f"motion {m.name} joint {diag.joint or '-'}: {m.n_frames} frames, {what}; "
                     f"{estimate_status(calibrator.state)}")
    if calibrator.reports and not updated:  # the last motion added did not update (or failed)
        t0 = time.perf_counter()
        calibrator.update()
        seconds["solver"] += time.perf_counter() - t0
    for r in calibrator.reports:
        copy_report(r, by_report[r.index])
    seconds["total"] = time.perf_counter() - started
    return CalibrationRun(str(recording.path), calibrator, diagnostics, seconds, recording)


def estimate_status(state: CalibrationState) -> str:
    """The estimate in a few words for progress lines: ``refined estimate, 7 accepted`` or ``no estimate yet``."""
    if state.T_camera_base is None:
        return "no estimate yet"
    return f"{state.stage} estimate, {state.n_accepted} accepted"


def copy_report(report: MotionReport, diag: MotionDiagnostic) -> None:
    """Fill a diagnostic from the calibrator's final report on that motion."""
    diag.accepted, diag.inlier_tracks, diag.linear = report.accepted, report.n_inlier_tracks, report.linear
    diag.reason = report.reason
    diag.axis_error_rad, diag.plane_distance_m = report.eps_a, report.eps_d
    diag.note = f"no axis for the linear stage: {report.stage_one}" if report.stage_one and report.accepted else ""


def unusable_reason(run: CalibrationRun, criteria: UsableCriteria) -> str:
    """"" when the result is usable, else why not."""
    s = run.calibrator.state
    if not run.calibrator.reports:
        return (f"none of the {len(run.diagnostics)} motions gave keypoint tracks (pruned, or nothing moved "
                "in the images: is the robot in view?)")
    if s.T_camera_base is None:
        return f"no estimate: {s.message}"
    if s.stage != "refined" or s.std is None:
        return f"only a {s.stage} estimate (the bundle adjustment gave none: {s.message or 'see motions'})"
    if run.n_accepted < criteria.min_motions:
        return f"only {run.n_accepted} motion(s) inform the estimate (need {criteria.min_motions})"
    std_deg, std_mm = np.degrees(s.std[:3]), s.std[3:] * 1e3
    if np.any(std_deg > criteria.max_std_deg) or np.any(std_mm > criteria.max_std_mm):
        return (f"the estimate is too uncertain: 1-sigma rotation {np.round(std_deg, 3).tolist()} deg "
                f"(limit {criteria.max_std_deg}), translation {np.round(std_mm, 2).tolist()} mm "
                f"(limit {criteria.max_std_mm}); record more motions")
    return ""


def result_dict(run: CalibrationRun, edge: ParentChild, exports: dict[str, Path]) -> dict[str, Any]:
    """The result JSON (see docs/recording-format.md, "Calibration result")."""
    s = run.calibrator.state
    T = s.T_camera_base
    return {
        "format": RESULT_FORMAT,
        "source": run.source,
        "convention": ("p_camera = T_camera_base @ p_base; camera frame = OpenCV optical frame (x right, y down, "
                       "z forward); metres, radians; quaternions (x, y, z, w)"),
        "T_camera_base": T.tolist(),
        "translation": T[:3, 3].tolist(),
        "quaternion": quaternion_xyzw_from_matrix(T[:3, :3]).tolist(),
        "T_base_camera": edge.T_base_camera.tolist(),
        "covariance": s.covariance.tolist(),
        "covariance_parameters": ("xi = (omega rad, tau m), camera frame: R = Exp(omega) R_hat, t = t_hat + tau "
                                  "(T_camera_base)"),
        "std": {"rotation_deg": np.degrees(s.std[:3]).tolist(), "translation_mm": (s.std[3:] * 1e3).tolist()},
        "rms_reprojection_px": s.rms_px,
        "stage": s.stage,
        "converged": s.converged,
        "frames": {"parent": edge.base_frame, "child": edge.camera_frame,
                   "child_is": "the camera's OpenCV optical frame (REP 103 *_optical_frame), not camera_link"},
        "motions": {"total": len(run.diagnostics), "accepted": run.n_accepted,
                    "rejected": len(run.diagnostics) - run.n_accepted},
        "per_motion": [
            {"motion": d.motion, "joint": d.joint, "frames": d.frames, "tracks": d.tracks, "accepted": d.accepted,
             "reason": d.reason, "inlier_tracks": d.inlier_tracks, "linear_stage": d.linear,
             "axis_error_rad": d.axis_error_rad, "plane_distance_m": d.plane_distance_m, "note": d.note}
            for d in run.diagnostics],
        "exports": {k: p.name for k, p in exports.items()},
        "seconds": {k: round(v, 2) for k, v in run.seconds.items()},
    }


def render_overlays(run: CalibrationRun, out_dir: Path, n_motions: int = 4) -> dict[Path, bytes]:
    """PNGs of the robot drawn with the estimate over the middle frame of up to ``n_motions`` accepted motions.

    Returns:
        {path in out_dir: PNG bytes}; nothing is written here.
    """
    rec = run.recording
    assert rec is not None
    T = run.calibrator.state.T_camera_base
    projector = RobotProjector(rec.scene, rec.intrinsics)
    accepted = [m for m, d in zip(rec.motions, run.diagnostics, strict=True) if d.accepted]
    pick = [accepted[k] for k in np.unique(np.linspace(0, len(accepted) - 1, min(n_motions, len(accepted)))
                                           .round().astype(int))] if accepted else []
    files: dict[Path, bytes] = {}
    for m in pick:
        k = m.n_frames // 2
        frame = rec.frames(m)[k]
        q = m.q_start.copy()
        q[m.joint] += m.delta[k]
        mask = projector.mask(q, T)
        image = draw_overlay(frame, mask, f"motion {m.name}, frame {k}: robot model drawn with the estimate")
        ok, png = cv2.imencode(".png", image)
        if not ok:
            raise OSError(f"OpenCV could not encode the overlay of motion {m.name}")
        files[out_dir / f"overlay_motion_{m.name}.png"] = png.tobytes()
    return files


def _read_ground_truth(path: Path) -> np.ndarray:
    try:
        data = json.loads(Path(path).read_text())
        return check_transform(np.asarray(data["T_camera_base"], dtype=np.float64), f"{path}: T_camera_base")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InvalidInputError(f"{path}: not a ground-truth file with a T_camera_base: {exc}") from exc


def run_calibrate(args: argparse.Namespace) -> int:
    """``arc-calib calibrate`` from parsed arguments; returns the exit code (0 only for a usable result)."""
    UsableCriteria(min_motions=args.min_motions, max_std_deg=args.max_std_deg, max_std_mm=args.max_std_mm)
    check_output(Path(args.output))
    truth = _read_ground_truth(Path(args.ground_truth)) if args.ground_truth else None
    started = time.perf_counter()
    recording = read_recording(args.recording)
    usable = recording.usable
    print(f"{recording.path}: {len(recording.motions)} motions ({len(usable)} with one moving joint), camera "
          f"{recording.intrinsics.width}x{recording.intrinsics.height}"
          f"{' with distortion' if recording.intrinsics.dist.size and np.any(recording.intrinsics.dist) else ''}, "
          f"robot {recording.model_path.name} (base {recording.base_body}, {len(recording.joint_names)} joints)",
          file=sys.stderr)
    if recording.ignored_joints:
        print(f"note: joints.csv columns ignored (not hinge joints of the arm): {list(recording.ignored_joints)}",
              file=sys.stderr)
    run = calibrate_recording(recording, progress=not args.quiet)
    overlays = (lambda: render_overlays(run, Path(args.overlay))) if args.overlay else None
    return finish(run, args, args.base_frame or recording.base_body, overlays, truth, started)


def finish(run: CalibrationRun, args: argparse.Namespace, base_frame: str,
           overlays: Callable[[], dict[Path, bytes]] | None, truth: np.ndarray | None, started: float) -> int:
    """Print the per-motion table; if the result is usable, write it with its exports and print it.

    ``args`` carries output, camera_frame, min_motions, max_std_deg, max_std_mm (and ground_truth for
    the message). Returns the exit code: 0 written, 1 not usable (nothing written).
    """
    criteria = UsableCriteria(min_motions=args.min_motions, max_std_deg=args.max_std_deg, max_std_mm=args.max_std_mm)
    output = Path(args.output)
    s = run.calibrator.state
    print(f"{'motion':>6} {'joint':>22} {'frames':>6} {'tracks':>6} {'status':>9}  reason / note")
    for d in run.diagnostics:
        status = "accepted" if d.accepted else "rejected"
        print(f"{d.motion:>6} {(d.joint or '-')[-22:]:>22} {d.frames:>6} {d.tracks:>6} {status:>9}  "
              f"{(d.reason or d.note)[:90]}")
    parts = ", ".join(f"{k} {v:.1f}" for k, v in run.seconds.items() if k != "total")
    print(f"motions: {len(run.diagnostics)}, accepted {run.n_accepted}, rejected "
          f"{len(run.diagnostics) - run.n_accepted}; {run.seconds.get('total', 0.0):.1f} s ({parts})")
    why = unusable_reason(run, criteria)
    if why:
        print(f"no usable calibration: {why}. Nothing written.")
        return 1
    T = s.T_camera_base
    edge = ParentChild.from_T_camera_base(T, base_frame, args.camera_frame)
    exports = export_paths(output)
    result = result_dict(run, edge, exports)
    texts: dict[Path, str | bytes] = dict(zip(exports.values(), export_texts(edge).values(), strict=True))
    texts[output] = json.dumps(result, indent=2) + "\n"
    images = overlays() if overlays is not None else {}
    if images:
        next(iter(images)).parent.mkdir(parents=True, exist_ok=True)
    write_files_atomic({**texts, **images})

    np.set_printoptions(precision=6, suppress=True)
    print(f"T_camera_base ({s.stage}; p_camera = T_camera_base @ p_base, OpenCV optical frame):")
    print(T)
    print(f"translation (m): {T[:3, 3]}  quaternion (x, y, z, w): {quaternion_xyzw_from_matrix(T[:3, :3])}")
    print(f"1-sigma: rotation {np.degrees(s.std[:3])} deg, translation {s.std[3:] * 1e3} mm; RMS reprojection "
          f"{s.rms_px:.3f} px; converged: {s.converged}")
    if truth is not None:
        rot, trans = pose_errors(T, truth)
        print(f"true error: rotation {rot:.2e} rad ({np.degrees(rot):.4f} deg), translation {trans * 1e3:.3f} mm")
    print(f"wrote {output}")
    for key, path in exports.items():
        print(f"wrote {path} ({key})")
    for path in images:
        print(f"wrote {path} (overlay)")
    print(f"TF (parent {edge.base_frame} -> child {edge.camera_frame}, the OpenCV optical frame; "
          f"T_base_camera = inv(T_camera_base)):")
    print(f"  {export_texts(edge)['static_transform_publisher'].splitlines()[-1]}")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


def check_output(output: Path) -> None:
    """Refuse an output path that cannot be written (before any work is done)."""
    if output.suffix != ".json":
        raise InvalidInputError(f"--output must be a .json file, got {output}")
    if not output.parent.is_dir():
        raise InvalidInputError(f"--output: directory {output.parent} does not exist")


def add_result_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``calibrate`` and ``run``: output, frames, usability."""
    parser.add_argument("--output", "-o", required=True, help="result JSON; exports are written beside it")
    parser.add_argument("--base-frame", help="TF name of the robot base (default: the model's base body)")
    parser.add_argument("--camera-frame", default=DEFAULT_CAMERA_FRAME,
                        help=f"TF name of the camera's OpenCV optical frame (default {DEFAULT_CAMERA_FRAME})")
    parser.add_argument("--min-motions", type=int, default=UsableCriteria.min_motions,
                        help=f"fewest accepted motions for a usable result (default {UsableCriteria.min_motions})")
    parser.add_argument("--max-std-deg", type=float, default=UsableCriteria.max_std_deg,
                        help=f"largest 1-sigma rotation per axis, deg (default {UsableCriteria.max_std_deg})")
    parser.add_argument("--max-std-mm", type=float, default=UsableCriteria.max_std_mm,
                        help=f"largest 1-sigma translation per axis, mm (default {UsableCriteria.max_std_mm})")
    parser.add_argument("--quiet", "-q", action="store_true", help="no per-motion progress on stderr")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``arc-calib calibrate`` options."""
    parser.add_argument("recording", help="the recording directory (docs/recording-format.md)")
    add_result_arguments(parser)
    parser.add_argument("--overlay", metavar="DIR", help="write PNGs of the robot drawn with the estimate here")
    parser.add_argument("--ground-truth", metavar="FILE",
                        help="a <recording>.ground_truth.json (simulated recordings): also print the true error")
