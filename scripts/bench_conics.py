"""Shared-orientation (Eq. 9-11) vs independent conic fits: how far their circle normals are from the truth.

For random synthetic Panda motions, every trajectory's two axis candidates (Eq. 14) from each fit are
compared with the true camera-frame axis (the nearer candidate counts), noise-free (the shared model's
perspective bias) and with 0.5 px noise. Also reports the fraction of trajectories whose conic is a valid
ellipse, and the axis error after the full per-motion estimation with either fit. Prints a table; --json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from solver import (
    PANDA,
    ArcCalibError,
    MotionConfig,
    SyntheticConfig,
    SyntheticScene,
    d415_intrinsics,
    estimate_motion_geometry,
    fit_conics_independent,
    fit_conics_shared,
    sample_camera_pose,
)
from solver.camera import normalized_from_pixels, rays_from_normalized
from solver.circle_normals import axis_candidates


def measure(noise: float, n_motions: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    K = d415_intrinsics()
    out: dict = {f: {"cand_err": [], "valid": [], "motion_err": []} for f in ("shared", "independent")}
    for _ in range(n_motions):
        T = sample_camera_pose(rng)
        scene = SyntheticScene(PANDA, K, T, SyntheticConfig(noise_px=noise, outlier_fraction=0.0), rng)
        m = scene.random_motion(rng)
        a_b, _ = PANDA.axis_and_point(m.observation.q_start, m.observation.joint)
        a_true = T[:3, :3] @ a_b
        uv = [normalized_from_pixels(t.pixels, K) for t in m.observation.tracks]
        for name, fitter in (("shared", fit_conics_shared), ("independent", fit_conics_independent)):
            fits = fitter(uv)
            for fit, track, u in zip(fits, m.observation.tracks, uv, strict=True):
                out[name]["valid"].append(fit.ok)
                if fit.ok:
                    try:
                        c = axis_candidates(fit.matrix, rays_from_normalized(u), track.delta)
                    except ArcCalibError:
                        continue
                    out[name]["cand_err"].append(float(np.min(np.arccos(np.clip(c @ a_true, -1, 1)))))
            try:
                g = estimate_motion_geometry(m.observation, K, MotionConfig(conic_fit=name))
                out[name]["motion_err"].append(float(np.arccos(np.clip(g.axis_cam @ a_true, -1, 1))))
            except ArcCalibError:
                pass
    return {name: {"candidate_axis_err_median_rad": float(np.median(v["cand_err"])) if v["cand_err"] else None,
                   "valid_ellipse_fraction": float(np.mean(v["valid"])),
                   "motion_axis_err_median_rad": float(np.median(v["motion_err"])) if v["motion_err"] else None,
                   "motions_with_axis": len(v["motion_err"])}
            for name, v in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--motions", type=int, default=40, help="random motions per noise level (default 40)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    result = {f"noise_{n}px": measure(n, args.motions, args.seed) for n in (0.0, 0.5)}
    print(f"{'noise':>9} {'fit':>12} {'candidate err (rad)':>20} {'valid ellipses':>15} "
          f"{'motion axis err (rad)':>22} {'motions':>8}")
    for level, fits in result.items():
        for name, r in fits.items():
            cand = r["candidate_axis_err_median_rad"]
            mot = r["motion_axis_err_median_rad"]
            print(f"{level:>9} {name:>12} {cand if cand is None else f'{cand:.2e}':>20} "
                  f"{r['valid_ellipse_fraction']:>15.2f} {mot if mot is None else f'{mot:.2e}':>22} "
                  f"{r['motions_with_axis']:>8}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
