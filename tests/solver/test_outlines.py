"""solver.outlines: the camera pose from occluding contours, against spheres ray-cast through a known camera."""

import numpy as np
import pytest

from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.frames import perturb, pose_difference, transform_from_rt
from solver.observations import CameraIntrinsics
from solver.outlines import (
    ContourPoints,
    EdgePairs,
    ImageEdges,
    OutlineConfig,
    contour_from_depth,
    fit_outline_pose,
    image_edges,
    outline_residuals,
    outline_residuals_and_jacobian,
    pair_contour_points,
)
from tests.solver.spheres import CAMERA, T_TRUE, K, project_px, render_spheres, sphere_contour, sphere_depth

#: Two images of spheres (centre (3,) m in the base frame, radius m), as two frames of an arm would show its links.
SCENES = [[((0.0, 0.0, 0.0), 0.06), ((0.15, 0.05, 0.1), 0.04), ((-0.12, 0.08, -0.05), 0.05)],
          [((0.05, -0.1, 0.05), 0.05), ((-0.1, -0.05, 0.12), 0.045), ((0.12, 0.1, -0.1), 0.055)]]
#: Sub-pixel accuracy of the edges of an anti-aliased disk (noise-free, 4x4 supersampled, unblurred), pixels: the
#: parabola through neighbours' differences locks towards pixel positions on so sharp an edge (median |error| 0.13 px
#: on the disk below, its median signed error 0.03 px); any blur (a lens, motion, a video codec) lowers it.
EDGE_TOL_PX = 0.15
#: Bias of the edges of a shaded disk (a sphere lit from the camera: darker towards its outline), pixels.
SHADED_BIAS_PX = 0.12
#: The pose recovered from noise-free outlines: rad, metres (the sampled contour and the supersampling leave less).
ROT_TOL, TRANS_TOL = 5e-4, 3e-4


def _model(T: np.ndarray) -> list[ContourPoints]:
    return [sphere_contour(T, spheres) for spheres in SCENES]


@pytest.fixture(scope="module")
def edges() -> list[ImageEdges]:
    return [image_edges(render_spheres(T_TRUE, spheres)) for spheres in SCENES]


def test_edges_of_an_antialiased_disk_are_subpixel():
    T = transform_from_rt(np.eye(3), np.array([0.0, 0.0, 1.0]))
    found = image_edges(render_spheres(T, [((0.0, 0.0, 0.0), 0.1)]))
    # the disk's image: centre at the principal point, radius f r / sqrt(d^2 - r^2)
    radius = 600.0 * 0.1 / np.sqrt(1.0 - 0.01)
    off = np.linalg.norm(found.points - K[:2, 2], axis=1) - radius
    assert len(found.points) > 2 * np.pi * radius * 0.9
    assert np.median(np.abs(off)) < EDGE_TOL_PX
    assert abs(np.median(off)) < 0.05  # unbiased
    # normals point from the dark outside to the bright disk: inwards
    radial = (found.points - K[:2, 2]) / np.linalg.norm(found.points - K[:2, 2], axis=1, keepdims=True)
    assert np.median(np.sum(found.normals * radial, axis=1)) < -0.95


@pytest.mark.parametrize("shape", [(7, 9), (1, 5), (4, 1)])
def test_bilinear_samples_as_scipys_map_coordinates(shape):
    from scipy.ndimage import map_coordinates

    from solver.outlines import _bilinear

    rng = np.random.default_rng(3)
    image = rng.uniform(0.0, 255.0, shape).astype(np.float32)
    # inside, on the last row and column, and beyond every border (the nearest border pixel's value there)
    rows = np.concatenate([rng.uniform(-3.0, shape[0] + 2.0, 500), [shape[0] - 1.0, 0.0]])
    cols = np.concatenate([rng.uniform(-3.0, shape[1] + 2.0, 500), [shape[1] - 1.0, 0.0]])
    expected = map_coordinates(image.astype(np.float64), [rows, cols], order=1, mode="nearest")
    np.testing.assert_allclose(_bilinear(image, rows, cols), expected, atol=1e-4)


def test_edges_of_tiny_images_do_not_fail():
    for shape in [(1, 1), (1, 6), (6, 1), (2, 2)]:
        image = np.zeros(shape, np.uint8)
        image[..., shape[-1] // 2:] = 200
        found = image_edges(image)
        assert np.all(np.isfinite(found.points)) and found.points.shape == found.normals.shape


def _shaded_disk(inside: float, outside: float, blur_px: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(H, W) uint8 image of a Lambertian sphere lit from the camera (half its brightness from shading), 8x8
    supersampled and blurred; its centre (2,) and radius, pixels."""
    import cv2

    s, radius, centre = 8, 80.0, np.array([240.37, 240.21])
    u = (np.arange(480 * s) + 0.5) / s - 0.5
    uu, vv = np.meshgrid(u, u)
    rr = np.hypot(uu - centre[0], vv - centre[1])
    facing = np.sqrt(1.0 - np.clip(rr / radius, 0.0, 1.0) ** 2)  # the normal's component towards the camera
    image = np.where(rr < radius, inside * (0.5 + 0.5 * facing), outside).reshape(480, s, 480, s).mean(axis=(1, 3))
    return np.clip(np.rint(cv2.GaussianBlur(image, (0, 0), blur_px)), 0, 255).astype(np.uint8), centre, radius


@pytest.mark.parametrize(("inside", "outside"), [(200.0, 50.0), (60.0, 200.0)],
                         ids=["bright-robot", "bright-background"])
def test_edges_of_a_shaded_disk_lie_near_its_outline(inside, outside):
    """Shading that darkens a surface towards its outline pulls a wide gradient's peak inside (Sobel's: 0.15 px)."""
    grey, centre, radius = _shaded_disk(inside, outside, blur_px=0.5)
    found = image_edges(grey)
    off = np.linalg.norm(found.points - centre, axis=1) - radius
    assert len(found.points) > 2 * np.pi * radius * 0.9
    assert abs(np.median(off)) < SHADED_BIAS_PX


def test_pairs_carry_the_edges_polarity(edges):
    """+1 where the image is brighter outside the contour: the test's spheres are bright on a dark background."""
    pairs = pair_contour_points(T_TRUE, _model(T_TRUE), edges, CAMERA, OutlineConfig())
    assert pairs.polarity is not None and len(pairs.polarity) == len(pairs.points_base) > 0
    assert np.all(pairs.polarity == -1.0)
    flipped = [ImageEdges(e.points, -e.normals) for e in edges]  # dark spheres on a bright background
    assert np.all(pair_contour_points(T_TRUE, _model(T_TRUE), flipped, CAMERA, OutlineConfig()).polarity == 1.0)


@pytest.mark.parametrize("blur_px", [0.0, 1.0])
def test_edge_strengths_are_the_contrast_across_the_edge(blur_px):
    """A step of c grey levels: each edge's strength is its largest neighbour difference, proportional to c."""
    import cv2

    def strengths(low: float, high: float) -> np.ndarray:
        ramp = np.clip(np.arange(200) - 99.6, 0.0, 1.0)  # a vertical step at column 99.6 + 0.5 (pixel centres)
        image = np.tile(low + (high - low) * ramp, (120, 1))
        if blur_px:
            image = cv2.GaussianBlur(image, (0, 0), blur_px)
        found = image_edges(np.clip(np.rint(image), 0, 255).astype(np.uint8))
        assert found.strengths is not None and len(found.strengths) == len(found.points) > 100
        return found.strengths

    weak, strong = strengths(80.0, 120.0), strengths(40.0, 200.0)
    assert np.median(strong) / np.median(weak) == pytest.approx(4.0, rel=0.1)
    assert np.median(strong) <= 160.0 and np.median(strong) > (45.0 if blur_px else 90.0)  # 0.38 c, 0.6 c


def test_pairs_carry_the_edges_strength(edges):
    pairs = pair_contour_points(T_TRUE, _model(T_TRUE), edges, CAMERA, OutlineConfig())
    assert pairs.strength is not None and len(pairs.strength) == len(pairs.points_base) > 0
    idx, _ = edges[0].nearest(pairs.edge_points[pairs.image == 0], 1e-9)
    assert edges[0].strengths is not None
    np.testing.assert_array_equal(pairs.strength[pairs.image == 0], edges[0].strengths[idx])
    without = [ImageEdges(e.points, e.normals) for e in edges]  # edges made otherwise: no contrast, no strength
    assert pair_contour_points(T_TRUE, _model(T_TRUE), without, CAMERA, OutlineConfig()).strength is None
    with pytest.raises(InvalidInputError, match="strengths"):
        ImageEdges(edges[0].points, edges[0].normals, np.ones(len(edges[0].points) + 1))
    with pytest.raises(InvalidInputError, match="strengths"):
        ImageEdges(edges[0].points[:1], edges[0].normals[:1], np.array([np.nan]))


def test_contours_lie_on_the_edges_at_the_true_pose(edges):
    contours = _model(T_TRUE)
    for contour, image in zip(contours, edges, strict=True):
        idx, found = image.nearest(project_px(T_TRUE, contour.points_base), 3.0)
        assert found.mean() > 0.99
        r = outline_residuals(T_TRUE, contour.points_base[found], image.points[idx[found]],
                              image.normals[idx[found]], CAMERA)
        assert np.median(np.abs(r)) < EDGE_TOL_PX


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


def test_an_image_without_edges_pairs_nothing(edges):
    contour = _model(T_TRUE)[0]
    blank = ImageEdges(np.zeros((0, 2)), np.zeros((0, 2)))
    pairs = pair_contour_points(T_TRUE, [contour, contour], [blank, edges[0]], CAMERA, OutlineConfig())
    alone = pair_contour_points(T_TRUE, [contour], [edges[0]], CAMERA, OutlineConfig())
    assert len(pairs.points_base) == len(alone.points_base) > 0
    assert len(pair_contour_points(T_TRUE, [contour], [blank], CAMERA, OutlineConfig()).points_base) == 0
    # the points in front are counted with or without edges: every point of both images, the camera looking at them
    assert pairs.in_front == 2 * alone.in_front == 2 * len(contour.points_base)
    behind = perturb(T_TRUE, np.array([0, 0, 0, 0, 0, -5.0]))  # the camera 5 m forward: the robot behind it
    assert pair_contour_points(behind, [contour], [edges[0]], CAMERA, OutlineConfig()).in_front == 0


def test_pairs_of_several_images_are_each_images_own_in_order(edges):
    """Pairing every image at once (one projection) gives each image's own pairs, labelled with its index."""
    T = perturb(T_TRUE, np.array([0.004, -0.002, 0.003, 0.002, -0.003, 0.004]))
    contours = _model(T)
    together = pair_contour_points(T, contours, edges, CAMERA, OutlineConfig())
    alone = [pair_contour_points(T, [c], [e], CAMERA, OutlineConfig()) for c, e in zip(contours, edges, strict=True)]
    assert len(contours) >= 2 and all(len(a.points_base) > 0 for a in alone)
    np.testing.assert_array_equal(together.image, np.concatenate([np.full(len(a.points_base), i)
                                                                  for i, a in enumerate(alone)]))
    for name in ("points_base", "edge_points", "normals", "polarity", "strength"):
        np.testing.assert_array_equal(getattr(together, name), np.concatenate([getattr(a, name) for a in alone]))
    assert together.in_front == sum(a.in_front for a in alone)
    empty = pair_contour_points(T, [], [], CAMERA, OutlineConfig())
    assert len(empty.points_base) == 0 and empty.in_front == 0
    with pytest.raises(InvalidInputError, match="2 contours for 1 edge images"):
        pair_contour_points(T, contours[:2], edges[:1], CAMERA, OutlineConfig())


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


#: A contour point from a depth image lies on the pixel boundary nearest the true outline: within this, pixels.
BOUNDARY_TOL_PX = 0.75


def test_contour_from_depth_traces_the_true_outline():
    T = transform_from_rt(np.eye(3), np.array([0.0, 0.0, 1.0]))
    depth, mask = sphere_depth(T, [((0.0, 0.0, 0.0), 0.1)])
    contour = contour_from_depth(depth, mask, T, K)
    px = project_px(T, contour.points_base)
    radius = 600.0 * 0.1 / np.sqrt(1.0 - 0.01)
    r = np.linalg.norm(px - K[:2, 2], axis=1)
    assert len(px) > 2 * np.pi * radius
    assert np.max(np.abs(r - radius)) < BOUNDARY_TOL_PX
    radial = (px - K[:2, 2]) / r[:, None]
    assert np.all(np.sum(contour.outward * radial, axis=1) > 0)  # outward: away from the disk
    assert len(contour_from_depth(depth, mask, T, K, stride=4).points_base) < len(px) / 3


def test_a_model_cut_by_the_image_border_has_no_contour_along_it():
    # the sphere's centre projects 20 px inside the left border: its disk runs off the image there
    centre = np.array([(20.0 - K[0, 2]) / K[0, 0], 0.0, 0.0])
    T = transform_from_rt(np.eye(3), np.array([0.0, 0.0, 1.0]))
    depth, mask = sphere_depth(T, [(tuple(centre), 0.1)])
    assert mask[:, 0].any()
    points = contour_from_depth(depth, mask, T, K).points_base
    px = project_px(T, points)
    # every contour point's ray grazes the sphere (its distance from the centre is the radius, to a pixel's
    # width at 1 m: 1.7 mm)
    cam, centre_cam = points + T[:3, 3], centre + T[:3, 3]  # the camera frame (T turns nothing)
    rays = cam / np.linalg.norm(cam, axis=1, keepdims=True)
    miss = np.linalg.norm(centre_cam - (rays @ centre_cam)[:, None] * rays, axis=1)
    assert np.max(np.abs(miss - 0.1)) < 1.7e-3
    assert px[:, 0].min() > -0.25 and len(px) > 150  # the arc inside the image, none at u = -0.5 along the border
    assert len(contour_from_depth(depth, np.zeros_like(mask), T, K).points_base) == 0  # no model, no contour


def test_the_pose_is_recovered_with_contours_from_rendered_depth(edges):
    def model(T):
        return [contour_from_depth(*sphere_depth(T, spheres), T, K) for spheres in SCENES]

    fit = fit_outline_pose(perturb(T_TRUE, np.array([2e-3, -1e-3, 1.5e-3, 3e-3, -2e-3, 8e-3])), edges, model, CAMERA)
    err = pose_difference(fit.T_camera_base, T_TRUE)
    assert np.linalg.norm(err[:3]) < 2 * ROT_TOL
    assert np.linalg.norm(err[3:]) < 2 * TRANS_TOL


def test_contour_from_depth_refuses_mismatched_images():
    with pytest.raises(InvalidInputError, match="one shape"):
        contour_from_depth(np.zeros((4, 4)), np.zeros((4, 5), bool), np.eye(4), K)


@pytest.mark.parametrize("camera", ["pinhole", "distorted", "fisheye"])
def test_the_outline_jacobian_is_the_finite_differences(camera):
    intrinsics = {"pinhole": CAMERA,
                  "distorted": CameraIntrinsics(K, np.array([0.08, -0.02, 0.001, 0.0005, 0.0]), 640, 480),
                  "fisheye": CameraIntrinsics(K, np.array([0.02, -0.01, 0.003, 0.0]), 640, 480, model="fisheye"),
                  }[camera]
    rng = np.random.default_rng(3)
    pairs = EdgePairs(rng.uniform(-0.15, 0.15, (40, 3)), rng.uniform(100, 500, (40, 2)),
                      (lambda n: n / np.linalg.norm(n, axis=1, keepdims=True))(rng.normal(size=(40, 2))))
    r, J = outline_residuals_and_jacobian(T_TRUE, pairs, intrinsics)
    np.testing.assert_allclose(r, outline_residuals(T_TRUE, pairs.points_base, pairs.edge_points, pairs.normals,
                                                    intrinsics), atol=1e-9)
    h = 1e-6

    def at(xi):
        return outline_residuals(perturb(T_TRUE, xi), pairs.points_base, pairs.edge_points, pairs.normals, intrinsics)

    for k in range(6):
        xi = np.zeros(6)
        xi[k] = h
        numeric = (at(xi) - at(-xi)) / (2 * h)
        np.testing.assert_allclose(J[:, k], numeric, rtol=1e-4, atol=1e-3)
