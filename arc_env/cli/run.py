"""``arc-calib run --driver module:Class``: calibrate online, a planner (random or informed) driving a ``RobotDriver``.

The driver's robot model (``arc_env.robot.model.RobotModel``, with a collision-only ground plane) is the
planner's context through a ``CalibrationSession``: motions must be within the limits (the model's and
the driver's) and collision-free over the whole sweep; once an estimate exists the moving links must
also stay in view. Before the first estimate, motions are not checked for visibility (there is no image
to test), so the first few may miss the camera and be pruned. The driver executes each motion, its
frames are tracked and the calibrator updated; the episode ends on convergence or after ``--motions``.
With ``--overlap`` a motion's frames are tracked and calibrated while the robot executes the next one
(``SessionConfig.overlap``): the planner plans from the estimate without the motion just executed, the
last one is processed after the loop, and the time the robot stood waiting for the computer is reported
as "waited".
The result is written like ``arc-calib calibrate``'s, and ``--record DIR`` also saves the sweeps as a
recording. If the driver fails (or Ctrl-C) mid-run, the motions recorded so far are kept in ``--record DIR``
and ``--resume DIR`` continues from them: they are tracked and given to the calibrator first (and copied
into the new ``--record``), then the planner goes on. The run's input ``--resume DIR`` is never written.

The informed planner predicts occlusion from depth images; here they are drawn by the simulator's
renderer of the same robot model (created only if the informed planner asks for one), so a real robot's
``run`` needs an offscreen GL backend only with ``--planner informed``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from arc_env.cli.calibrate import outline_frames_from
from arc_env.cli.progress import Progress
from arc_env.cli.result import check_frame_names, check_outputs, finish
from arc_env.cli.viewer import check_rerun_save, open_rerun_log
from arc_env.robot.driver import Sweep, load_driver
from arc_env.robot.exports import (
    DEFAULT_CALIB_NAME,
    calib_name_from,
    check_frame_name,
    easy_handeye2_install_path,
    ros_base_frame,
)
from arc_env.robot.recording import Recording, RecordingWriter, read_recording
from arc_env.robot.session import (
    CalibrationRun,
    CalibrationSession,
    MotionDiagnostic,
    SessionConfig,
    StepResult,
    copy_report,
    driver_session,
    estimate_status,
)
from arc_env.sim.twin import TwinRenderer
from planners.context import observation_from_estimate
from planners.errors import PlanningError
from planners.informed import InformedPlanner, InformedPlannerConfig
from planners.random_planner import RandomPlanner, RandomPlannerConfig
from solver.arrays import FloatArray
from solver.errors import ArcCalibError, InvalidInputError


def run_online(args: argparse.Namespace) -> int:
    """``arc-calib run`` from parsed arguments; returns the exit code (0 only for a usable result)."""
    resume = Path(args.resume) if getattr(args, "resume", None) else None
    check_frame_names(args)
    calib_name = args.calib_name or (calib_name_from(Path(args.record).resolve().name) if args.record
                                     else DEFAULT_CALIB_NAME)
    check_outputs(Path(args.output), [resume] if resume else [], args.force,
                  other_outputs=[Path(args.record)] if args.record else [],
                  installed_calib=easy_handeye2_install_path(calib_name) if args.install_calib else None)
    if args.motions < 3:
        raise InvalidInputError("--motions must be >= 3")
    check_rerun_save(args, [resume] if resume else [], args.force)
    previous = read_recording(resume, min_motions=1) if resume else None
    driver = load_driver(args.driver)
    base_frame = args.base_frame or ros_base_frame(driver.robot.base_body)
    if args.base_frame is None:
        check_frame_name(base_frame, f"--driver {args.driver}: the robot's base body (or give --base-frame)")
    if previous is not None and tuple(previous.joint_names) != tuple(driver.joint_names):
        raise InvalidInputError(f"--resume {resume}: its joints {list(previous.joint_names)} are not the driver's "
                                f"{list(driver.joint_names)}")
    writer: RecordingWriter | None = None
    if args.record:
        writer = RecordingWriter(Path(args.record), driver.intrinsics, driver.robot)

    def on_sweep(index: int, q_start: FloatArray, joint: int, sweep: Sweep) -> None:
        if writer is not None:
            writer.add_motion(driver.joint_names, sweep.positions, sweep.frames)

    started = time.perf_counter()
    informed = getattr(args, "planner", "random") == "informed"
    overlap = bool(getattr(args, "overlap", False))
    outline_frames = outline_frames_from(args)
    session = driver_session(driver, SessionConfig(overlap=overlap, outline_frames=outline_frames), on_sweep)
    log = open_rerun_log(args, session.robot, driver.intrinsics, f"run {args.driver}",
                         getattr(driver, "T_camera_base_true", None))  # simulated drivers know the truth
    session.observer = log
    renderer = TwinRenderer(session.robot, driver.intrinsics) if informed else None
    session.renderer = renderer
    diagnostics: list[MotionDiagnostic] = []
    seconds = {"robot": 0.0, "tracking": 0.0, "solver": 0.0} | ({"waited": 0.0} if overlap else {})

    def take(result: StepResult) -> None:
        """Count a processed motion: its diagnostic (matched by its index), times and progress line."""
        assert result.motion is not None and result.index is not None and calibrator is not None
        m = result.motion
        for key, part in (("robot", "render"), ("tracking", "tracking"), ("solver", "solver"), ("waited", "waited")):
            if key in seconds:
                seconds[key] += result.seconds.get(part, 0.0)
        name = driver.joint_names[m.joint]
        diagnostics.append(MotionDiagnostic(f"{result.index:03d}", name, result.n_frames, m.n_tracks))
        s = calibrator.state
        bar.step(f"joint {name}, {result.n_frames} frames, {m.n_tracks} tracks; "
                 f"{estimate_status(s)}{' [converged]' if s.converged else ''}")

    try:
        session.reset(np.random.default_rng(args.seed))
        calibrator = session.calibrator
        assert calibrator is not None
        # there is no camera image to test before an estimate, so neither planner runs its image test
        rng = np.random.default_rng(args.seed)
        planner = (InformedPlanner(session, rng, InformedPlannerConfig(bootstrap_image_tests=0)) if informed
                   else RandomPlanner(session, rng, RandomPlannerConfig(max_image_tests=0)))
        with Progress(args.motions, "motions", enabled=not args.quiet) as bar:
            if previous is not None:
                _replay(previous, session, writer, diagnostics, bar)
            obs = observation_from_estimate(calibrator.state.T_camera_base)
            while session.n_motions < args.motions and not (calibrator.state.converged and not args.all_motions):
                try:
                    action = planner.plan(obs)
                except PlanningError as exc:
                    bar.clear()
                    print(f"the planner found no motion: {exc}", file=sys.stderr)
                    break
                before = session.n_motions
                try:
                    result = session.step(np.asarray(action["Q"], dtype=np.float64), int(action["J"]),
                                          float(action["delta"][0]))
                except Exception as exc:  # the driver's own code failed (or Ctrl-C, below)
                    bar.clear()
                    # not counted: this motion's execution failed; counted (overlap): the one in processing did
                    failed = before if session.n_motions == before else before - 1
                    raise DriverFailure(f"motion {failed} failed: {type(exc).__name__}: {exc}") from exc
                if result.refused:
                    raise ArcCalibError(f"the session refused the planner's motion: {result.refused}")
                if not result.pending:
                    take(result)
                obs = observation_from_estimate(calibrator.state.T_camera_base)
            try:
                last = session.flush()  # with overlap, the last motion executed (None without)
            except Exception as exc:
                bar.clear()
                raise DriverFailure(f"motion {session.n_motions - 1} failed: {type(exc).__name__}: {exc}") from exc
            if last is not None:
                take(last)
        for report, diag in zip(calibrator.reports, diagnostics, strict=True):
            copy_report(report, diag)
        if writer is not None:
            writer.close()
            writer = None
            print(f"recorded the sweeps to {args.record}", file=sys.stderr)
    except (DriverFailure, KeyboardInterrupt) as exc:
        kept = writer is not None and writer.n_motions > 0
        if kept:
            assert writer is not None
            writer.close()
            writer = None
        what = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"the driver failed: {exc}"
        how = (f"the {session.n_motions} motions done are kept in {args.record}; continue with "
               f"--resume {args.record} --record NEW_DIR" if kept else
               "no motion was kept (record with --record DIR to be able to --resume)")
        print(f"arc-calib run: {what}; {how}. No result written.", file=sys.stderr)
        if log is not None:  # the log of the motions done is kept: it may show what went wrong
            log.close()
            log = None
        if isinstance(exc, KeyboardInterrupt):
            raise
        return 1
    except BaseException:
        if log is not None:
            log.abort()
            log = None
        raise
    finally:
        if writer is not None:
            writer.abort()
        if renderer is not None:
            renderer.close()
        close = getattr(driver, "close", None)
        if callable(close):
            close()
    if log is not None:
        log.finish(calibrator)
        log.close()
        print(f"rerun log: {args.rerun_save}" if args.rerun_save else "rerun log: sent to the viewer", file=sys.stderr)
    run = CalibrationRun(f"driver {args.driver}", calibrator, diagnostics, seconds)
    run.check_focal()
    run.seconds["total"] = time.perf_counter() - started
    truth = getattr(driver, "T_camera_base_true", None)  # simulated drivers only
    return finish(run, args, base_frame, None, truth, started, calib_name)


class DriverFailure(ArcCalibError):
    """The driver raised while executing a motion (the message names the motion and the error)."""


def _replay(previous: Recording, session: CalibrationSession, writer: RecordingWriter | None,
            diagnostics: list[MotionDiagnostic], bar: Progress) -> None:
    """Feed a resumed recording's motions to the session (and copy them into the new recording)."""
    names = previous.joint_names
    for m in previous.usable:
        assert m.joint is not None
        frames = previous.frames(m)
        outcome = session.replay(m.q_start, m.joint, m.delta, session.track(frames, m.delta), frames)
        if writer is not None:
            positions = np.tile(m.q_start, (m.n_frames, 1))
            positions[:, m.joint] += m.delta
            writer.add_motion(names, positions, frames)
        diagnostics.append(MotionDiagnostic(f"{len(diagnostics):03d}", names[m.joint], m.n_frames, outcome.n_tracks))
        bar.step(f"resumed motion {m.name}: joint {names[m.joint]}, {outcome.n_tracks} tracks; "
                 f"{estimate_status(session.calibrator.state) if session.calibrator else ''}")
