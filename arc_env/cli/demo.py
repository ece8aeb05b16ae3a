"""``arc-calib demo``: one episode of ``ArcCalib-v0`` with random (or informed) collision-free motions, narrated.

``--synthetic`` runs the solver alone on synthetic keypoints (the Panda's DH kinematics) instead.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from arc_env.cli.progress import Progress
from arc_env.cli.viewer import check_rerun_save, open_rerun_log
from arc_env.robot.exports import write_files_atomic
from arc_env.robot.library import robot_from_arguments
from arc_env.robot.overlay import draw_overlay, mask_iou
from arc_env.robot.session import OUTLINE_FRAMES
from arc_env.sim.env import ArcCalibEnv, EnvConfig
from arc_env.sim.imaging import realism_settings
from arc_env.sim.scene import SceneConfig
from planners.errors import PlanningError
from planners.informed import InformedPlanner
from planners.random_planner import RandomPlanner
from solver import (
    PANDA,
    ArcCalibError,
    Calibrator,
    SyntheticConfig,
    SyntheticScene,
    d415_intrinsics,
    pose_errors,
    sample_camera_pose,
)
from solver.arrays import FloatArray
from solver.frames import quaternion_xyzw_from_matrix


def run_demo(args: argparse.Namespace) -> int:
    """Run the episode described by the parsed ``arc-calib demo`` arguments; returns the exit code."""
    check_rerun_save(args, force=True)  # like --overlay, demo replaces its outputs
    robot = robot_from_arguments(args.robot, args.base_body)
    scene = SceneConfig(robot=robot, width=args.width, height=args.height, background=args.background,
                        background_seed=args.seed, **realism_settings(args.realism, args.appearance))
    outline_frames = OUTLINE_FRAMES if args.outline_frames is None else args.outline_frames  # the scene renders: GL
    config = EnvConfig(scene=scene, max_motions=args.motions, oracle_keypoints=args.oracle,
                       oracle_noise_px=args.noise, outline_frames=0 if args.oracle else outline_frames)
    env = ArcCalibEnv(config)
    try:
        return _episode(env, args)
    finally:
        env.close()


def _episode(env: ArcCalibEnv, args: argparse.Namespace) -> int:
    obs, info = env.reset(seed=args.seed)
    log = open_rerun_log(args, env.scene.robot, env.intrinsics, f"demo seed {args.seed}", env.T_camera_base_true)
    env.session.observer = log
    try:
        code = _motions(env, args, obs, info)
    except BaseException:
        if log is not None:
            log.abort()
        raise
    if log is not None:
        assert env.session.calibrator is not None
        log.finish(env.session.calibrator)
        log.close()
        if args.rerun_save:
            print(f"rerun log: {args.rerun_save} ({Path(args.rerun_save).stat().st_size / 1e6:.1f} MB; "
                  f"open it with: rerun {args.rerun_save})")
    return code


def _motions(env: ArcCalibEnv, args: argparse.Namespace, obs: dict[str, Any], info: dict[str, Any]) -> int:
    planner = (InformedPlanner if args.planner == "informed" else RandomPlanner)(env.session,
                                                                                  np.random.default_rng(args.seed))
    look = env.config.scene
    mode = ("oracle keypoints" if args.oracle else
            f"rendered pixels ({args.realism} camera, {look.appearance} robot), optical-flow tracking")
    robot = env.config.scene.robot.path or "Franka Panda (gymnasium-robotics)"
    print(f"{robot}, camera {env.intrinsics.width}x{env.intrinsics.height} fx={env.intrinsics.K[0, 0]:.0f}, "
          f"{mode}, {args.planner} motions, seed {args.seed}")
    print(f"{'#':>3} {'joint':>5} {'delta':>6} {'frames':>6} {'tracks':>6} {'status':>9} {'stage':>8} "
          f"{'rot err':>9} {'trans err':>10} {'sec':>5}  note")
    started = time.perf_counter()
    # the table's rows are the log; the bar only adds to a terminal
    seconds = {"planning": 0.0, "transit": 0.0, "render": 0.0, "tracking": 0.0, "solver": 0.0}
    with Progress(args.motions, "motions", enabled=sys.stderr.isatty()) as bar:
        for i in range(args.motions):
            t0 = time.perf_counter()
            try:
                action = planner.plan(obs)
            except PlanningError as exc:
                bar.clear()
                print(f"arc-calib demo: the planner found no motion: {exc}", file=sys.stderr)
                break
            seconds["planning"] += time.perf_counter() - t0
            obs, reward, terminated, truncated, info = env.step(action)
            bar.clear()
            if info["refused"]:  # the planner checks validity, so this is a bug if it happens
                print(f"{i + 1:>3} refused: {info['refused']}")
                continue
            m = info["motion"]
            for k in env.last_seconds:
                seconds[k] = seconds.get(k, 0.0) + env.last_seconds[k]
            note = m["reason"] or (f"no axis (bundle adjustment only): {m['stage_one']}" if m["stage_one"] else "")
            note = note or (info["message"] if info["T_camera_base"] is None else "")
            rot = np.nan if info["rot_error_rad"] is None else info["rot_error_rad"]
            trans = np.nan if info["trans_error_m"] is None else info["trans_error_m"]
            print(f"{i + 1:>3} {m['joint'] + 1:>5} {float(action['delta'][0]):>6.2f} {info['n_frames']:>6} "
                  f"{m['n_tracks']:>6} {'accepted' if m['accepted'] else 'rejected':>9} {info['stage']:>8} "
                  f"{rot:>9.2e} {trans * 1e3:>7.2f} mm {time.perf_counter() - t0:>5.1f}  {note[:60]}"
                  + ("  [converged]" if obs["converged"] else ""))
            bar.step(f"{info['stage']} estimate" + (", converged" if obs["converged"] else ""))
            if (terminated and args.stop_when_converged) or truncated:
                break
    total = time.perf_counter() - started
    cal = env.session.calibrator
    assert cal is not None
    s = cal.state
    print()
    print(f"motions: {len(cal.reports)} executed, {s.n_accepted} accepted, {s.n_rejected} rejected; "
          f"{total:.1f} s (planning {seconds['planning']:.1f}, transit {seconds['transit']:.1f}, "
          f"render {seconds['render']:.1f}, tracking {seconds['tracking']:.1f}, solver {seconds['solver']:.1f})")
    for r in cal.reports:
        if not r.accepted:
            print(f"  motion {r.index + 1} (joint {r.joint + 1}) rejected: {r.reason}")
    if s.T_camera_base is None:
        print(f"no estimate: {s.message}")
        return 1
    np.set_printoptions(precision=5, suppress=True)
    print(f"T_camera_base ({s.stage}; p_camera = T_camera_base @ p_base, OpenCV optical frame):")
    print(s.T_camera_base)
    print(f"translation (m): {s.T_camera_base[:3, 3]}  quaternion (x, y, z, w): "
          f"{quaternion_xyzw_from_matrix(s.T_camera_base[:3, :3])}")
    if s.std is not None:
        print(f"1-sigma: rotation {np.degrees(s.std[:3])} deg, translation {s.std[3:] * 1e3} mm; "
              f"RMS reprojection {s.rms_px:.3f} px")
    print(f"converged: {s.converged}")
    print(f"final error: rotation {info['rot_error_rad']:.2e} rad ({np.degrees(info['rot_error_rad']):.4f} deg), "
          f"translation {info['trans_error_m'] * 1e3:.3f} mm")
    if args.overlay:
        try:
            _write_overlay(env, s.T_camera_base, Path(args.overlay))
        except (OSError, ArcCalibError) as exc:
            print(f"arc-calib demo: could not write the overlay: {exc}", file=sys.stderr)
            return 1
    return 0


def _write_overlay(env: ArcCalibEnv, T_camera_base: FloatArray, path: Path) -> None:
    frame = env.scene.render()
    true = env.scene.robot_mask()
    est = env.scene.robot_mask(T_camera_base)
    iou = mask_iou(est, true)
    image = draw_overlay(frame, est, f"IoU {iou:.3f}  red: robot rendered with the estimate, green: true outline",
                         true_mask=true)
    ok, png = cv2.imencode(".png", image)
    if not ok:
        raise OSError(f"OpenCV could not encode the overlay {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    write_files_atomic({path: png.tobytes()})
    print(f"overlay: {path} (IoU of the robot mask rendered with the estimate vs the true mask: {iou:.4f})")


def run_synthetic(args: argparse.Namespace) -> int:
    """``arc-calib demo --synthetic``: the solver alone on synthetic keypoints; returns the exit code."""
    rng = np.random.default_rng(args.seed)
    T_camera_base_true = sample_camera_pose(rng)
    intrinsics = d415_intrinsics()
    scene = SyntheticScene(PANDA, intrinsics, T_camera_base_true,
                           SyntheticConfig(noise_px=args.noise, outlier_fraction=args.outliers), rng)
    calibrator = Calibrator(intrinsics, PANDA.axis_and_point)
    print(f"synthetic Franka Panda, camera 1920x1080 fx=fy=1380, {args.noise} px noise, "
          f"{args.outliers:.0%} bad tracks, seed {args.seed}")
    print(f"{'#':>3} {'joint':>5} {'tracks':>6} {'status':>9} {'stage':>8} {'rot err':>10} "
          f"{'trans err':>10} {'1-sigma rot':>11} {'1-sigma t':>10}  note")
    for i in range(args.motions):
        try:
            motion = scene.random_motion(rng)
        except ArcCalibError as exc:
            print(f"arc-calib demo: {exc}", file=sys.stderr)
            return 1
        report = calibrator.add_motion(motion.observation)
        s = calibrator.state
        rot, trans = (pose_errors(s.T_camera_base, T_camera_base_true) if s.T_camera_base is not None
                      else (np.nan, np.nan))
        std_r = f"{np.linalg.norm(s.std[:3]):.1e}" if s.std is not None else "-"
        std_t = f"{np.linalg.norm(s.std[3:]) * 1e3:.2f} mm" if s.std is not None else "-"
        note = report.reason or (f"bundle adjustment only; no axis for the linear stage: {report.stage_one}"
                                 if report.stage_one else "")
        note = note or ("" if s.T_camera_base is not None else s.message)
        print(f"{i + 1:>3} {report.joint + 1:>5} {report.n_tracks:>6} "
              f"{'accepted' if report.accepted else 'rejected':>9} {s.stage:>8} {rot:>10.2e} "
              f"{trans * 1e3:>7.2f} mm {std_r:>11} {std_t:>10}  {note[:70]}"
              + ("  [converged]" if s.converged else ""))
        if s.converged and args.stop_when_converged:
            break
    s = calibrator.state
    print()
    rejected = [r for r in calibrator.reports if not r.accepted]
    print(f"motions: {len(calibrator.reports)} executed, {s.n_accepted} accepted, {s.n_rejected} rejected")
    for r in rejected:
        print(f"  motion {r.index + 1} (joint {r.joint + 1}) rejected: {r.reason}")
    if s.T_camera_base is None:
        print(f"no estimate: {s.message}")
        return 1
    rot, trans = pose_errors(s.T_camera_base, T_camera_base_true)
    np.set_printoptions(precision=5, suppress=True)
    print(f"T_camera_base ({s.stage}; p_camera = T_camera_base @ p_base, OpenCV optical frame):")
    print(s.T_camera_base)
    q = quaternion_xyzw_from_matrix(s.T_camera_base[:3, :3])
    print(f"translation (m): {s.T_camera_base[:3, 3]}  quaternion (x, y, z, w): {q}")
    if s.std is not None:
        print(f"1-sigma: rotation {np.degrees(s.std[:3])} deg, translation {s.std[3:] * 1e3} mm; "
              f"RMS reprojection {s.rms_px:.3f} px")
    print(f"converged: {s.converged}")
    print(f"final error: rotation {rot:.2e} rad ({np.degrees(rot):.4f} deg), translation {trans * 1e3:.3f} mm")
    return 0
