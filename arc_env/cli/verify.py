"""``arc-calib verify result.json RECORDING_OR_BAG``: is a calibration still consistent with a fresh recording?

The pose from ``result.json`` is held fixed; the recording (a directory or a ROS bag, read exactly as
``calibrate`` reads it: ``arc_env.cli.calibrate.read_input``) is tracked motion by motion and checked
(``arc_env.robot.verify``): reprojection residuals with only the tracks' points fitted, and the IoU of
the robot model's outline against the motion the frames show. No simulator is involved.

Exit codes: 0 consistent, 1 inconsistent, 2 bad input (a missing or malformed file, a recording of
another robot, no usable motion or too few tracks to judge). ``--json`` prints the report as JSON on
stdout (keys in docs/verify.md); otherwise a table and the verdict.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from arc_env.cli.calibrate import add_input_arguments, read_input
from arc_env.cli.export import read_result
from arc_env.cli.progress import Progress
from arc_env.robot.recording import Recording
from arc_env.robot.verify import CONSISTENT, VerifyCriteria, VerifyReport, check_same_robot, verify_recording
from solver.errors import InvalidInputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``arc-calib verify`` options."""
    parser.add_argument("result", help="a result.json written by 'arc-calib calibrate' or 'arc-calib run'")
    parser.add_argument("recording", help="a fresh recording directory or ROS bag (as 'arc-calib calibrate' takes)")
    parser.add_argument("--max-residual-px", type=float, default=VerifyCriteria.max_residual_px, metavar="PX",
                        help="consistent only if the best-fitting quarter of the tracks fit within this, px "
                             f"(default {VerifyCriteria.max_residual_px})")
    parser.add_argument("--min-mask-iou", type=float, default=VerifyCriteria.min_mask_iou, metavar="IOU",
                        help="consistent only if the median model-outline IoU is at least this (default "
                             f"{VerifyCriteria.min_mask_iou})")
    parser.add_argument("--json", action="store_true", help="print the report as JSON on stdout (docs/verify.md)")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress (nor a bag's motions) on stderr")
    add_input_arguments(parser, "default: the result's time_offset_s")
    parser.set_defaults(time_offset=None)


def _result_joints(path: Path, data: dict) -> list[str]:
    rows = data.get("per_motion")
    if not isinstance(rows, list):
        return []
    return [r["joint"] for r in rows if isinstance(r, dict) and isinstance(r.get("joint"), str)]


def _read_recording(args: argparse.Namespace, result_offset_s: float) -> Recording:
    """The recording, its joints read at ``--time-offset`` or else, when it is timed, at the result's offset."""
    if args.time_offset is not None:
        return read_input(args, quiet=args.json or args.quiet)
    recording = read_input(argparse.Namespace(**{**vars(args), "time_offset": 0.0}), quiet=args.json or args.quiet)
    timed = any(m.times is not None for m in recording.motions)
    if not timed or result_offset_s == 0.0:
        return recording
    return read_input(argparse.Namespace(**{**vars(args), "time_offset": result_offset_s}), quiet=True)


def print_report(report: VerifyReport, result: Path, recording: Recording) -> None:
    """The per-motion table and the verdict, on stdout."""
    c = report.criteria
    q = f"p{c.residual_quantile * 100:.0f} px"
    print(f"{recording.path} against {result} (pose fixed; joints read at a time offset of "
          f"{report.time_offset_s * 1e3:+.2f} ms)")
    print(f"{'motion':>6} {'joint':>22} {'frames':>6} {'tracks':>6} {q:>7} {'median px':>9} {'rms px':>8} {'IoU':>5}"
          "  note")

    def cell(x: float | None, width: int, digits: int = 3) -> str:
        return f"{x:>{width}.{digits}f}" if x is not None else f"{'-':>{width}}"

    for m in report.motions:
        print(f"{m.motion:>6} {(m.joint or '-')[-22:]:>22} {m.frames:>6} {m.tracks:>6} "
              f"{cell(m.quantile_px(c.residual_quantile), 7)} {cell(m.median_px, 9)} {cell(m.rms_px, 8)} "
              f"{cell(m.mask_iou, 5, 2)}  {m.note[:80]}")
    iou = f"{report.mask_iou:.3f}" if report.mask_iou is not None else "-"
    print(f"residual over {report.track_rms_px.size} tracks: {c.residual_quantile:.0%} of them within "
          f"{report.judged_px:.3f} px (threshold {c.max_residual_px:g} px), median {report.median_px:.3f} px, RMS "
          f"{report.rms_px:.3f} px; mask IoU: median {iou} over motions (threshold {c.min_mask_iou:g})")
    if report.verdict == CONSISTENT:
        print("verdict: consistent: the calibration explains this recording")
    else:
        print(f"verdict: inconsistent: {'; '.join(report.reasons)}. Has the camera moved? Calibrate again")


def run_verify(args: argparse.Namespace) -> int:
    """``arc-calib verify`` from parsed arguments; returns the exit code (0 consistent, 1 inconsistent)."""
    criteria = VerifyCriteria(max_residual_px=args.max_residual_px, min_mask_iou=args.min_mask_iou)
    path = Path(args.result)
    data = read_result(path)
    recording_path = Path(args.recording)
    if not recording_path.exists():
        raise InvalidInputError(f"{recording_path}: no such recording or bag")
    offset = data.get("time_offset_s")
    result_offset = float(offset) if isinstance(offset, int | float) else 0.0
    recording = _read_recording(args, result_offset)
    check_same_robot(_result_joints(path, data), recording, str(path))
    with Progress(max(len(recording.motions), 1), "motions", enabled=not args.quiet) as bar:
        report = verify_recording(recording, data["T_camera_base"], criteria, on_motion=bar.step)
    if args.json:
        print(json.dumps({"result": str(path), "recording": str(recording.path), **report.as_dict()}, indent=2))
    else:
        print_report(report, path, recording)
    sys.stdout.flush()
    return 0 if report.verdict == CONSISTENT else 1


__all__ = ["add_arguments", "print_report", "run_verify"]
