"""What ``arc-calib verify`` measures at the right pose and at poses moved by known amounts (its thresholds).

For each seed: ``arc-calib record`` (a simulated episode, PNG frames) into a temporary directory, calibrated
as ``arc-calib calibrate`` does (``calibrate_recording``); then the recording is tracked once, as verify
tracks it (``arc_env.robot.verify.track_recording``), and checked (``check_tracked``) against the true pose,
the calibrated one, and the true pose moved by each perturbation size (rotation rad and translation m,
in ``--directions`` random directions each: xi = (rot * u, trans * v), u and v random unit vectors).

    python scripts/bench_verify.py [--motions 8] [--size 640x360] [--seeds 0 1] [--realism clean]
        [--sizes 0.005 0.02] [--directions 3] [--json out.json]

Prints one row per pose: the 10 %, 25 % (what verify judges) and 50 % quantiles and the RMS of the track
residuals (px) and the median mask IoU. ``--json FILE`` writes ``{"settings": {...}, "rows": [{"seed", "pose",
"rot_rad", "trans_m", "p10_px", "p25_px", "median_px", "rms_px", "mask_iou", "tracks"}, ...]}`` (``pose``:
"true", "calibrated" or "moved"; rot_rad / trans_m: how far from the true pose, geodesic rad and m).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from arc_env.robot.recording import read_recording
from arc_env.robot.session import calibrate_recording
from arc_env.robot.verify import VerifyCriteria, check_tracked, track_recording
from arc_env.sim.record import RecordSettings, record_episode
from solver.frames import perturb, pose_errors


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--motions", type=int, default=8, help="motions per recording (default 8)")
    parser.add_argument("--size", default="640x360", help="image size WxH (default 640x360)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="episode seeds (default 0 1)")
    parser.add_argument("--realism", choices=("clean", "realistic"), default="clean", help="(default clean)")
    parser.add_argument("--sizes", type=float, nargs="+", default=[0.005, 0.02], metavar="S",
                        help="perturbations: S rad and S m each (default 0.005 0.02: 5 mrad / 5 mm, 20 mrad / 2 cm)")
    parser.add_argument("--directions", type=int, default=3, help="random directions per size (default 3)")
    parser.add_argument("--json", metavar="FILE", help="write the figures here")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    criteria = VerifyCriteria(min_tracks=1)
    rows = []
    print(f"{'seed':>4} {'pose':>10} {'rot mrad':>8} {'trans mm':>8} {'tracks':>6} {'p10 px':>7} {'p25 px':>7} "
          f"{'median px':>9} {'rms px':>8} {'IoU':>6}")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            out = Path(tmp) / f"rec_{seed}"
            t0 = time.perf_counter()
            truth = record_episode(RecordSettings(out=out, motions=args.motions, seed=seed, width=width, height=height,
                                                  realism=args.realism))
            T_true = np.asarray(truth["T_camera_base"], dtype=np.float64)
            recording = read_recording(out)
            t1 = time.perf_counter()
            run = calibrate_recording(recording)
            t2 = time.perf_counter()
            tracked = track_recording(recording)
            t3 = time.perf_counter()
            print(f"seed {seed}: recorded {t1 - t0:.0f} s, calibrated {t2 - t1:.0f} s, tracked {t3 - t2:.0f} s",
                  flush=True)
            poses = [("true", T_true)]
            if run.calibrator.state.T_camera_base is not None:
                poses.append(("calibrated", run.calibrator.state.T_camera_base))
            rng = np.random.default_rng(seed)
            for size in args.sizes:
                for _ in range(args.directions):
                    poses.append(("moved", perturb(T_true, np.concatenate([size * _unit(rng), size * _unit(rng)]))))
            for name, T in poses:
                report = check_tracked(recording, tracked, T, criteria)
                rot, trans = pose_errors(T, T_true)
                row = {"seed": seed, "pose": name, "rot_rad": rot, "trans_m": trans, "median_px": report.median_px,
                       "p10_px": report.quantile_px(0.1), "p25_px": report.quantile_px(0.25),
                       "rms_px": report.rms_px, "mask_iou": report.mask_iou, "tracks": int(report.track_rms_px.size)}
                rows.append(row)
                print(f"{seed:>4} {name:>10} {rot * 1e3:>8.2f} {trans * 1e3:>8.2f} {row['tracks']:>6} "
                      f"{row['p10_px']:>7.3f} {row['p25_px']:>7.3f} {row['median_px']:>9.3f} {row['rms_px']:>8.3f} "
                      f"{row['mask_iou']:>6.3f}", flush=True)
    print("\nmedian over seeds and directions:")
    for name, size in [("true", 0.0), ("calibrated", None), *[("moved", s) for s in args.sizes]]:
        pick = [r for r in rows if r["pose"] == name and (size is None or name != "moved"
                                                          or abs(r["rot_rad"] - size) < 1e-6)]
        if pick:
            label = name if name != "moved" else f"moved {size * 1e3:g} mrad / {size * 1e3:g} mm"
            print(f"  {label:>28}: p25 px {np.median([r['p25_px'] for r in pick]):.3f} (min "
                  f"{min(r['p25_px'] for r in pick):.3f}, max {max(r['p25_px'] for r in pick):.3f}), "
                  f"median px {np.median([r['median_px'] for r in pick]):.3f} (min "
                  f"{min(r['median_px'] for r in pick):.3f}, max {max(r['median_px'] for r in pick):.3f}), IoU "
                  f"{np.median([r['mask_iou'] for r in pick]):.3f} (min {min(r['mask_iou'] for r in pick):.3f}, max "
                  f"{max(r['mask_iou'] for r in pick):.3f})")
    if args.json:
        settings = {"motions": args.motions, "size": args.size, "seeds": args.seeds, "realism": args.realism,
                    "sizes": args.sizes, "directions": args.directions}
        Path(args.json).write_text(json.dumps({"settings": settings, "rows": rows}, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
