"""solver.outlines: the camera pose from occluding contours, against spheres ray-cast through a known camera."""

import numpy as np
import pytest

from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.frames import perturb, pose_difference, transform_from_rt
from solver.observations import CameraIntrinsics
from solver.outlines import (
    ContourPoints,
    ImageEdges,
    OutlineConfig,
    contour_from_depth,
    fit_outline_pose,
    image_edges,
    outline_residuals,
)

W, H = 640, 480
K = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
CAMERA = CameraIntrinsics(K, np.zeros(5), W, H)
#: A camera 1 m in front of the base, looking at it, tilted a little.
T_TRUE = perturb(transform_from_rt(np.eye(3), np.array([0.02, -0.01, 1.0])), np.array([0.05, -0.08, 0.02, 0, 0, 0]))
#: Two images of spheres (centre (3,) m in the base frame, radius m), as two frames of an arm would show its links.
SCENES = [[((0.0, 0.0, 0.0), 0.06), ((0.15, 0.05, 0.1), 0.04), ((-0.12, 0.08, -0.05), 0.05)],
          [((0.05, -0.1, 0.05), 0.05), ((-0.1, -0.05, 0.12), 0.045), ((0.12, 0.1, -0.1), 0.055)]]
#: Sub-pixel accuracy of the edges of an anti-aliased disk (noise-free, 4x4 supersampled), pixels.
EDGE_TOL_PX = 0.1
#: The pose recovered from noise-free outlines: rad, metres (the sampled contour and the supersampling leave less).
ROT_TOL, TRANS_TOL = 5e-4, 3e-4


def _render(T: np.ndarray, spheres, supersample: int = 4) -> np.ndarray:
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


def _contour(T: np.ndarray, spheres, n: int = 720) -> ContourPoints:
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
        step = _image(X + 1e-4 * normal) - _image(X)
        outward.append(step / np.linalg.norm(step, axis=1, keepdims=True))
        points.append((X - T[:3, 3]) @ T[:3, :3])
    # the test's spheres do not overlap in the image: no contour point is hidden
    return ContourPoints(np.concatenate(points), np.concatenate(outward))


def _image(points_cam: np.ndarray) -> np.ndarray:
    """(N, 2) pixels of camera-frame points (N, 3)."""
    return points_cam[:, :2] / points_cam[:, 2:] * [K[0, 0], K[1, 1]] + K[:2, 2]


def _model(T: np.ndarray) -> list[ContourPoints]:
    return [_contour(T, spheres) for spheres in SCENES]


@pytest.fixture(scope="module")
def edges() -> list[ImageEdges]:
    return [image_edges(_render(T_TRUE, spheres)) for spheres in SCENES]


def test_edges_of_an_antialiased_disk_are_subpixel():
    T = transform_from_rt(np.eye(3), np.array([0.0, 0.0, 1.0]))
    found = image_edges(_render(T, [((0.0, 0.0, 0.0), 0.1)]))
    # the disk's image: centre at the principal point, radius f r / sqrt(d^2 - r^2)
    radius = 600.0 * 0.1 / np.sqrt(1.0 - 0.01)
    off = np.linalg.norm(found.points - K[:2, 2], axis=1) - radius
    assert len(found.points) > 2 * np.pi * radius * 0.9
    assert np.median(np.abs(off)) < EDGE_TOL_PX
    # normals point from the dark outside to the bright disk: inwards
    radial = (found.points - K[:2, 2]) / np.linalg.norm(found.points - K[:2, 2], axis=1, keepdims=True)
    assert np.median(np.sum(found.normals * radial, axis=1)) < -0.95


def test_contours_lie_on_the_edges_at_the_true_pose(edges):
    contours = _model(T_TRUE)
    for contour, image in zip(contours, edges, strict=True):
        idx, found = image.nearest(_project_px(T_TRUE, contour.points_base), 3.0)
        assert found.mean() > 0.99
        r = outline_residuals(T_TRUE, contour.points_base[found], image.points[idx[found]],
                              image.normals[idx[found]], CAMERA)
        assert np.median(np.abs(r)) < EDGE_TOL_PX


def _project_px(T, points_base):
    return _image(points_base @ T[:3, :3].T + T[:3, 3])


@pytest.mark.parametrize("start", [np.array([2e-3, -1e-3, 1.5e-3, 3e-3, -2e-3, 8e-3]),
                                   np.array([-3e-3, 2e-3, 0.0, -4e-3, 3e-3, -6e-3])], ids=["a", "b"])
def test_the_pose_is_recovered_from_a_perturbed_start(edges, start):
    T0 = perturb(T_TRUE, start)
    fit = fit_outline_pose(T0, edges, _model, CAMERA)
    err = pose_difference(fit.T_camera_base, T_TRUE)
    assert np.linalg.norm(err[:3]) < ROT_TOL
    assert np.linalg.norm(err[3:]) < TRANS_TOL
    assert fit.n_pairs > 0.9 * sum(len(c.points_base) for c in _model(T_TRUE))
    assert fit.median_abs_px < EDGE_TOL_PX


def test_outlines_the_images_do_not_show_raise(edges):
    far = perturb(T_TRUE, np.array([0, 0, 0, 2.0, 0, 0]))  # every outline out of the image
    with pytest.raises(InsufficientMotionsError, match="contour points lie within"):
        fit_outline_pose(far, edges, _model, CAMERA)


def test_bad_inputs_are_refused(edges):
    with pytest.raises(InvalidInputError, match="T_init"):
        fit_outline_pose(np.full((4, 4), np.nan), edges, _model, CAMERA)
    with pytest.raises(InvalidInputError, match="at least one image"):
        fit_outline_pose(T_TRUE, [], _model, CAMERA)
    with pytest.raises(InvalidInputError, match="1 contours for 2 images"):
        fit_outline_pose(T_TRUE, edges, lambda T: _model(T)[:1], CAMERA)
    with pytest.raises(InvalidInputError, match="uint8"):
        image_edges(np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(InvalidInputError, match="finite"):
        ContourPoints(np.full((2, 3), np.nan), np.zeros((2, 2)))
    with pytest.raises(InvalidInputError):
        OutlineConfig(max_normal_angle_deg=0.0)


def _depth(T: np.ndarray, spheres) -> tuple[np.ndarray, np.ndarray]:
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


#: A contour point from a depth image lies on the pixel boundary nearest the true outline: within this, pixels.
BOUNDARY_TOL_PX = 0.75


def test_contour_from_depth_traces_the_true_outline():
    T = transform_from_rt(np.eye(3), np.array([0.0, 0.0, 1.0]))
    depth, mask = _depth(T, [((0.0, 0.0, 0.0), 0.1)])
    contour = contour_from_depth(depth, mask, T, K)
    px = _project_px(T, contour.points_base)
    radius = 600.0 * 0.1 / np.sqrt(1.0 - 0.01)
    r = np.linalg.norm(px - K[:2, 2], axis=1)
    assert len(px) > 2 * np.pi * radius
    assert np.max(np.abs(r - radius)) < BOUNDARY_TOL_PX
    radial = (px - K[:2, 2]) / r[:, None]
    assert np.all(np.sum(contour.outward * radial, axis=1) > 0)  # outward: away from the disk
    assert len(contour_from_depth(depth, mask, T, K, stride=4).points_base) < len(px) / 3


def test_the_pose_is_recovered_with_contours_from_rendered_depth(edges):
    def model(T):
        return [contour_from_depth(*_depth(T, spheres), T, K) for spheres in SCENES]

    fit = fit_outline_pose(perturb(T_TRUE, np.array([2e-3, -1e-3, 1.5e-3, 3e-3, -2e-3, 8e-3])), edges, model, CAMERA)
    err = pose_difference(fit.T_camera_base, T_TRUE)
    assert np.linalg.norm(err[:3]) < 2 * ROT_TOL
    assert np.linalg.norm(err[3:]) < 2 * TRANS_TOL


def test_contour_from_depth_refuses_mismatched_images():
    with pytest.raises(InvalidInputError, match="one shape"):
        contour_from_depth(np.zeros((4, 4)), np.zeros((4, 5), bool), np.eye(4), K)
