"""solver.outline_fusion: the tracks' pose and the outlines adjusted together, on spheres seen by a known camera."""

from dataclasses import replace

import numpy as np
import pytest

from solver import outline_fusion
from solver.errors import InsufficientMotionsError, InvalidInputError, OutlineDisagreementError
from solver.frames import perturb, pose_difference
from solver.outline_fusion import (
    CoarseContours,
    OutlineAdjustment,
    OutlineFusionConfig,
    OutlineImage,
    consistent_prior_scale,
    disagreement_chi2,
)
from solver.outlines import (
    ContourPoints,
    ImageEdges,
    OutlineConfig,
    image_edges,
    outline_residuals,
    pair_contour_points,
)
from solver.refinement import conservative_covariance, few_clusters_factor
from tests.solver.spheres import CAMERA, T_TRUE, project_px, render_spheres, sphere_contour

#: Six motions' images (one each) of three spheres: centre (3,) m in the base frame, radius m.
_RNG = np.random.default_rng(7)
SCENES = [[(tuple(_RNG.uniform(-0.15, 0.15, 3)), float(_RNG.uniform(0.035, 0.05))) for _ in range(3)]
          for _ in range(6)]
#: The tracks' pose: 8 mm and a few mrad off, with a covariance so vague that the outlines decide.
START = np.array([2e-3, -1e-3, 1.5e-3, 3e-3, -2e-3, 8e-3])
VAGUE = np.diag([0.1, 0.1, 0.1, 0.2, 0.2, 0.2]) ** 2
#: The pose from noise-free outlines of six images: rad, metres.
ROT_TOL, TRANS_TOL = 5e-4, 3e-4
#: chi-square, 6 dof, 0.999: an honest covariance holds the error within it.
CHI2_999 = 22.46
#: The settings with no limit on how uncertain the prior may be (VAGUE moves the contours by metres' worth).
UNLIMITED = OutlineFusionConfig(max_prior_px=np.inf)


def _renderer(T: np.ndarray, q: np.ndarray):
    return sphere_contour(T, SCENES[int(q[0])])


@pytest.fixture(scope="module")
def edges() -> list[ImageEdges]:
    return [image_edges(render_spheres(T_TRUE, spheres)) for spheres in SCENES]


def _adjustment(edges, config=None, groups=None, renderer=_renderer) -> OutlineAdjustment:
    """The images as motions 0-5 (or ``groups``), their contours from ``renderer``."""
    adjustment = OutlineAdjustment(renderer, CAMERA, config or UNLIMITED)
    for k, image in enumerate(edges):
        adjustment.add(OutlineImage(image, np.array([float(k)]), k if groups is None else groups[k]))
    return adjustment


def _chi2(T, covariance) -> float:
    err = pose_difference(T, T_TRUE)
    return float(err @ np.linalg.solve(covariance, err))


def test_a_vague_prior_gives_the_outlines_pose(edges):
    fusion = _adjustment(edges).fuse(perturb(T_TRUE, START), VAGUE)
    err = pose_difference(fusion.T_camera_base, T_TRUE)
    assert np.linalg.norm(err[:3]) < ROT_TOL
    assert np.linalg.norm(err[3:]) < TRANS_TOL
    assert (fusion.n_images, fusion.n_groups, fusion.rendered) == (6, 6, 12)  # rendered at the start and once moved
    assert np.all(np.diag(fusion.covariance) < 0.1 * np.diag(VAGUE))
    assert _chi2(fusion.T_camera_base, fusion.covariance) < CHI2_999


def test_a_tight_prior_holds_the_pose(edges):
    prior = perturb(T_TRUE, 0.1 * START)  # 0.9 mm off, 1-sigma 10 nm: the outlines (1-sigma ~5 um) barely move it
    fusion = _adjustment(edges, replace(UNLIMITED, max_disagreement_chi2=1e9)).fuse(prior, np.eye(6) * 1e-16)
    assert np.linalg.norm(pose_difference(fusion.T_camera_base, prior)) < 1e-6


@pytest.mark.parametrize("shift", ["inward", "sideways"])
def test_the_edge_offsets_are_in_the_covariance(edges, shift):
    """Edges 0.3 px inside the outline, or all 0.3 px to one side, move the pose; the covariance holds the error."""
    start = perturb(T_TRUE, START)

    def fused(config):
        adjustment = OutlineAdjustment(_renderer, CAMERA, config)
        for k, image in enumerate(edges):
            move = 0.3 * image.normals if shift == "inward" else np.array([0.3, 0.0])
            adjustment.add(OutlineImage(ImageEdges(image.points + move, image.normals), np.array([float(k)]), k))
        return adjustment.fuse(start, VAGUE)

    # the shift towards the brighter side not estimated: with one polarity throughout it would take the inward offset
    honest = fused(replace(UNLIMITED, edge_offset_px=0.3, floor_px=0.0, polarity_offset_px=0.0))
    blind = fused(replace(UNLIMITED, edge_offset_px=0.0, floor_px=0.0, polarity_offset_px=0.0))
    assert np.linalg.norm(pose_difference(honest.T_camera_base, T_TRUE)[3:]) > TRANS_TOL  # the offset shows
    assert _chi2(honest.T_camera_base, honest.covariance) < CHI2_999
    assert _chi2(blind.T_camera_base, blind.covariance) > CHI2_999  # the textbook covariance does not


def _centres(k: int) -> np.ndarray:
    """(3, 2) px: image k's sphere centres, projected."""
    return project_px(T_TRUE, np.array([centre for centre, _ in SCENES[k]]))


def _sphere_of(k: int, points: np.ndarray) -> np.ndarray:
    """(E,) int: the sphere of image k each edge point (E, 2) outlines (the nearest projected centre)."""
    return np.argmin(np.linalg.norm(points[:, None] - _centres(k)[None], axis=2), axis=1)


def test_the_edges_shift_towards_the_brighter_side_is_estimated(edges):
    """Edges 0.3 px towards the brighter side, half the spheres dark on a bright background: the shift is estimated
    with the pose and taken out of the residuals; not estimated, it shows as their scatter and moves the pose."""
    start = perturb(T_TRUE, START)
    shifted = []
    for k, image in enumerate(edges):
        dark = _sphere_of(k, image.points) % 2 == 1
        normals = np.where(dark[:, None], -image.normals, image.normals)  # dark to bright
        shifted.append(ImageEdges(image.points + 0.3 * normals, normals))
    config = replace(UNLIMITED, floor_px=0.0)
    estimated = _adjustment(shifted, config).fuse(start, VAGUE)
    ignored = _adjustment(shifted, replace(config, polarity_offset_px=0.0)).fuse(start, VAGUE)
    assert estimated.polarity_offset_px == pytest.approx(0.3, abs=0.03)
    assert ignored.polarity_offset_px == 0.0
    assert np.linalg.norm(pose_difference(estimated.T_camera_base, T_TRUE)[3:]) < TRANS_TOL
    assert _chi2(estimated.T_camera_base, estimated.covariance) < CHI2_999
    assert estimated.sigma_px < 0.7 * ignored.sigma_px


def _outward(k: int, points: np.ndarray) -> np.ndarray:
    """(E, 2): the outward image directions at edge points (E, 2) of image k: away from their sphere's centre."""
    away = points - _centres(k)[_sphere_of(k, points)]
    return away / np.linalg.norm(away, axis=1, keepdims=True)


def _shaded(edges, dark_spheres: bool) -> list[ImageEdges]:
    """The edges moved towards the brighter side by 0.15 px, the bright spheres' by 0.5 px more times the outward
    normal's image y (their bottom edges further: a rim turned away from the light); with ``dark_spheres`` every
    second sphere dark on a bright background (its edges moved by the 0.15 px only)."""
    shaded = []
    for k, image in enumerate(edges):
        dark = (_sphere_of(k, image.points) % 2 == 1) & dark_spheres
        normals = np.where(dark[:, None], -image.normals, image.normals)  # dark to bright
        shift = 0.15 + np.where(dark, 0.0, 0.5 * _outward(k, image.points)[:, 1])
        shaded.append(ImageEdges(image.points + shift[:, None] * normals, normals))
    return shaded


def test_the_shifts_growth_along_the_outward_normal_is_estimated(edges):
    """Estimated, the growth takes the bright spheres' extra shift where the dark ones show it apart from a turn of
    the camera: the turn's error is a third of what the constant shift alone leaves, and the covariance holds."""
    start = perturb(T_TRUE, START)
    config = replace(UNLIMITED, floor_px=0.0)
    estimated = _adjustment(_shaded(edges, True), config).fuse(start, VAGUE)
    constant = _adjustment(_shaded(edges, True), replace(config, polarity_direction_px=0.0)).fuse(start, VAGUE)
    assert estimated.polarity_direction_px[1] > 0.1 and abs(estimated.polarity_direction_px[0]) < 0.05
    np.testing.assert_array_equal(constant.polarity_direction_px, [0.0, 0.0])
    turn = np.linalg.norm(pose_difference(estimated.T_camera_base, T_TRUE)[:3])
    assert turn < np.linalg.norm(pose_difference(constant.T_camera_base, T_TRUE)[:3]) / 2
    assert _chi2(estimated.T_camera_base, estimated.covariance) < CHI2_999


def test_one_polarity_leaves_the_growth_to_the_pose(edges):
    """Every edge with one polarity: the growth along the normal would be a turn of the camera, so it is not
    estimated and the pose is the constant shift's alone."""
    start = perturb(T_TRUE, START)
    config = replace(UNLIMITED, floor_px=0.0)
    estimated = _adjustment(_shaded(edges, False), config).fuse(start, VAGUE)
    constant = _adjustment(_shaded(edges, False), replace(config, polarity_direction_px=0.0)).fuse(start, VAGUE)
    np.testing.assert_allclose(estimated.polarity_direction_px, [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(estimated.T_camera_base, constant.T_camera_base, atol=1e-12)
    assert estimated.polarity_offset_px == pytest.approx(constant.polarity_offset_px, abs=1e-12)


def test_faint_edges_weigh_less(edges):
    """The first sphere of each image seen as a faint edge (contrast 5 grey levels per pixel) 1 px to one side, the
    others' strong (100) where they are: weighted by their contrast, the pose stays; unweighted, it moves."""
    start = perturb(T_TRUE, START)
    faint = []
    for k, image in enumerate(edges):
        first = _sphere_of(k, image.points) == 0
        moved = image.points + np.where(first[:, None], [1.0, 0.0], [0.0, 0.0])
        faint.append(ImageEdges(moved, image.normals, np.where(first, 5.0, 100.0)))
    config = replace(UNLIMITED, floor_px=0.0, polarity_offset_px=0.0)
    weighted = _adjustment(faint, config).fuse(start, VAGUE)
    unweighted = _adjustment(faint, replace(config, contrast_grey=0.0)).fuse(start, VAGUE)
    error = np.linalg.norm(pose_difference(weighted.T_camera_base, T_TRUE)[3:])
    assert error < TRANS_TOL
    assert np.linalg.norm(pose_difference(unweighted.T_camera_base, T_TRUE)[3:]) > 3 * max(error, TRANS_TOL / 3)
    # the residuals' scale is every pair's alike, whatever their weights
    assert weighted.sigma_px == pytest.approx(unweighted.sigma_px, rel=0.5)


def test_settled_images_are_not_rendered_again(edges):
    adjustment = _adjustment(edges)
    first = adjustment.fuse(perturb(T_TRUE, START), VAGUE)
    again = adjustment.fuse(perturb(T_TRUE, START), VAGUE, first.T_camera_base)
    assert again.rendered == 0
    assert np.linalg.norm(pose_difference(again.T_camera_base, first.T_camera_base)) < 1e-5


def test_settled_images_keep_their_pairs(edges, monkeypatch):
    """Once the pose settles, only a new image is paired; the pose is the one from pairing every image each time."""
    import solver.outline_fusion as fusion_module

    paired: list[int] = []
    pair = fusion_module.pair_contour_points

    def counting(T, contours, *args, **kwargs):
        paired.append(len(contours))
        return pair(T, contours, *args, **kwargs)

    monkeypatch.setattr(fusion_module, "pair_contour_points", counting)
    extra = OutlineImage(edges[0], np.array([0.0]), 6)  # a seventh motion's image: scene 0 again
    poses = {}
    for repair_px in (0.25, 0.0):
        adjustment = _adjustment(edges, replace(UNLIMITED, repair_px=repair_px))
        first = adjustment.fuse(perturb(T_TRUE, START), VAGUE)
        adjustment.add(extra)
        paired.clear()
        poses[repair_px] = adjustment.fuse(perturb(T_TRUE, START), VAGUE, first.T_camera_base)
        if repair_px:
            assert paired and set(paired) == {1}  # the new image alone
        else:
            assert paired and set(paired) == {7}
    d = pose_difference(poses[0.0].T_camera_base, poses[0.25].T_camera_base)
    assert float(d @ np.linalg.solve(poses[0.0].covariance, d)) < 0.1**2
    assert np.allclose(poses[0.25].covariance, poses[0.0].covariance, rtol=0.05, atol=0.0)


def test_from_few_motions_the_outlines_bound_the_covariance_below(edges):
    """Below trusted_groups motions the fused covariance is at least the outlines' own; from there it is less."""
    groups = [0, 0, 1, 1, 2, 2]  # three motions
    prior = np.eye(6) * 1e-5**2  # as sure as the outlines (~5 um): the fusion halves their variance
    fused = {trusted: _adjustment(edges, replace(UNLIMITED, trusted_groups=trusted), groups).fuse(T_TRUE, prior)
             for trusted in (6, 3)}
    floor, free = fused[6], fused[3]
    assert np.linalg.eigvalsh(floor.covariance - floor.outline_covariance).min() > -1e-9 * np.trace(floor.covariance)
    assert np.linalg.eigvalsh(free.outline_covariance - free.covariance).min() > -1e-9 * np.trace(free.covariance)
    assert np.trace(floor.covariance) > 1.5 * np.trace(free.covariance)
    assert np.allclose(floor.T_camera_base, free.T_camera_base)  # the pose is the same


def test_from_few_motions_the_outlines_floor_is_widened_by_the_few_clusters_factor(edges):
    """Below trusted_groups the outlines' covariance, the floor, is few_clusters_factor(G) times theirs (G motions);
    the pose is weighed as before. From trusted_groups motions on nothing changes."""
    prior = np.eye(6) * 1e-5**2
    for groups, factor in [([0, 0, 1, 1, 2, 2], few_clusters_factor(3)), (None, 1.0)]:
        on, off = (_adjustment(edges, replace(UNLIMITED, few_groups_t=flag), groups).fuse(T_TRUE, prior)
                   for flag in (True, False))
        np.testing.assert_allclose(on.outline_covariance, factor * off.outline_covariance, rtol=1e-9)
        np.testing.assert_allclose(on.T_camera_base, off.T_camera_base, atol=1e-12)
        assert np.linalg.eigvalsh(on.covariance - off.covariance).min() > -1e-9 * np.trace(on.covariance)
        if factor > 1.0:
            np.testing.assert_allclose(on.covariance, conservative_covariance(off.covariance, on.outline_covariance),
                                       rtol=1e-9)
        else:
            np.testing.assert_allclose(on.covariance, off.covariance, rtol=1e-12)


def test_from_few_motions_loosely_fitting_outlines_are_refused(edges):
    """Below trusted_groups a residual scale over max_early_sigma_px refuses the outlines; from there it does not."""
    three = [0, 0, 1, 1, 2, 2]
    prior = np.eye(6) * 1e-4**2
    assert _adjustment(edges, groups=three).fuse(T_TRUE, prior).sigma_px < 0.5  # noise-free edges fit closely
    strict = replace(UNLIMITED, max_early_sigma_px=0.01)
    with pytest.raises(InsufficientMotionsError, match="too loosely"):
        _adjustment(edges, strict, three).fuse(T_TRUE, prior)
    assert _adjustment(edges, strict).fuse(T_TRUE, prior).n_groups == 6  # six motions: the scale is not judged


def test_a_prior_too_uncertain_to_pair_by_is_refused(edges):
    """The default reach: 8 px RMS. A 1-sigma of 20 cm moves these contours by far more; 0.1 mm by far less."""
    with pytest.raises(InsufficientMotionsError, match="too uncertain for the outlines"):
        _adjustment(edges, OutlineFusionConfig()).fuse(perturb(T_TRUE, START), VAGUE)
    near = np.diag([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4]) ** 2
    assert _adjustment(edges, OutlineFusionConfig()).fuse(T_TRUE, near).n_groups == 6


def test_a_start_the_outlines_fixed_before_judges_the_reach(edges):
    """A vague prior (1-sigma 20 cm) cannot be paired by, but from a start whose own covariance is tight (a pose the
    outlines fixed in an earlier update) the nearest edges are no guess: the fusion runs from it and lands on the
    truth; the start's covariance needs its start."""
    start = perturb(T_TRUE, START / 10)  # 0.8 mm and 0.2 mrad off
    tight = np.diag([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3]) ** 2
    adjustment = _adjustment(edges, OutlineFusionConfig())
    with pytest.raises(InsufficientMotionsError, match="too uncertain for the outlines"):
        adjustment.fuse(perturb(T_TRUE, START), VAGUE, start)
    fused = adjustment.fuse(perturb(T_TRUE, START), VAGUE, start, start_covariance=tight)
    assert np.linalg.norm(pose_difference(fused.T_camera_base, T_TRUE)[3:]) < 1e-4
    assert _chi2(fused.T_camera_base, fused.covariance) < 22.5
    with pytest.raises(InvalidInputError, match="needs its start"):
        adjustment.fuse(T_TRUE, VAGUE, start_covariance=tight)


def test_outlines_that_disagree_with_the_tracks_are_refused(edges):
    prior = perturb(T_TRUE, np.array([0, 0, 0, 0, 0, 0.02]))  # 20 mm off with a 1-sigma of 0.1 mm
    with pytest.raises(OutlineDisagreementError, match="disagree") as refused:
        _adjustment(edges).fuse(prior, np.eye(6) * 1e-8)
    failure = refused.value
    assert failure.chi2 > 22.46 and failure.xi.shape == (6,)
    # its xi is the outlines' pose from the tracks' (one Newton step from where the fit ended): about 20 mm along z
    # back to the truth
    assert abs(failure.xi[5] + 0.02) < 2e-3 and np.linalg.norm(failure.xi[3:5]) < 2e-3
    assert failure.chi2 == pytest.approx(disagreement_chi2(failure.xi, failure.prior_information,
                                                           failure.outline_information))


def test_a_scaled_prior_is_the_prior_with_its_covariance_scaled(edges):
    """``prior_scale`` s: the fusion of the covariance C taken as s C (the reach judged by the start's covariance)."""
    prior = perturb(T_TRUE, np.array([0, 0, 0, 0, 0, 0.002]))  # 2 mm off
    C = np.diag([1e-4, 1e-4, 1e-4, 5e-4, 5e-4, 5e-4]) ** 2
    tight = np.diag([1e-4] * 6) ** 2
    scaled = _adjustment(edges).fuse(prior, C, T_TRUE, start_covariance=tight, prior_scale=9.0)
    plain = _adjustment(edges).fuse(prior, 9.0 * C, T_TRUE, start_covariance=tight)
    assert scaled.prior_scale == 9.0 and plain.prior_scale == 1.0
    assert np.linalg.norm(pose_difference(scaled.T_camera_base, plain.T_camera_base)) < 1e-9
    np.testing.assert_allclose(scaled.covariance, plain.covariance, rtol=1e-6, atol=1e-18)
    for bad in (0.5, np.nan, np.inf):
        with pytest.raises(InvalidInputError, match="prior_scale"):
            _adjustment(edges).fuse(prior, C, prior_scale=bad)


def test_the_consistent_prior_scale_brings_the_disagreement_to_its_target():
    rng = np.random.default_rng(4)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(6, 6))
    C_tracks, C_outline = A @ A.T * 1e-6 + np.eye(6) * 1e-8, B @ B.T * 1e-6 + np.eye(6) * 1e-8
    xi = 4e-3 * rng.normal(size=6)

    def chi2(scale):  # with the covariances themselves: (s C_tracks + C_outline)^-1
        return float(xi @ np.linalg.solve(scale * C_tracks + C_outline, xi))

    failure = OutlineDisagreementError("disagree", chi2(1.0), xi, np.linalg.inv(C_tracks), np.linalg.inv(C_outline))
    assert chi2(1.0) > 12.59 and chi2(1e4) < 12.59
    scale = consistent_prior_scale(failure, 12.59, 1e4)
    assert scale is not None and scale > 1.0 and chi2(scale) == pytest.approx(12.59, rel=1e-6)
    assert consistent_prior_scale(failure, chi2(1.0) + 1.0, 1e4) == 1.0  # already below the target
    assert consistent_prior_scale(failure, 12.59, 1.001) is None  # the most allowed is not enough
    assert consistent_prior_scale(OutlineDisagreementError("disagree", 50.0), 12.59, 1e4) is None  # nothing to use


def test_too_few_motions_or_bad_priors_are_refused(edges):
    with pytest.raises(InsufficientMotionsError, match="from 2 motion"):
        _adjustment(edges, groups=[0, 0, 0, 1, 1, 1]).fuse(T_TRUE, VAGUE)
    with pytest.raises(InvalidInputError, match="positive definite"):
        _adjustment(edges).fuse(T_TRUE, -VAGUE)
    with pytest.raises(InvalidInputError, match="symmetric"):
        _adjustment(edges).fuse(T_TRUE, np.full((6, 6), np.nan))
    with pytest.raises(InvalidInputError, match="T_prior"):
        _adjustment(edges).fuse(np.eye(3), VAGUE)
    with pytest.raises(InsufficientMotionsError, match="contour points lie within"):
        _adjustment(edges).fuse(perturb(T_TRUE, np.array([0, 0, 0, 2.0, 0, 0])), VAGUE)
    with pytest.raises(InvalidInputError, match="finite"):
        OutlineImage(edges[0], np.array([np.nan]), 0)


def _free_along(u: np.ndarray, strength: float = 1e8, omega: np.ndarray | None = None) -> np.ndarray:
    """(6, 6) covariance: 1/sqrt(strength) in every direction but (omega, u) (10 m there: free; omega 0 by default)."""
    w = np.concatenate([np.zeros(3) if omega is None else omega, u])
    w /= np.linalg.norm(w)
    basis, _ = np.linalg.qr(np.column_stack([w, np.eye(6)]))
    return basis @ np.diag([1e2] + [1.0 / strength] * 5) @ basis.T


#: The ray from the camera through the base origin: the direction the tracks of joints meeting there leave free.
RAY = T_TRUE[:3, 3] / np.linalg.norm(T_TRUE[:3, 3])


def _shifted(T: np.ndarray, shift: np.ndarray) -> np.ndarray:
    out = T.copy()
    out[:3, 3] += shift
    return out


def test_the_outlines_fix_the_depth_the_tracks_leave_free(edges):
    """The tracks' pose 30 cm too far along the ray, free there: the search finds the depth, the fusion refines it."""
    prior = _shifted(T_TRUE, 0.3 * RAY)
    adjustment = _adjustment(edges, OutlineFusionConfig())  # the default reach: the free direction is left out
    start, step = adjustment.search_along(prior, RAY, np.linspace(-0.6, 0.6, 40))
    assert abs((start[:3, 3] - T_TRUE[:3, 3]) @ RAY) < step
    fusion = adjustment.fuse(prior, _free_along(RAY), start, free_direction=RAY)
    err = pose_difference(fusion.T_camera_base, T_TRUE)
    assert np.linalg.norm(err[:3]) < ROT_TOL
    assert np.linalg.norm(err[3:]) < TRANS_TOL
    assert _chi2(fusion.T_camera_base, fusion.covariance) < CHI2_999
    # the free direction's 1-sigma is the outlines' (millimetres: three small spheres' sizes; measured 2.7 mm)
    w = np.concatenate([np.zeros(3), RAY])
    assert np.sqrt(w @ fusion.covariance @ w) < 5e-3
    with pytest.raises(InsufficientMotionsError, match="too uncertain"):  # not without the direction searched
        _adjustment(edges, OutlineFusionConfig()).fuse(prior, _free_along(RAY), start)


def test_the_reach_is_judged_with_the_searched_direction_fixed(edges):
    """The tracks' free direction turns too (10 mrad per 10 cm along the ray), where the search moves along the
    ray alone: the prior's marginal covariance off the ray keeps ~1 rad of it, yet with the ray fixed the rest is
    tight, so the fusion goes ahead (as-shipped Panda 1080p pose 3: refused at 19.4 px and 10.5 px, pose dropped)."""
    omega = np.array([0.0, 0.1, 0.0])
    prior = perturb(T_TRUE, 0.3 * np.concatenate([omega, RAY]))  # 30 cm along the free line from the truth
    C = _free_along(RAY, omega=omega)
    Q = np.eye(6) - np.outer(*2 * [np.concatenate([np.zeros(3), RAY])])
    assert np.sqrt(np.max(np.diag(Q @ C @ Q)[:3])) > 0.5  # its marginal off the ray: 1 rad (21 px of reach)
    adjustment = _adjustment(edges, OutlineFusionConfig())
    start, _ = adjustment.search_along(prior, RAY, np.linspace(-0.6, 0.6, 40))
    fusion = adjustment.fuse(prior, C, start, free_direction=RAY)
    err = pose_difference(fusion.T_camera_base, T_TRUE)
    assert np.linalg.norm(err[:3]) < ROT_TOL and np.linalg.norm(err[3:]) < TRANS_TOL


def test_tracks_sure_of_their_depth_keep_it(edges):
    """Sure of a depth 2 mm off (1-sigma 10 um), the tracks hold it: the search only says where to start."""
    prior = _shifted(T_TRUE, 2e-3 * RAY)
    adjustment = _adjustment(edges, replace(UNLIMITED, max_disagreement_chi2=1e9))
    start, _ = adjustment.search_along(prior, RAY, np.linspace(-0.6, 0.6, 40))
    fusion = adjustment.fuse(prior, np.eye(6) * 1e-10, start, free_direction=RAY)
    assert np.linalg.norm(pose_difference(fusion.T_camera_base, prior)[3:]) < 1e-4


class _WithCoarse:
    """The spheres' contours (``_renderer``) with a cheaper renderer (``CoarseContours``): every other point, each
    moved 1 mm outwards in the base frame's x (a pixel or two in the image, as a half-resolution render's). Counts
    the calls of each."""

    def __init__(self):
        self.calls = {"full": 0, "coarse": 0}

    def __call__(self, T, q):
        self.calls["full"] += 1
        return _renderer(T, q)

    def coarse(self):
        def cheap(T, q):
            self.calls["coarse"] += 1
            full = _renderer(T, q)
            return ContourPoints(full.points_base[::2] + np.array([1e-3, 0.0, 0.0]), full.outward[::2])
        return cheap


@pytest.mark.parametrize("coarse", [True, False])
def test_the_search_renders_its_coarse_rounds_with_the_cheaper_renderer(edges, coarse):
    """With ``coarse_search`` every round but the last renders with the renderer's cheaper one (``CoarseContours``),
    the last at full resolution; the depth found is the one the full renders find, within the last round's step."""
    prior = _shifted(T_TRUE, 0.3 * RAY)
    offsets = np.linspace(-0.6, 0.6, 40)
    config = OutlineFusionConfig(coarse_search=coarse)
    assert isinstance(_WithCoarse(), CoarseContours) and not isinstance(_renderer, CoarseContours)
    renderer = _WithCoarse()
    start, step = _adjustment(edges, config, renderer=renderer).search_along(prior, RAY, offsets)
    rounds = config.search_rounds
    assert renderer.calls == ({"full": len(edges), "coarse": (rounds - 1) * len(edges)} if coarse
                              else {"full": rounds * len(edges), "coarse": 0})
    plain, _ = _adjustment(edges, OutlineFusionConfig()).search_along(prior, RAY, offsets)
    assert abs((start[:3, 3] - plain[:3, 3]) @ RAY) <= step + 1e-12
    assert abs((start[:3, 3] - T_TRUE[:3, 3]) @ RAY) < step
    # without a cheaper renderer the rounds use the renderer itself
    np.testing.assert_array_equal(_adjustment(edges, config).search_along(prior, RAY, offsets)[0], plain)


def test_a_free_line_that_misses_the_robot_or_bad_input_is_refused(edges):
    side = np.array([1.0, 0.0, 0.0])
    with pytest.raises(InsufficientMotionsError, match="free direction"):  # every pose puts the spheres off-image
        _adjustment(edges).search_along(T_TRUE, side, np.linspace(2.0, 3.0, 10))
    with pytest.raises(InsufficientMotionsError, match="from 2 motion"):
        _adjustment(edges, groups=[0, 0, 0, 1, 1, 1]).fuse(T_TRUE, _free_along(RAY), free_direction=RAY)
    with pytest.raises(InvalidInputError, match="direction"):
        _adjustment(edges).search_along(T_TRUE, np.zeros(3), np.linspace(-0.1, 0.1, 5))
    with pytest.raises(InvalidInputError, match="direction"):
        _adjustment(edges).fuse(T_TRUE, _free_along(RAY), free_direction=np.array([np.nan, 0, 1]))
    with pytest.raises(InvalidInputError, match="two finite offsets"):
        _adjustment(edges).search_along(T_TRUE, RAY, np.array([0.1]))


def test_capped_scores_rank_the_true_pose_first_with_every_point_or_every_other(edges):
    """Contours rendered 8 mm off; scored at poses around the truth, the truth scores lowest whether every contour
    point counts or every other one; a point's score never exceeds the cap squared."""
    adjustment = _adjustment(edges)
    offsets = [np.zeros(6), np.array([0, 0, 0, 4e-3, 0, 0]), np.array([0, 0, 0, 0, 0, 4e-2]),
               np.array([5e-3, 0, 0, 0, 0, 0]), np.array([0, 0, 0, -3e-3, 3e-3, 0])]
    poses = np.array([perturb(T_TRUE, xi) for xi in offsets])
    for stride in (1, 2):
        scores = adjustment.capped_scores(perturb(T_TRUE, START), poses, 6.0, stride)
        assert scores.shape == (5,) and int(np.argmin(scores)) == 0 and np.all(scores <= 36.0)
    with pytest.raises(InvalidInputError):
        adjustment.capped_scores(T_TRUE, poses, 0.0)
    with pytest.raises(InvalidInputError):
        adjustment.capped_scores(T_TRUE, poses, 6.0, 0)
    with pytest.raises(InsufficientMotionsError):
        OutlineAdjustment(_renderer, CAMERA, UNLIMITED).capped_scores(T_TRUE, poses, 6.0)


def test_capped_scores_are_each_poses_paired_residuals_capped_and_screening_keeps_the_best(edges, monkeypatch):
    """Scored together (in chunks of a few poses), each pose's score is the mean over its contour points in front of
    the camera of min(r, cap)^2 from its own pairing (``pair_contour_points``, ``outline_residuals``), cap^2 for a
    point left unpaired; a screen keeps the k best of a cheaper ranking, scored as without it, the rest inf."""
    monkeypatch.setattr(outline_fusion, "_SCORED_POINTS", 700)  # several chunks of poses
    adjustment = _adjustment(edges)
    rng = np.random.default_rng(3)
    poses = np.array([perturb(T_TRUE, xi) for xi in rng.normal(0, [4e-3] * 3 + [3e-3] * 3, (40, 6))])
    cap, stride = 6.0, 2
    scores = adjustment.capped_scores(T_TRUE, poses, cap, stride)
    contours = [_renderer(T_TRUE, np.array([float(k)])) for k in range(len(edges))]
    contours = [ContourPoints(c.points_base[::stride], c.outward[::stride]) for c in contours]
    for T, score in zip(poses, scores, strict=True):
        pairs = pair_contour_points(T, contours, edges, CAMERA, OutlineConfig(max_match_px=cap))
        r = outline_residuals(T, pairs.points_base, pairs.edge_points, pairs.normals, CAMERA)
        assert pairs.in_front > len(r) > 0
        expected = (np.sum(np.minimum(r**2, cap**2)) + (pairs.in_front - len(r)) * cap**2) / pairs.in_front
        assert score == pytest.approx(expected, rel=1e-12)
    screened = adjustment.capped_scores(T_TRUE, poses, cap, stride, screen=(4, 10))
    kept = np.isfinite(screened)
    assert kept.sum() == 10 and np.all(screened[~kept] == np.inf)
    np.testing.assert_allclose(screened[kept], scores[kept], rtol=1e-12)
    assert int(np.argmin(screened)) == int(np.argmin(scores))
    with pytest.raises(InvalidInputError):
        adjustment.capped_scores(T_TRUE, poses, cap, stride, screen=(0, 10))


def test_contour_rays_are_the_contours_pixels_through_the_inverse_camera(edges):
    """After scoring at the truth (the contours rendered there), each contour point's normalized coordinates are its
    projected pixel through K^-1 (the spheres' camera has no distortion)."""
    adjustment = _adjustment(edges)
    adjustment.capped_scores(T_TRUE, T_TRUE[None], 6.0)
    rays = adjustment.contour_rays(T_TRUE)
    contours = [_renderer(T_TRUE, np.array([float(k)])) for k in range(len(edges))]
    pixels = np.concatenate([project_px(T_TRUE, c.points_base) for c in contours])
    K = CAMERA.K
    np.testing.assert_allclose(rays, (pixels - K[:2, 2]) / np.diag(K)[:2], atol=1e-9)
    assert OutlineAdjustment(_renderer, CAMERA, UNLIMITED).contour_rays(T_TRUE).shape == (0, 2)


def test_an_image_without_edges_scores_the_cap(edges):
    """An image whose edge detector found nothing: its contour points in front count cap^2 each."""
    empty = ImageEdges(np.zeros((0, 2)), np.zeros((0, 2)))
    adjustment = _adjustment([empty] * len(edges))
    assert adjustment.capped_scores(T_TRUE, T_TRUE[None], 6.0)[0] == pytest.approx(36.0)
    mixed = _adjustment([empty] + list(edges[1:]))
    assert 0.0 < mixed.capped_scores(T_TRUE, T_TRUE[None], 6.0)[0] < 36.0
