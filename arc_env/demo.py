"""``arc-calib demo``: one episode of ``ArcCalib-v0`` with random collision-free motions, narrated."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from arc_env.env import ArcCalibEnv, EnvConfig
from arc_env.progress import Progress
from arc_env.scene import RobotSource, SceneConfig
from planners.informed_planner import InformedPlanner
from planners.random_planner import RandomPlanner
from solver.errors import ArcCalibError, InvalidInputError
from solver.frames import quaternion_xyzw_from_matrix


def mask_iou(a: NDArray[np.bool_], b: NDArray[np.bool_]) -> float:
    """Intersection over union of two (H, W) bool masks (1.0 when both are empty)."""
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def overlay_image(frame: NDArray[np.uint8], mask_estimate: NDArray[np.bool_],
                  mask_true: NDArray[np.bool_], iou: float) -> NDArray[np.uint8]:
    """The frame (H, W, 3) RGB with the estimate's mask tinted red and the true outline in green; BGR out."""
    bgr = cv2.cvtColor(frame, cv2.COLOR_RGB2BGR)
    tint = bgr.copy()
    tint[mask_estimate] = (0.45 * tint[mask_estimate] + 0.55 * np.array([40, 40, 230])).astype(np.uint8)
    contours, _ = cv2.findContours(mask_true.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(tint, contours, -1, (60, 220, 60), max(1, frame.shape[1] // 640))
    scale = frame.shape[1] / 1920
    cv2.putText(tint, f"IoU {iou:.3f}  red: robot rendered with the estimate, green: true outline",
                (int(20 * scale), int(50 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 1.0 * scale, (255, 255, 255),
                max(1, int(2 * scale)), cv2.LINE_AA)
    return tint


def run_demo(args: argparse.Namespace) -> int:
    """Run the episode described by the parsed ``arc-calib demo`` arguments; returns the exit code."""
    if args.robot and not args.base_body:
        raise InvalidInputError("--robot needs --base-body (the body whose frame is the robot's base)")
    robot = RobotSource(path=args.robot, base_body=args.base_body, home=()) if args.robot else RobotSource()
    scene = SceneConfig(robot=robot, width=args.width, height=args.height)
    config = EnvConfig(scene=scene, max_motions=args.motions, oracle_keypoints=args.oracle,
                       oracle_noise_px=args.noise)
    env = ArcCalibEnv(config)
    try:
        return _episode(env, args)
    finally:
        env.close()


def _episode(env: ArcCalibEnv, args: argparse.Namespace) -> int:
    obs, info = env.reset(seed=args.seed)
    planner = (InformedPlanner if args.planner == "informed" else RandomPlanner)(env, np.random.default_rng(args.seed))
    mode = "oracle keypoints" if args.oracle else "rendered pixels, optical-flow tracking"
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
            except ArcCalibError as exc:
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
    cal = env.calibrator
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


def _write_overlay(env: ArcCalibEnv, T_estimate: NDArray[np.float64], path: Path) -> None:
    frame = env.scene.render()
    true = env.scene.robot_mask()
    est = env.scene.robot_mask(T_estimate)
    iou = mask_iou(est, true)
    image = overlay_image(frame, est, true, iou)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    if not cv2.imwrite(str(tmp), image):
        raise OSError(f"OpenCV could not write {tmp}")
    tmp.replace(path)
    print(f"overlay: {path} (IoU of the robot mask rendered with the estimate vs the true mask: {iou:.4f})")
