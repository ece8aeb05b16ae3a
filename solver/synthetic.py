"""Synthetic exploratory motions: a DH robot with keypoints on its links, seen by a known camera.

Built independently of the estimation code: keypoints are 3-D points fixed on the links, moved by
the robot's forward kinematics and projected with ``cv2.projectPoints``; nothing here fits conics or
circles. Used by the tests, ``scripts/bench_solver.py`` and ``arc-calib demo --synthetic``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from solver.arrays import FloatArray
from solver.camera import in_image, pixels_from_camera_points
from solver.errors import InvalidInputError
from solver.frames import transform_from_rt
from solver.kinematics import DHChain
from solver.observations import CameraIntrinsics, KeypointTrack, MotionObservation


def d415_intrinsics(width: int = 1920, height: int = 1080) -> CameraIntrinsics:
    """A RealSense-D415-like colour camera (fx = fy = 1380 px at 1920x1080), no distortion."""
    f = 1380.0 * width / 1920.0
    return CameraIntrinsics.from_fov(f, width, height)


def look_at(eye: FloatArray, target: FloatArray, roll: float = 0.0) -> FloatArray:
    """T_camera_base of a camera at ``eye`` (base frame, m) looking at ``target``, rolled by ``roll``.

    The camera's y axis (down in the image) points as close to base -z as the view allows; roll
    turns the camera about its optical axis (rad).
    """
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(np.array([0.0, 0.0, -1.0]), z)  # x = y x z with y as close to "down" as z allows
    if np.linalg.norm(x) < 1e-6:
        x = np.cross(np.array([0.0, 1.0, 0.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    x, y = c * x + s * y, -s * x + c * y
    R_base_camera = np.column_stack([x, y, z])
    R = R_base_camera.T
    return transform_from_rt(R, -R @ np.asarray(eye, float))


def sample_camera_pose(rng: np.random.Generator, target: FloatArray = (0.35, 0.0, 0.45),
                       distance: tuple[float, float] = (1.0, 2.5), max_roll: float = 0.3) -> FloatArray:
    """A random T_camera_base around the robot: 1-2.5 m from the workspace, looking at it."""
    azimuth = rng.uniform(-np.pi, np.pi)
    elevation = rng.uniform(0.05, 0.9)
    r = rng.uniform(*distance)
    target = np.asarray(target, float)
    eye = target + r * np.array([np.cos(elevation) * np.cos(azimuth),
                                 np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    eye[2] = max(eye[2], 0.2)
    jitter = rng.normal(0.0, 0.05, 3)
    return look_at(eye, target + jitter, rng.uniform(-max_roll, max_roll))


@dataclass(frozen=True)
class SyntheticConfig:
    """How synthetic motions are made.

    Attributes:
        keypoints_per_link: feature points fixed on each link.
        link_radius: m; points lie within this distance of the link's segment.
        tracks_per_motion: at most this many tracked keypoints per motion.
        frames_per_motion: frames over the sweep.
        noise_px: standard deviation of the Gaussian pixel noise.
        outlier_fraction: fraction of tracks replaced by tracker failures (drift or a jump).
        delta_range: rad; |Delta| is uniform in this range.
        min_visible_tracks: a motion with fewer visible moving keypoints is re-drawn.
        image_margin: px; keypoints closer to the border count as not visible.
    """

    keypoints_per_link: int = 40
    link_radius: float = 0.06
    tracks_per_motion: int = 40
    frames_per_motion: int = 30
    noise_px: float = 0.5
    outlier_fraction: float = 0.1
    delta_range: tuple[float, float] = (0.5, 1.2)
    min_visible_tracks: int = 8
    image_margin: float = 10.0

    def __post_init__(self) -> None:
        if self.frames_per_motion < 6 or self.tracks_per_motion < 1:
            raise InvalidInputError("need frames_per_motion >= 6 and tracks_per_motion >= 1")
        if not 0 <= self.outlier_fraction < 1 or self.noise_px < 0:
            raise InvalidInputError("outlier_fraction must be in [0, 1) and noise_px >= 0")


@dataclass(frozen=True)
class SyntheticMotion:
    """A synthetic motion with its ground truth.

    Attributes:
        observation: what the solver sees.
        outliers: (L,) bool: which tracks were corrupted.
        points_base: (L, 3) float64, m: each track's keypoint at the start configuration.
        delta: float: the commanded Delta, rad.
    """

    observation: MotionObservation
    outliers: NDArray[np.bool_]
    points_base: FloatArray
    delta: float


class SyntheticScene:
    """A DH robot with random feature points on its links and a camera at a known pose."""

    def __init__(self, chain: DHChain, intrinsics: CameraIntrinsics, T_camera_base: FloatArray,
                 config: SyntheticConfig | None = None, rng: np.random.Generator | None = None):
        self.chain = chain
        self.intrinsics = intrinsics
        self.T_camera_base = np.asarray(T_camera_base, dtype=np.float64)
        self.config = config or SyntheticConfig()
        rng = rng if rng is not None else np.random.default_rng(0)
        self.link_points = self._sample_link_points(rng)

    def _sample_link_points(self, rng: np.random.Generator) -> list[FloatArray]:
        """Points fixed on each link i (in joint frame i): around the segment to the next origin."""
        frames = self.chain.frames(np.zeros(self.chain.n_joints))
        out = []
        for i in range(self.chain.n_joints):
            inv = np.linalg.inv(frames[i])
            nxt = (inv @ frames[i + 1][:, 3])[:3]
            s = rng.uniform(0.0, 1.0, self.config.keypoints_per_link)[:, None]
            offsets = rng.normal(size=(self.config.keypoints_per_link, 3))
            offsets *= (self.config.link_radius * rng.uniform(0.5, 1.0, (offsets.shape[0], 1))
                        / np.linalg.norm(offsets, axis=1, keepdims=True))
            out.append(s * nxt + offsets)
        return out

    def project(self, points_base: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Pixels (M, 2) and depths (M,) of base-frame points (M, 3)."""
        pc = points_base @ self.T_camera_base[:3, :3].T + self.T_camera_base[:3, 3]
        return pixels_from_camera_points(pc, self.intrinsics), pc[:, 2]

    def keypoints_base(self, q: FloatArray, first_link: int) -> tuple[FloatArray, FloatArray]:
        """All keypoints on links >= first_link at q: positions (K, 3) and their link index (K,)."""
        frames = self.chain.frames(q)
        pts, links = [], []
        for i in range(first_link, self.chain.n_joints):
            p = self.link_points[i]
            pts.append(p @ frames[i][:3, :3].T + frames[i][:3, 3])
            links.append(np.full(p.shape[0], i))
        return np.concatenate(pts), np.concatenate(links)

    def simulate(self, q_start: FloatArray, joint: int, delta: float,
                 rng: np.random.Generator) -> SyntheticMotion | None:
        """Sweep ``joint`` by ``delta`` from ``q_start``; None when too few keypoints stay in view."""
        cfg = self.config
        deltas = np.linspace(0.0, delta, cfg.frames_per_motion)
        pix, depth = [], []
        for d in deltas:
            q = q_start.copy()
            q[joint] += d
            p, _ = self.keypoints_base(q, joint)
            uv, z = self.project(p)
            pix.append(uv)
            depth.append(z)
        pix_a, depth_a = np.stack(pix, axis=1), np.stack(depth, axis=1)  # (K, M, 2), (K, M)
        inside = (depth_a > 0.1).all(axis=1) & in_image(pix_a, self.intrinsics, cfg.image_margin).all(axis=1)
        candidates = np.flatnonzero(inside)
        if candidates.size < cfg.min_visible_tracks:
            return None
        chosen = rng.choice(candidates, min(cfg.tracks_per_motion, candidates.size), replace=False)
        start_points, _ = self.keypoints_base(q_start, joint)
        n_out = int(round(cfg.outlier_fraction * chosen.size))
        outliers = np.zeros(chosen.size, dtype=bool)
        outliers[rng.choice(chosen.size, n_out, replace=False)] = True
        tracks = []
        M = cfg.frames_per_motion
        for slot, k in enumerate(chosen):
            uv = pix_a[k] + rng.normal(0.0, cfg.noise_px, (M, 2))
            if outliers[slot]:
                direction = rng.normal(size=2)
                direction /= np.linalg.norm(direction)
                if rng.uniform() < 0.5:  # slow drift off the feature
                    uv += np.linspace(0, 1, M)[:, None] * direction * rng.uniform(4.0, 15.0)
                else:  # jump to a neighbouring feature
                    start = rng.integers(M // 4, 3 * M // 4)
                    uv[start:] += direction * rng.uniform(4.0, 15.0)
            first = rng.integers(0, M // 5 + 1)
            last = M - rng.integers(0, M // 5 + 1)
            tracks.append(KeypointTrack(uv[first:last], deltas[first:last]))
        obs = MotionObservation(q_start=q_start.copy(), joint=joint, tracks=tuple(tracks))
        return SyntheticMotion(obs, outliers, start_points[chosen], float(delta))

    def random_motion(self, rng: np.random.Generator, joints: tuple[int, ...] | None = None,
                      max_tries: int = 200) -> SyntheticMotion:
        """A random exploratory motion (random Q, J, Delta within limits) with enough keypoints in view.

        Raises:
            InvalidInputError: no such motion was found in ``max_tries`` draws.
        """
        joints = tuple(range(self.chain.n_joints)) if joints is None else joints
        lo, hi = self.chain.lower, self.chain.upper
        mid, half = (lo + hi) / 2, (hi - lo) / 2
        for _ in range(max_tries):
            q = mid + rng.uniform(-0.8, 0.8, lo.shape) * half
            j = int(rng.choice(joints))
            delta = rng.uniform(*self.config.delta_range) * rng.choice([-1.0, 1.0])
            if not lo[j] <= q[j] + delta <= hi[j]:
                delta = -delta
            if not lo[j] <= q[j] + delta <= hi[j]:
                continue
            motion = self.simulate(q, j, delta, rng)
            if motion is not None:
                return motion
        raise InvalidInputError(f"no motion with {self.config.min_visible_tracks} visible keypoints "
                                f"in {max_tries} draws: is the robot in the camera's view?")
