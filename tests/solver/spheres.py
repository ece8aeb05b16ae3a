"""Spheres ray-cast through a known camera: images, depth and exact occluding contours, for the outline tests."""

import numpy as np

from solver.frames import perturb, transform_from_rt
from solver.observations import CameraIntrinsics
from solver.outlines import ContourPoints

W, H = 640, 480
K = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
CAMERA = CameraIntrinsics(K, np.zeros(5), W, H)
#: A camera 1 m in front of the base, looking at it, tilted a little.
T_TRUE = perturb(transform_from_rt(np.eye(3), np.array([0.02, -0.01, 1.0])), np.array([0.05, -0.08, 0.02, 0, 0, 0]))


def render_spheres(T: np.ndarray, spheres, supersample: int = 4) -> np.ndarray:
    """(H, W) uint8: bright spheres on a dark background, ray-cast per sub-pixel and averaged."""
    s = supersample
    u = (np.arange(W * s) + 0.5) / s - 0.5
    v = (np.arange(H * s) + 0.5) / s - 0.5
    uu, vv = np.meshgrid(u, v)
    rays = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu)], -1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    hit = np.zeros(uu.shape, bool)
    for centre, radius in spheres:
        c = T[:3, :3] @ np.asarray(centre) + T[:3, 3]
        along = rays @ c
        hit |= np.sum(c * c) - along**2 < radius**2
    image = np.where(hit, 200.0, 50.0).reshape(H, s, W, s).mean(axis=(1, 3))
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def sphere_contour(T: np.ndarray, spheres, n: int = 720) -> ContourPoints:
    """The spheres' occluding circles seen from T: the tangent cone's circle of contact, in the base frame."""
    points, outward = [], []
    for centre, radius in spheres:
        c = T[:3, :3] @ np.asarray(centre) + T[:3, 3]
        d = np.linalg.norm(c)
        axis = c / d
        middle = c * (1 - radius**2 / d**2)
        rho = radius * np.sqrt(1 - radius**2 / d**2)
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        t = np.linspace(0, 2 * np.pi, n, endpoint=False)
        X = middle + rho * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
        normal = (X - c) / radius  # the sphere's outward normal there, across the ray
        step = image_px(X + 1e-4 * normal) - image_px(X)
        outward.append(step / np.linalg.norm(step, axis=1, keepdims=True))
        points.append((X - T[:3, 3]) @ T[:3, :3])
    # the test's spheres do not overlap in the image: no contour point is hidden
    return ContourPoints(np.concatenate(points), np.concatenate(outward))


def image_px(points_cam: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of camera-frame points (N, 3)."""
    return points_cam[:, :2] / points_cam[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]


def project_px(T, points_base):
    return image_px(points_base @ T[:3, :3].T + T[:3, 3])


def sphere_depth(T: np.ndarray, spheres) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) depth along the optical axis, metres, and the (H, W) mask of the spheres, ray-cast per pixel centre."""
    uu, vv = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu)], -1)  # z = 1
    depth = np.full(uu.shape, 100.0)
    for centre, radius in spheres:
        c = T[:3, :3] @ np.asarray(centre) + T[:3, 3]
        a = np.sum(rays * rays, -1)
        b = rays @ c
        disc = b**2 - a * (np.sum(c * c) - radius**2)
        z = np.where(disc >= 0, (b - np.sqrt(np.maximum(disc, 0))) / a, np.inf)
        depth = np.minimum(depth, z)
    return depth, depth < 100.0


