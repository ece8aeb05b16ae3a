"""Benchmark track_keypoints on a rendered 1920x1080 sweep: time per frame and points tracked.

A textured plate (radius 300 px) turns 0.8 rad about a point 200 px from its centre over a static noise
background (the plate covers and uncovers background corners), 40 frames with a smooth start and stop.
OpenCV and BLAS run on one thread. Prints, and with --json PATH writes:
{"ms_per_frame": {config: best of --repeats}, "points_per_frame": {...}, "tracks": {...},
 "median_error_px": {...}, "max_error_px": {...}}
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from arc_env.robot.tracking import TrackerConfig, track_keypoints  # noqa: E402

SIZE = (1080, 1920)
CENTRE = np.array([900.0, 540.0])
PLATE_CENTRE, PLATE_RADIUS = np.array([1100.0, 540.0]), 300.0
CONFIGS = {
    "default": TrackerConfig(),
    "no_redetect": TrackerConfig(redetect_every=0),
    "plain_lk": TrackerConfig(affine_iterations=0),
    "quadratic": TrackerConfig(quadratic_warp=True, window_sigma_px=0.0),
    "uniform": TrackerConfig(window_sigma_px=0.0),
}


def rotation_about(centre: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3): turn image points about centre by angle rad."""
    c, s = np.cos(angle), np.sin(angle)
    M = np.eye(3)
    M[:2, :2] = [[c, s], [-s, c]]
    M[:2, 2] = centre - M[:2, :2] @ centre
    return M


def render_sweep(rng: np.random.Generator, n_frames: int, rgb: bool) -> tuple[list[np.ndarray], np.ndarray]:
    """F frames (grey or RGB uint8) and (F,) delta, rad."""
    def noise() -> np.ndarray:
        image = cv2.GaussianBlur(rng.uniform(0, 255, SIZE).astype(np.float32), (0, 0), 2.0)
        return np.clip((image - image.mean()) / image.std() * 50 + 128, 0, 255).astype(np.float32)

    background, texture = noise(), noise()
    yy, xx = np.mgrid[0:SIZE[0], 0:SIZE[1]]
    alpha = ((xx - PLATE_CENTRE[0]) ** 2 + (yy - PLATE_CENTRE[1]) ** 2 <= PLATE_RADIUS**2).astype(np.float32)
    s = np.linspace(0.0, 1.0, n_frames)
    delta = 0.8 * s * s * (3 - 2 * s)
    frames = []
    for d in delta:
        M = rotation_about(CENTRE, d)[:2]
        a = cv2.warpAffine(alpha, M, SIZE[::-1])
        grey = np.clip(np.rint(a * cv2.warpAffine(texture, M, SIZE[::-1], flags=cv2.INTER_CUBIC)
                               + (1 - a) * background), 0, 255).astype(np.uint8)
        frames.append(cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB) if rgb else grey)
    return frames, delta


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=40, help="frames in the sweep (default 40)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per configuration; best counts (default 3)")
    parser.add_argument("--rgb", action="store_true", help="feed (H, W, 3) RGB frames")
    parser.add_argument("--json", type=Path, help="write the figures to this file")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    frames, delta = render_sweep(np.random.default_rng(0), args.frames, args.rgb)
    centre = CENTRE
    figures: dict[str, dict[str, float]] = {k: {} for k in ("ms_per_frame", "points_per_frame", "tracks",
                                                            "median_error_px", "max_error_px")}
    print(f"{'config':<12} {'ms/frame':>9} {'pts/frame':>10} {'tracks':>7} {'median px':>10} {'max px':>8}")
    for name, config in CONFIGS.items():
        results = [track_keypoints(frames, delta, config) for _ in range(args.repeats)]
        result = min(results, key=lambda r: r.seconds)
        errors = []
        for t in result.tracks:
            back = np.linalg.inv(rotation_about(centre, t.delta[0]))
            for p, d in zip(t.pixels, t.delta, strict=True):
                q = rotation_about(centre, d) @ back @ np.array([*t.pixels[0], 1.0])
                errors.append(np.hypot(*(p - q[:2])))
        row = {"ms_per_frame": 1e3 * result.seconds / len(frames),
               "points_per_frame": sum(len(t) for t in result.tracks) / len(frames),
               "tracks": len(result.tracks),
               "median_error_px": float(np.median(errors)) if errors else float("nan"),
               "max_error_px": float(np.max(errors)) if errors else float("nan")}
        for key, value in row.items():
            figures[key][name] = value
        print(f"{name:<12} {row['ms_per_frame']:9.1f} {row['points_per_frame']:10.0f} {row['tracks']:7d} "
              f"{row['median_error_px']:10.3f} {row['max_error_px']:8.3f}")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
