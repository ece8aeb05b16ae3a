"""Round trip simulation -> recording -> calibration: accuracy and timings per resolution.

For each resolution and seed: ``arc-calib record`` (the random planner, PNG or MP4, optional lens
distortion) into a temporary directory, then ``arc-calib calibrate``'s pipeline on it; prints the true
error, the 1-sigma, whether the result is usable and where the time went.

    python scripts/bench_recording.py --sizes 1280x720 1920x1080 --seeds 0 1 --motions 12 [--video]
        [--dist -0.12,0.03,0,0,0] [--rss] [--json out.json]

``--rss`` runs ``arc-calib calibrate`` as a child process instead and reports its peak resident memory
(``os.wait4``'s ``ru_maxrss``), which must not grow with the number of motions (frames are decoded one
motion at a time).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from arc_env.robot.recording import read_recording
from arc_env.robot.session import UsableCriteria, calibrate_recording, unusable_reason
from arc_env.sim.distortion import parse_dist
from arc_env.sim.record import RecordSettings, record_episode
from solver.frames import pose_errors


def run_one(size: str, seed: int, args: argparse.Namespace, tmp: Path) -> dict:
    width, height = (int(v) for v in size.lower().split("x"))
    out = tmp / f"rec_{size}_{seed}"
    dist = tuple(parse_dist(args.dist)) if args.dist else ()
    t0 = time.perf_counter()
    truth = record_episode(RecordSettings(out=out, motions=args.motions, seed=seed, width=width, height=height,
                                          video=args.video, dist=dist))
    t1 = time.perf_counter()
    if args.rss:
        return _child_calibrate(out, truth, {"size": size, "seed": seed, "record_s": round(t1 - t0, 1)})
    run = calibrate_recording(read_recording(out))
    t2 = time.perf_counter()
    s = run.calibrator.state
    row = {"size": size, "seed": seed, "record_s": round(t1 - t0, 1), "calibrate_s": round(t2 - t1, 1),
           "accepted": run.n_accepted, "motions": len(run.diagnostics),
           "usable": not unusable_reason(run, UsableCriteria()),
           "converged": s.converged, "rot_err_rad": None, "trans_err_mm": None, "std_deg": None, "std_mm": None,
           "peak_rss_mb": None}
    if s.T_camera_base is not None:
        rot, trans = pose_errors(s.T_camera_base, np.asarray(truth["T_camera_base"]))
        row.update(rot_err_rad=rot, trans_err_mm=trans * 1e3)
    if s.std is not None:
        row.update(std_deg=float(np.degrees(s.std[:3]).max()), std_mm=float(s.std[3:].max() * 1e3))
    return row


def _child_calibrate(recording: Path, truth: dict, row: dict) -> dict:
    """``arc-calib calibrate`` in a child process: its figures from result.json, its peak RSS from wait4."""
    result = recording.with_name(recording.name + "_result.json")
    t0 = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-m", "arc_env.cli", "calibrate", str(recording), "--output",
                              str(result), "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    row.update(calibrate_s=round(time.perf_counter() - t0, 1), peak_rss_mb=round(usage.ru_maxrss / 1024, 1),
               rot_err_rad=None, trans_err_mm=None, std_deg=None, std_mm=None, converged=False, accepted=0,
               motions=len(list((recording / "motions").iterdir())), usable=os.waitstatus_to_exitcode(status) == 0)
    if result.is_file():
        data = json.loads(result.read_text())
        rot, trans = pose_errors(np.asarray(data["T_camera_base"]), np.asarray(truth["T_camera_base"]))
        row.update(rot_err_rad=rot, trans_err_mm=trans * 1e3, converged=data["converged"],
                   accepted=data["motions"]["accepted"])
        if data["std"] is not None:
            row.update(std_deg=max(data["std"]["rotation_deg"]), std_mm=max(data["std"]["translation_mm"]))
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", nargs="+", default=["1280x720", "1920x1080"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--motions", type=int, default=12)
    parser.add_argument("--video", action="store_true", help="MP4 instead of PNG")
    parser.add_argument("--dist", help="simulate this OpenCV distortion, 'k1,k2,p1,p2[,k3]'")
    parser.add_argument("--rss", action="store_true", help="calibrate in a child process and report its peak RSS")
    parser.add_argument("--json", metavar="PATH", help="also write the rows as JSON")
    args = parser.parse_args()
    rows = []
    print(f"{'size':>10} {'seed':>4} {'acc':>6} {'rot err rad':>11} {'trans mm':>9} {'1s deg':>7} {'1s mm':>6} "
          f"{'usable':>6} {'conv':>5} {'record s':>8} {'calib s':>7} {'peak RSS MB':>11}")
    with tempfile.TemporaryDirectory() as tmp:
        for size in args.sizes:
            for seed in args.seeds:
                r = run_one(size, seed, args, Path(tmp))
                rows.append(r)

                def f(v, fmt):
                    return format(v, fmt) if v is not None else "-"

                print(f"{size:>10} {seed:>4} {r['accepted']:>3}/{r['motions']:<2} {f(r['rot_err_rad'], '11.2e')} "
                      f"{f(r['trans_err_mm'], '9.2f')} {f(r['std_deg'], '7.3f')} {f(r['std_mm'], '6.2f')} "
                      f"{str(r['usable']):>6} {str(r['converged']):>5} {r['record_s']:>8} {r['calibrate_s']:>7} "
                      f"{f(r['peak_rss_mb'], '11.1f')}",
                      flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
