"""``arc-calib export result.json``: rewrite every ROS export of an existing result, without recalibrating.

The pose comes from the result's ``T_camera_base``; the frame names and the calibration name default to
the ones the result records (``frames``, ``calib_name``) and the options (the same as ``calibrate``'s)
override them, so a wrong ``--base-frame`` costs one command, not a calibration. The exports go beside
the result (replacing the earlier ones: that is this command's job) or into ``--output DIR``; the result
itself is rewritten only with ``--update-result`` (its ``frames``, ``calib_name`` and ``exports``).

A result with ``"usable": false`` has no exports: refused with exit code 1. A missing or unreadable
file, invalid JSON, a missing key or a pose that is not a finite rigid transform: one line naming the
file and what is wrong, exit code 2.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from arc_env.cli.result import add_export_arguments, check_frame_names, plan_exports, print_exports
from arc_env.robot.exports import (
    DEFAULT_CAMERA_FRAME,
    RESULT_FORMAT,
    calib_name_from,
    check_calib_name,
    check_frame_name,
    easy_handeye2_install_path,
    frames_dict,
    write_files_atomic,
)
from solver.errors import ArcCalibError, InvalidInputError
from solver.frames import check_transform


class UnusableResultError(ArcCalibError):
    """The result says ``"usable": false``: there is nothing to export."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``arc-calib export`` options."""
    parser.add_argument("result", help="a result.json written by 'arc-calib calibrate' or 'arc-calib run'")
    parser.add_argument("--output", "-o", metavar="DIR",
                        help="write the exports into DIR, named after the result (default: beside the result)")
    add_export_arguments(parser, from_result=True)
    parser.add_argument("--force", action="store_true",
                        help="replace an existing ~/.ros2/easy_handeye2/calibrations/NAME.calib (--install-calib)")
    parser.add_argument("--update-result", action="store_true",
                        help="also record the new frames, calibration name and exports in result.json "
                             "(only with the exports beside it)")


def _reject(path: Path, what: str) -> InvalidInputError:
    return InvalidInputError(f"{path}: {what}")


def read_result(path: Path) -> dict[str, Any]:
    """The parsed ``result.json``, checked for what ``export`` reads.

    Raises:
        InvalidInputError: the file is missing or unreadable, not JSON, not a result of this format, or its
            ``usable``, ``T_camera_base``, ``frames`` or ``calib_name`` are missing or malformed (NaN
            included); the message names the file and the key.
        UnusableResultError: the result says ``"usable": false`` (the message gives its reason).
    """
    path = Path(path)
    if not path.is_file():
        raise _reject(path, "no such file" if not path.exists() else "not a regular file")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise _reject(path, f"cannot be read: {exc}") from exc
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise _reject(path, f"not valid JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise _reject(path, "not an ARC-Calib result (expected a JSON object)")
    if data.get("format") != RESULT_FORMAT:
        raise _reject(path, f"not an ARC-Calib result: 'format' is {data.get('format')!r}, expected {RESULT_FORMAT!r}")
    for key in ("usable", "T_camera_base"):
        if key not in data:
            raise _reject(path, f"missing key {key!r}")
    if not isinstance(data["usable"], bool):
        raise _reject(path, f"'usable' must be true or false, got {data['usable']!r}")
    try:
        T = np.asarray(data["T_camera_base"], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise _reject(path, f"'T_camera_base' is not a 4x4 array of numbers ({exc})") from exc
    data["T_camera_base"] = check_transform(T, f"{path}: T_camera_base")
    frames = data.get("frames")
    if not isinstance(frames, dict) or not isinstance(frames.get("parent"), str):
        raise _reject(path, "missing key 'frames' with the 'parent' (base) frame name")
    if not data["usable"]:
        reason = data.get("unusable_reason") or "no reason given"
        raise UnusableResultError(f"{path}: the result is not usable ({reason}); it has no ROS exports. "
                                  "Calibrate again (more motions, or relax --max-std-deg / --max-std-mm)")
    return data


def _recorded_optical_frame(path: Path, frames: dict[str, Any]) -> str:
    """The optical frame's name the result records (results before ``optical_frame`` existed: the child)."""
    name = frames.get("optical_frame") or frames.get("child") or DEFAULT_CAMERA_FRAME
    return check_frame_name(name, f"{path}: frames.optical_frame")


def _recorded_calib_name(path: Path, data: dict[str, Any]) -> str:
    if "calib_name" in data:
        return check_calib_name(data["calib_name"], f"{path}: calib_name")
    source = data.get("source")
    return calib_name_from(Path(source).name if isinstance(source, str) else "")


def run_export(args: argparse.Namespace) -> int:
    """``arc-calib export`` from parsed arguments; returns the exit code (0 written)."""
    check_frame_names(args)
    path = Path(args.result)
    data = read_result(path)
    frames = data["frames"]
    base_frame = args.base_frame or check_frame_name(frames["parent"], f"{path}: frames.parent")
    args.camera_frame = args.camera_frame or _recorded_optical_frame(path, frames)
    if args.camera_link_frame is not None and args.camera_link_frame == args.camera_frame:
        raise InvalidInputError(f"--camera-link-frame {args.camera_link_frame!r} is the optical frame's name; the "
                                "camera link is the frame above it")
    calib_name = args.calib_name or _recorded_calib_name(path, data)
    folder = Path(args.output) if args.output else None
    if folder is not None:
        if folder.exists() and not folder.is_dir():
            raise InvalidInputError(f"--output {folder}: exists and is not a directory")
        if args.update_result and folder.resolve() != path.resolve().parent:
            raise InvalidInputError("--update-result records export file names beside the result: drop --output "
                                    "or give the result's own folder")
    if args.install_calib:
        target = easy_handeye2_install_path(calib_name)
        if (target.exists() or target.is_symlink()) and not args.force:
            raise InvalidInputError(f"{target}: already exists; use --force to replace it")
    planned = plan_exports(data["T_camera_base"], args, base_frame, calib_name, path, folder)
    written = {k: p for k, p in planned.paths.items() if k != "installed_calib"}
    files = dict(planned.files)
    if args.update_result:
        data = {**data, "T_camera_base": data["T_camera_base"].tolist(),
                "frames": frames_dict(planned.edge, planned.optical_frame), "calib_name": planned.calib_name,
                "exports": {k: p.name for k, p in written.items()}}
        files[path] = json.dumps(data, indent=2) + "\n"
    write_files_atomic(files, planned.modes)
    if args.update_result:
        print(f"updated {path} (frames, calib_name, exports)")
    print_exports(planned)
    return 0


__all__ = ["UnusableResultError", "add_arguments", "read_result", "run_export"]
