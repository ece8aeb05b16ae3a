"""``arc-calib run --driver module:Class``: calibrate online, a planner (random or informed) driving a ``RobotDriver``.

The planner proposes exploratory motions that the driver's robot model (the digital twin of
``DriverEnv``) says are within the limits and collision-free over the whole sweep; once an estimate
exists it also requires the moving links to stay in view. Before the first estimate, motions are not
checked for visibility (the simulator's image test would need the unknown camera pose), so the first
few may miss the camera and be pruned. The driver executes each motion, its frames are tracked and the
calibrator updated; the episode ends on convergence or after ``--motions``. The result is written like
``arc-calib calibrate``'s, and ``--record DIR`` also saves the sweeps as a recording.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

import numpy as np

from arc_env.calibrate import (
    CalibrationRun,
    MotionDiagnostic,
    check_output,
    copy_report,
    estimate_status,
    finish,
)
from arc_env.driver import DriverEnv, RobotDriver, Sweep
from arc_env.env import EnvConfig
from arc_env.progress import Progress
from arc_env.recording import RecordingWriter
from planners.informed_planner import InformedPlanner, InformedPlannerConfig
from planners.random_planner import RandomPlanner, RandomPlannerConfig
from solver.errors import ArcCalibError, InvalidInputError


def load_driver(spec: str) -> RobotDriver:
    """Instantiate ``module:Name`` (a class or factory taking no arguments) and check it is a RobotDriver."""
    module_name, _, attr = spec.partition(":")
    if not module_name or not attr:
        raise InvalidInputError(f"--driver must be 'module:Class', got {spec!r}")
    try:
        factory = getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise InvalidInputError(f"--driver {spec}: cannot load it: {exc}") from exc
    try:
        driver = factory()
    except Exception as exc:  # the user's code: report it, do not crash
        raise InvalidInputError(f"--driver {spec}: constructing it failed: {type(exc).__name__}: {exc}") from exc
    missing = [name for name in ("robot", "joint_names", "intrinsics", "joint_limits", "move_to", "sweep")
               if not hasattr(driver, name)]
    if missing:
        raise InvalidInputError(f"--driver {spec}: not a RobotDriver, missing {missing} (see docs/driver.md)")
    return driver


def run_online(args: argparse.Namespace) -> int:
    """``arc-calib run`` from parsed arguments; returns the exit code (0 only for a usable result)."""
    check_output(Path(args.output))
    if args.motions < 3:
        raise InvalidInputError("--motions must be >= 3")
    driver = load_driver(args.driver)
    writer: RecordingWriter | None = None
    if args.record:
        writer = RecordingWriter(Path(args.record), driver.intrinsics, driver.robot)

    def on_sweep(index: int, q_start: np.ndarray, joint: int, sweep: Sweep) -> None:
        if writer is not None:
            writer.add_motion(driver.joint_names, sweep.positions, sweep.frames)

    started = time.perf_counter()
    env = DriverEnv(driver, EnvConfig(max_motions=args.motions, terminate_on_convergence=not args.all_motions),
                    on_sweep=on_sweep)
    try:
        obs, _ = env.reset(seed=args.seed)
        # the twin has no camera image, so neither planner may run its image test
        rng = np.random.default_rng(args.seed)
        planner = (InformedPlanner(env, rng, InformedPlannerConfig(bootstrap_image_tests=0))
                   if getattr(args, "planner", "random") == "informed"
                   else RandomPlanner(env, rng, RandomPlannerConfig(max_image_tests=0)))
        diagnostics: list[MotionDiagnostic] = []
        seconds = {"robot": 0.0, "tracking": 0.0, "solver": 0.0}
        with Progress(args.motions, "motions", enabled=not args.quiet) as bar:
            while True:
                try:
                    action = planner.plan(obs)
                except ArcCalibError as exc:
                    bar.clear()
                    print(f"the planner found no motion: {exc}", file=sys.stderr)
                    break
                obs, _, terminated, truncated, info = env.step(action)
                if info["refused"]:
                    raise ArcCalibError(f"the twin refused the planner's motion: {info['refused']}")
                m = info["motion"]
                for key, part in (("robot", "render"), ("tracking", "tracking"), ("solver", "solver")):
                    seconds[key] += env.last_seconds.get(part, 0.0)
                diagnostics.append(MotionDiagnostic(f"{len(diagnostics):03d}", driver.joint_names[m["joint"]],
                                                    info["n_frames"], m["n_tracks"]))
                s = env.calibrator.state
                bar.step(f"joint {driver.joint_names[m['joint']]}, {info['n_frames']} frames, {m['n_tracks']} tracks; "
                         f"{estimate_status(s)}{' [converged]' if s.converged else ''}")
                if terminated or truncated:
                    break
        for report, diag in zip(env.calibrator.reports, diagnostics, strict=True):
            copy_report(report, diag)
        if writer is not None:
            writer.close()
            writer = None
            print(f"recorded the sweeps to {args.record}", file=sys.stderr)
    finally:
        if writer is not None:
            writer.abort()
        env.close()
        close = getattr(driver, "close", None)
        if callable(close):
            close()
    run = CalibrationRun(f"driver {args.driver}", env.calibrator, diagnostics,
                         {**seconds, "total": time.perf_counter() - started})
    truth = getattr(driver, "T_camera_base_true", None)  # simulated drivers only
    return finish(run, args, args.base_frame or driver.robot.base_body, None, truth, started)
