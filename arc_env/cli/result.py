"""What ``calibrate`` and ``run`` share: the usability check, the per-motion table, the result and its exports."""

from __future__ import annotations

import argparse
import json
import shlex
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from arc_env.robot.exports import (
    DEFAULT_CAMERA_FRAME,
    EXECUTABLE_EXPORTS,
    ParentChild,
    check_calib_name,
    check_frame_name,
    easy_handeye2_install_path,
    export_paths,
    export_texts,
    result_dict,
    write_files_atomic,
)
from arc_env.robot.report import report_path
from arc_env.robot.session import CalibrationRun, UsableCriteria, unusable_reason
from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import pose_errors, quaternion_xyzw_from_matrix


@dataclass(frozen=True)
class Exports:
    """The exports of one result, ready to be committed with ``write_files_atomic(files, modes)``.

    Attributes:
        edge: the TF edge they carry.
        calib_name: the easy_handeye2 calibration name.
        optical_frame: the camera's optical frame name (the edge's child, or the frame below its camera link).
        paths: {export key: file}; with ``--install-calib`` also ``"installed_calib"``.
        files: {file: text}.
        modes: {file: permission bits} (the executable ``.tf.sh``).
    """

    edge: ParentChild
    calib_name: str
    optical_frame: str
    paths: dict[str, Path]
    files: dict[Path, str | bytes]
    modes: dict[Path, int]


def plan_exports(T_camera_base: FloatArray, args: argparse.Namespace, base_frame: str, calib_name: str,
                 output: Path, folder: Path | None = None) -> Exports:
    """Every export of ``T_camera_base`` (4, 4, metres) as ``args`` asks (frames, camera link, install).

    Args:
        T_camera_base: the estimate.
        args: camera_frame, camera_link_frame, install_calib (``add_export_arguments``).
        base_frame: the TF parent (``--base-frame`` or its default), checked here.
        calib_name: the calibration name (``--calib-name`` or its default), checked here.
        output: the result file the exports are named after.
        folder: where the exports go (default: beside ``output``).
    """
    calib_name = check_calib_name(calib_name, "--calib-name")
    edge = ParentChild.from_T_camera_base(T_camera_base, check_frame_name(base_frame, "--base-frame"),
                                          args.camera_frame)
    if args.camera_link_frame:
        edge = edge.to_camera_link(args.camera_link_frame)
    paths = export_paths(output, folder)
    texts = export_texts(edge, calib_name)
    files: dict[Path, str | bytes] = {paths[k]: texts[k] for k in paths}
    modes = {paths[k]: 0o755 for k in EXECUTABLE_EXPORTS}
    if args.install_calib:
        paths["installed_calib"] = easy_handeye2_install_path(calib_name)
        files[paths["installed_calib"]] = texts["easy_handeye2"]
    return Exports(edge, calib_name, args.camera_frame, paths, files, modes)


def print_exports(exports: Exports) -> None:
    """Say what was written and the commands that use it (names shell-quoted)."""
    for key, path in exports.paths.items():
        print(f"wrote {path} ({key})")
    edge = exports.edge
    what = "the OpenCV optical frame" if edge.optical else f"the camera link above {exports.optical_frame}"
    print(f"TF (parent {edge.base_frame} -> child {edge.camera_frame}, {what}):")
    print(f"  {exports.files[exports.paths['static_transform_publisher']].splitlines()[-1].removeprefix('exec ')}")
    name = shlex.quote(exports.calib_name)
    if "installed_calib" in exports.paths:
        print(f"easy_handeye2: ros2 launch easy_handeye2 publish.launch.py name:={name}")
    else:
        print(f"easy_handeye2: copy {shlex.quote(str(exports.paths['easy_handeye2']))} to "
              f"~/.ros2/easy_handeye2/calibrations/{name}.calib (or pass --install-calib), then "
              f"ros2 launch easy_handeye2 publish.launch.py name:={name}")


def finish(run: CalibrationRun, args: argparse.Namespace, base_frame: str,
           overlays: Callable[[], dict[Path, bytes]] | None, truth: np.ndarray | None, started: float,
           calib_name: str, report: Callable[[dict[str, Any], dict[Path, bytes]], str] | None = None) -> int:
    """Print the per-motion table; if the result is usable, write it with its exports and print it.

    An estimate that is not usable is still written to ``result.json`` with ``"usable": false`` and the
    reason, so a user can look, but without ROS exports or overlays; with no estimate at all nothing is
    written. ``args`` carries output, the export options (``add_export_arguments``), min_motions,
    max_std_deg, max_std_mm. ``base_frame`` and ``calib_name`` are the TF parent and the easy_handeye2
    name (the options or their defaults). ``report`` (``calibrate``), given the result dict and the overlay
    images, returns the HTML report, written with the result (usable or not) to ``report_path(output)``.
    Returns the exit code: 0 usable (written), 1 not usable.
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
    planned = plan_exports(T_camera_base, args, base_frame, calib_name, output)
    edge = planned.edge
    if why:
        unusable = result_dict(run, edge, {}, why, planned.calib_name, planned.optical_frame)
        pages = {report_path(output): report(unusable, {})} if report is not None else {}
        write_files_atomic({output: json.dumps(unusable, indent=2) + "\n", **pages})
        print(f"no usable calibration: {why}. Wrote {output} with \"usable\": false (no ROS exports)"
              + (f" and {report_path(output)}." if pages else "."))
        if truth is not None:
            rot, trans = pose_errors(T_camera_base, truth)
            print(f"true error: rotation {rot:.2e} rad ({np.degrees(rot):.4f} deg), translation {trans * 1e3:.3f} mm")
        return 1
    written = {k: p for k, p in planned.paths.items() if k != "installed_calib"}
    result = result_dict(run, edge, written, "", planned.calib_name, planned.optical_frame)
    images = overlays() if overlays is not None else {}
    pages = {report_path(output): report(result, images)} if report is not None else {}
    write_files_atomic({**planned.files, output: json.dumps(result, indent=2) + "\n", **images, **pages},
                       planned.modes)  # all or nothing

    np.set_printoptions(precision=6, suppress=True)
    print(f"T_camera_base ({s.stage}; p_camera = T_camera_base @ p_base, OpenCV optical frame):")
    print(T_camera_base)
    print(f"translation (m): {T_camera_base[:3, 3]}  quaternion (x, y, z, w): "
          f"{quaternion_xyzw_from_matrix(T_camera_base[:3, :3])}")
    print(f"1-sigma: rotation {np.degrees(s.std[:3])} deg, translation {s.std[3:] * 1e3} mm; RMS reprojection "
          f"{s.rms_px:.3f} px; converged: {s.converged}")
    if s.time_offset_s is not None and s.time_offset_std_s is not None:
        given = run.given_time_offset_s
        print(f"time offset (t_joint - t_camera): {(given + s.time_offset_s) * 1e3:+.2f} ms = given "
              f"{given * 1e3:+g} ms + estimated {s.time_offset_s * 1e3:+.2f} ms "
              f"(1-sigma {s.time_offset_std_s * 1e3:.2f} ms)")
    outlines = run.calibrator.outlines
    if outlines is not None:
        if s.outline is None:
            how = f"not used ({s.outline_note})"
        elif s.outline.prior_scale > 1.0:
            how = (f"combined with the tracks, whose pose disagreed with them: the tracks' covariance taken "
                   f"{s.outline.prior_scale:.1f}x larger (not converged)")
        else:
            how = "combined with the tracks"
        print(f"outlines: {outlines.n_images} images of {outlines.n_groups} motions; {how}")
    if truth is not None:
        rot, trans = pose_errors(T_camera_base, truth)
        print(f"true error: rotation {rot:.2e} rad ({np.degrees(rot):.4f} deg), translation {trans * 1e3:.3f} mm")
    print(f"wrote {output}")
    for path in images:
        print(f"wrote {path} (overlay)")
    for path in pages:
        print(f"wrote {path} (report)")
    print_exports(planned)
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


#: Overlay images ``calibrate`` writes into ``--overlay DIR`` (a glob pattern).
OVERLAY_PATTERN = "overlay_motion_*.png"


def check_outputs(output: Path, inputs: Sequence[Path], force: bool = False, overlay_dir: Path | None = None,
                  other_outputs: Sequence[Path] = (), installed_calib: Path | None = None,
                  report: bool = False) -> None:
    """Refuse, before any work, outputs that would damage the input or an earlier result.

    Args:
        output: the result JSON (its exports sit beside it).
        inputs: what the run reads (a recording directory, a ground-truth file): no output may be one
            of them or inside one.
        force: allow replacing existing output files (never an input, never a directory).
        overlay_dir: ``--overlay DIR``, if given.
        other_outputs: folders the run creates (e.g. ``run --record DIR``): they too must stay out of the
            inputs, and the result and its exports must stay out of them.
        installed_calib: ``--install-calib``'s target in ``~/.ros2/easy_handeye2/calibrations/``, if any.
        report: the run writes ``report_path(output)`` too.

    Raises:
        InvalidInputError: an output is not .json, its directory does not exist, it is (or is inside)
            an input, it is an existing directory, or it exists and ``force`` is off.
    """
    output = Path(output)
    if output.suffix != ".json":
        raise InvalidInputError(f"--output must be a .json file, got {output}")
    if not output.parent.is_dir():
        raise InvalidInputError(f"--output: directory {output.parent} does not exist")
    files = [output, *export_paths(output).values(), *([installed_calib] if installed_calib else []),
             *([report_path(output)] if report else [])]
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
    """Validate the names given as options before any work: they reach the exports.

    ``--base-frame``, ``--camera-frame`` and ``--camera-link-frame`` (ROS frame names), ``--calib-name``
    (a file name stem); the camera link must differ from the optical frame.
    """
    if args.base_frame is not None:
        check_frame_name(args.base_frame, "--base-frame")
    if args.camera_frame is not None:
        check_frame_name(args.camera_frame, "--camera-frame")
    if args.camera_link_frame is not None:
        check_frame_name(args.camera_link_frame, "--camera-link-frame")
        if args.camera_link_frame == args.camera_frame:
            raise InvalidInputError(f"--camera-link-frame {args.camera_link_frame!r} is the optical frame's name "
                                    "(--camera-frame); the camera link is the frame above it")
    if args.calib_name is not None:
        check_calib_name(args.calib_name, "--calib-name")


def add_export_arguments(parser: argparse.ArgumentParser, from_result: bool = False) -> None:
    """The options that shape the exports, shared by ``calibrate``, ``run`` and ``export``.

    Args:
        parser: the subcommand's parser.
        from_result: ``export``: the frame and name defaults are the ones the result records.
    """
    recorded = " (default: the one the result records)" if from_result else ""
    parser.add_argument("--base-frame", help="TF name of the robot base, the exports' parent frame" + (
        recorded or " (default: the robot model's base link as ROS names it: the base body's name, except "
                    "the gymnasium-robotics Panda's panda0_link0, which is panda_link0; docs/exports.md)"))
    parser.add_argument("--camera-frame", default=None if from_result else DEFAULT_CAMERA_FRAME,
                        help="TF name of the camera's OpenCV optical frame" + (
                            recorded or f" (default {DEFAULT_CAMERA_FRAME})"))
    parser.add_argument("--camera-link-frame", metavar="NAME",
                        help="export base -> NAME, the camera's REP 103 body frame (camera_link: x forward, y left, "
                             "z up), for drivers that publish camera_link -> optical frame themselves; the ideal "
                             "rotation between the two, no offset (default: export base -> optical frame)")
    parser.add_argument("--calib-name", metavar="NAME",
                        help="the easy_handeye2 calibration name: letters, digits, '_', '-'" + (
                            recorded or " (default: the recording's folder name, other characters as '_'; "
                                        "arc_calib for run without --record)"))
    parser.add_argument("--install-calib", action="store_true",
                        help="also write the .calib to ~/.ros2/easy_handeye2/calibrations/NAME.calib, where "
                             "'ros2 launch easy_handeye2 publish.launch.py name:=NAME' reads it")


def add_result_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared by ``calibrate`` and ``run``: output, frames, usability."""
    parser.add_argument("--output", "-o", required=True, help="result JSON; exports are written beside it")
    add_export_arguments(parser)
    parser.add_argument("--min-motions", type=int, default=UsableCriteria.min_motions,
                        help=f"fewest accepted motions for a usable result (default {UsableCriteria.min_motions})")
    parser.add_argument("--max-std-deg", type=float, default=UsableCriteria.max_std_deg,
                        help=f"largest 1-sigma rotation per axis, deg (default {UsableCriteria.max_std_deg})")
    parser.add_argument("--max-std-mm", type=float, default=UsableCriteria.max_std_mm,
                        help=f"largest 1-sigma translation per axis, mm (default {UsableCriteria.max_std_mm})")
    parser.add_argument("--quiet", "-q", action="store_true", help="no per-motion progress on stderr")
    parser.add_argument("--force", action="store_true",
                        help="replace existing output files (never the input; never a directory)")
