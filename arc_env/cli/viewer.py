"""``--rerun`` and ``--rerun-save FILE.rrd`` of ``demo``, ``calibrate`` and ``run``: the episode logged to Rerun.

The log itself is ``arc_env.robot.rerun_log``; Rerun is imported only when one of the options is given.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from arc_env.robot.model import RobotModel
from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.observations import CameraIntrinsics

if TYPE_CHECKING:
    from arc_env.robot.rerun_log import RerunLog


def add_rerun_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``--rerun`` and ``--rerun-save`` options."""
    parser.add_argument("--rerun", action="store_true",
                        help="log the episode to a Rerun viewer (started if none runs): frames with tracks, fitted "
                             "ellipses and axes, the posed robot, the camera estimate with its 1-sigma, curves")
    parser.add_argument("--rerun-save", metavar="FILE.rrd",
                        help="write the same log to FILE.rrd (no viewer needed; open it with 'rerun FILE.rrd')")


def check_rerun_save(args: argparse.Namespace, inputs: Sequence[Path] = (), force: bool = False) -> None:
    """Refuse, before any work, a bad ``--rerun-save`` file.

    It must end in .rrd, its directory must exist, and it may be neither inside an input nor (without
    ``force``) an existing file.

    Raises:
        InvalidInputError: as above.
    """
    if not args.rerun_save:
        return
    path = Path(args.rerun_save)
    if path.suffix != ".rrd":
        raise InvalidInputError(f"--rerun-save must name a .rrd file, got {path}")
    if not path.parent.is_dir():
        raise InvalidInputError(f"--rerun-save: directory {path.parent} does not exist")
    if path.is_dir():
        raise InvalidInputError(f"--rerun-save {path}: is a directory")
    for source in inputs:
        if path.resolve().is_relative_to(Path(source).resolve()):
            raise InvalidInputError(f"--rerun-save {path}: is inside the input {Path(source).resolve()}; write "
                                    "outputs elsewhere (ARC-Calib never writes into what it reads)")
    if path.exists() and not force:
        raise InvalidInputError(f"--rerun-save {path}: already exists; use --force to replace it")


def open_rerun_log(args: argparse.Namespace, robot: RobotModel, intrinsics: CameraIntrinsics, name: str,
                   T_camera_base_true: FloatArray | None = None) -> RerunLog | None:
    """The log ``--rerun`` / ``--rerun-save`` ask for, or None when neither is given."""
    if not (args.rerun or args.rerun_save):
        return None
    from arc_env.robot.rerun_log import RerunLog

    return RerunLog(robot, intrinsics, save=Path(args.rerun_save) if args.rerun_save else None, spawn=args.rerun,
                    name=name, T_camera_base_true=T_camera_base_true)
