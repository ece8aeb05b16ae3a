"""What ``calibrate`` and ``run`` share: the usability check, the per-motion table, the result and its exports."""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from arc_env.robot.exports import (
    DEFAULT_CAMERA_FRAME,
    ParentChild,
    check_frame_name,
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

    An estimate that is not usable is still written to ``result.json`` with ``"usable": false`` and the
    reason, so a user can look, but without ROS exports or overlays; with no estimate at all nothing is
    written. ``args`` carries output, camera_frame, min_motions, max_std_deg, max_std_mm (and
    ground_truth for the message). Returns the exit code: 0 usable (written), 1 not usable.
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
    T_camera_base = s.T_camera_base
    if why and T_camera_base is None:
        print(f"no usable calibration: {why}. Nothing written.")
        return 1
    edge = ParentChild.from_T_camera_base(T_camera_base, base_frame, args.camera_frame)
    if why:
        write_files_atomic({output: json.dumps(result_dict(run, edge, {}, why), indent=2) + "\n"})
        print(f"no usable calibration: {why}. Wrote {output} with \"usable\": false (no ROS exports).")
        if truth is not None:
            rot, trans = pose_errors(T_camera_base, truth)
            print(f"true error: rotation {rot:.2e} rad ({np.degrees(rot):.4f} deg), translation {trans * 1e3:.3f} mm")
        return 1
    exports = export_paths(output)
    result = result_dict(run, edge, exports)
    texts: dict[Path, str | bytes] = dict(zip(exports.values(), export_texts(edge).values(), strict=True))
    texts[output] = json.dumps(result, indent=2) + "\n"
    images = overlays() if overlays is not None else {}
    write_files_atomic({**texts, **images})  # all or nothing

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


#: Overlay images ``calibrate`` writes into ``--overlay DIR`` (a glob pattern).
OVERLAY_PATTERN = "overlay_motion_*.png"


def check_outputs(output: Path, inputs: Sequence[Path], force: bool = False, overlay_dir: Path | None = None,
                  other_outputs: Sequence[Path] = ()) -> None:
    """Refuse, before any work, outputs that would damage the input or an earlier result.

    Args:
        output: the result JSON (its exports sit beside it).
        inputs: what the run reads (a recording directory, a ground-truth file): no output may be one
            of them or inside one.
        force: allow replacing existing output files (never an input, never a directory).
        overlay_dir: ``--overlay DIR``, if given.
        other_outputs: folders the run creates (e.g. ``run --record DIR``): they too must stay out of the
            inputs, and the result and its exports must stay out of them.

    Raises:
        InvalidInputError: an output is not .json, its directory does not exist, it is (or is inside)
            an input, it is an existing directory, or it exists and ``force`` is off.
    """
    output = Path(output)
    if output.suffix != ".json":
        raise InvalidInputError(f"--output must be a .json file, got {output}")
    if not output.parent.is_dir():
        raise InvalidInputError(f"--output: directory {output.parent} does not exist")
    files = [output, *export_paths(output).values()]
    for path in [*files, *([overlay_dir] if overlay_dir is not None else []), *other_outputs]:
        for source in inputs:
            if _within(path, source):
                raise InvalidInputError(f"{path}: is inside the input {Path(source).resolve()}; write outputs "
                                        "elsewhere (ARC-Calib never writes into what it reads)")
        for folder in other_outputs:
            if path in files and _within(path, folder):
                raise InvalidInputError(f"{path}: is inside {folder}, which this run creates; keep the result "
                                        "out of it")
    for path in files:
        if path.is_dir():
            raise InvalidInputError(f"{path}: is a directory; --output names the result file")
        if (path.exists() or path.is_symlink()) and not force:
            raise InvalidInputError(f"{path}: already exists; use --force to replace it")
    if overlay_dir is not None:
        if overlay_dir.exists() and not overlay_dir.is_dir():
            raise InvalidInputError(f"--overlay {overlay_dir}: exists and is not a directory")
        earlier = sorted(overlay_dir.glob(OVERLAY_PATTERN)) if overlay_dir.is_dir() else []
        if earlier and not force:
            raise InvalidInputError(f"--overlay {overlay_dir}: already holds {earlier[0].name} (and "
                                    f"{len(earlier) - 1} more); use --force to replace them")


def _within(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or inside it, symlinks resolved."""
    return Path(path).resolve().is_relative_to(Path(folder).resolve())


def check_frame_names(args: argparse.Namespace) -> None:
    """Validate ``--base-frame`` (if given) and ``--camera-frame`` before any work: they reach the exports."""
    if args.base_frame is not None:
        check_frame_name(args.base_frame, "--base-frame")
    check_frame_name(args.camera_frame, "--camera-frame")


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
    parser.add_argument("--force", action="store_true",
                        help="replace existing output files (never the input; never a directory)")
