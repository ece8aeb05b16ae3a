"""What ``calibrate`` and ``run`` share: the usability check, the per-motion table, the result and its exports."""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from arc_env.robot.exports import (
    DEFAULT_CAMERA_FRAME,
    ParentChild,
    export_paths,
    export_texts,
    result_dict,
    write_files_atomic,
)
from arc_env.robot.session import CalibrationRun, UsableCriteria, unusable_reason
from solver.errors import InvalidInputError
from solver.frames import pose_errors, quaternion_xyzw_from_matrix


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
    T_camera_base = s.T_camera_base
    edge = ParentChild.from_T_camera_base(T_camera_base, base_frame, args.camera_frame)
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
    print(T_camera_base)
    print(f"translation (m): {T_camera_base[:3, 3]}  quaternion (x, y, z, w): "
          f"{quaternion_xyzw_from_matrix(T_camera_base[:3, :3])}")
    print(f"1-sigma: rotation {np.degrees(s.std[:3])} deg, translation {s.std[3:] * 1e3} mm; RMS reprojection "
          f"{s.rms_px:.3f} px; converged: {s.converged}")
    if truth is not None:
        rot, trans = pose_errors(T_camera_base, truth)
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
