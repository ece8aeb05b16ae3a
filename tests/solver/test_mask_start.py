"""The first pose from the change masks, against spheres on the Panda's joints ray-cast through a known camera."""

from types import SimpleNamespace

import numpy as np
import pytest

from solver import PANDA, Calibrator, mask_start
from solver.errors import InsufficientMotionsError, InvalidInputError
from solver.frames import perturb, pose_difference, pose_errors
from solver.mask_start import (
    ChangeMask,
    ChangeMaskConfig,
    MaskStartConfig,
    MaskView,
    MovingSurface,
    change_mask,
    changed_pixels,
    mask_iou,
    mask_starts,
)
from solver.observations import MotionObservation
from solver.outline_fusion import OutlineImage
from solver.outlines import ImageEdges
from solver.synthetic import sample_camera_pose
from tests.solver.spheres import CAMERA, H, W, project_px, render_spheres, sphere_contour

#: Spheres of this radius (m) on the Panda's joints 2-7 stand in for its links.
RADIUS = 0.07
#: The turn of each test motion, rad: large enough that a sphere's positions barely overlap, so the change is the
#: spheres' whole discs (a real casting's interior changes too, as its shading turns with it).
DELTA = 0.6
#: The Panda's ready pose, rad: the test motions start near it. (With the arm straight up, q = 0, the joints 2-7
#: lie near one vertical line, the moving links' mean points nearly collinear, and the masks' PnP has no hold.)
PANDA_READY = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
#: A mask start is a start: the outlines' adjustment has reached the pose from these (on the as-shipped iiwa
#: captures, starts 1-9 degrees and 30-120 mm off; on these spheres, 11 degrees and 51 mm).
START_MAX_ROT_RAD = np.radians(12.0)
START_MAX_TRANS_FRACTION = 0.15  # of the camera's distance from the base


def _sphere_centres(q, joint):
    """(S, 3) m, base frame: the spheres the joint moves (on the joints after it), at q."""
    return np.array([PANDA.axis_and_point(q, k)[1] for k in range(max(joint + 1, 1), 7)])


def _fibonacci(n):
    i = np.arange(n) + 0.5
    phi, theta = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
    return np.stack([np.sin(phi) * np.cos(theta), np.sin(phi) * np.sin(theta), np.cos(phi)], axis=1)


class SphereSurface:
    """A ``MovingSurface``: points on the spheres a joint moves."""

    def moving_points(self, q, joint):
        return (_sphere_centres(q, joint)[:, None, :] + RADIUS * _fibonacci(300)[None]).reshape(-1, 3)


def _motions(seed, n):
    """n random motions: (q at each of 3 images, joint)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        q = PANDA_READY + rng.uniform(-0.4, 0.4, 7)
        joint = int(rng.integers(0, 4))
        qs = []
        for d in (0.0, DELTA / 2, DELTA):
            qk = q.copy()
            qk[joint] += d
            qs.append(qk)
        out.append((qs, joint))
    return out


def _views(T, motions):
    """Each motion's change mask from ray-cast images through T, with the surface's points at its images' q."""
    surface = SphereSurface()
    views = []
    for qs, joint in motions:
        greys = [render_spheres(T, [(tuple(c), RADIUS) for c in _sphere_centres(q, joint)], supersample=1)
                 for q in qs]
        views.append(MaskView(change_mask(greys), np.stack([surface.moving_points(q, joint) for q in qs])))
    return views


def test_a_change_mask_marks_where_a_square_was_and_went():
    first = np.full((H, W), 60, np.uint8)
    second = first.copy()
    first[100:160, 100:160] = 200
    second[100:160, 300:360] = 200
    mask = change_mask([first, second])
    assert mask.cell_px == W // 160 and mask.cells.shape == (H // mask.cell_px, W // mask.cell_px)
    rows, cols = np.nonzero(mask.cells)
    px, py = (cols + 0.5) * mask.cell_px, (rows + 0.5) * mask.cell_px
    in_either = ((py > 95) & (py < 165)) & (((px > 95) & (px < 165)) | ((px > 295) & (px < 365)))
    assert in_either.all()  # nothing marked elsewhere (the dilation is 7 px, less than 5 px beyond with the cells)
    assert mask.cells[130 // mask.cell_px, 130 // mask.cell_px] and mask.cells[130 // mask.cell_px,
                                                                                330 // mask.cell_px]
    assert not mask.cells[130 // mask.cell_px, 230 // mask.cell_px]  # between them: unchanged


def test_a_change_below_the_threshold_is_not_marked():
    first = np.full((H, W), 60, np.uint8)
    faint = first + np.uint8(ChangeMaskConfig().threshold_grey)
    assert not change_mask([first, faint]).cells.any()
    assert change_mask([first, faint + np.uint8(1)]).cells.all()


def test_changed_pixels_counts_the_images_that_differ_from_the_first():
    rng = np.random.default_rng(3)
    greys = [rng.integers(0, 256, (40, 60)).astype(np.uint8) for _ in range(5)]
    differs = np.stack([np.abs(g.astype(int) - greys[0].astype(int)) > 20 for g in greys[1:]])  # (4, 40, 60)
    for least in (1, 2, 4):
        expected = np.where(differs.sum(axis=0) >= least, 255, 0)
        np.testing.assert_array_equal(changed_pixels(greys, 20, least), expected)
    np.testing.assert_array_equal(changed_pixels(greys, 20, 9), changed_pixels(greys, 20, 4))  # capped at K - 1
    one = np.zeros((40, 60), np.uint8)
    one[20, 30] = 255
    assert not changed_pixels([np.zeros_like(one), one], 10, open_px=3).any()  # a lone pixel opened away
    grown = changed_pixels([np.zeros_like(one), one], 10, dilate_px=5)
    assert grown[20, 28:33].all() and grown[18:23, 30].all()
    assert np.count_nonzero(grown) == 17  # a 5 px ellipse: rows of 3, 5, 5, 5, 3


def test_change_mask_refuses_bad_images():
    grey = np.zeros((H, W), np.uint8)
    with pytest.raises(InvalidInputError, match="at least 2"):
        change_mask([grey])
    with pytest.raises(InvalidInputError, match="uint8"):
        change_mask([grey.astype(np.float32), grey.astype(np.float32)])
    with pytest.raises(InvalidInputError, match="shape"):
        change_mask([grey, grey[:-1]])
    with pytest.raises(InvalidInputError, match="too small"):
        change_mask([grey[:, :100], grey[:, :100]])
    with pytest.raises(InvalidInputError, match="different grids"):
        ChangeMask(np.zeros((2, 3), bool), 4).union(ChangeMask(np.zeros((2, 3), bool), 5))


def test_the_sphere_surface_is_a_moving_surface():
    assert isinstance(SphereSurface(), MovingSurface)
    assert not isinstance(lambda T, q: None, MovingSurface)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_masks_give_a_start_near_the_true_pose(seed):
    """Measured on these spheres: 4.7 degrees / 106 mm, 6.9 / 260 and 11.1 / 51 (seeds 0-2); not on every
    configuration: seeds 3-5 end 21.5 / 188, 14.4 / 172 and 23.7 / 396, each covering the masks less than the truth
    does (a start the outlines then refuse or mend: ``test_a_start_the_outlines_do_not_confirm_gives_no_pose``)."""
    T = sample_camera_pose(np.random.default_rng(100 + seed), distance=(1.5, 2.5))
    views = _views(T, _motions(seed, 4))
    truth = mask_iou(views, T, CAMERA)
    starts = mask_starts(views, CAMERA)
    assert 1 <= len(starts) <= MaskStartConfig().returned
    assert [iou for iou, _ in starts] == sorted((iou for iou, _ in starts), reverse=True)
    iou, best = starts[0]
    rot, trans = pose_errors(best, T)
    distance = np.linalg.norm(T[:3, 3])
    assert rot < START_MAX_ROT_RAD and trans < START_MAX_TRANS_FRACTION * distance, (seed, rot, trans, iou, truth)
    assert iou >= truth - 0.05  # it covers the masks about as well as the truth does


def test_the_same_masks_give_the_same_starts():
    T = sample_camera_pose(np.random.default_rng(100), distance=(1.5, 2.5))
    views = _views(T, _motions(0, 3))
    a, b = mask_starts(views, CAMERA), mask_starts(views, CAMERA)
    assert len(a) == len(b) and all(x[0] == y[0] and np.array_equal(x[1], y[1]) for x, y in zip(a, b, strict=True))


def test_starts_that_converged_together_are_returned_once(monkeypatch):
    """Every refinement ending 5 mrad / 5 mm from one pose (within ``distinct_rad`` / ``distinct_m``) gives that start
    once; with the distinctness off, every refined start comes back."""
    T = sample_camera_pose(np.random.default_rng(100), distance=(1.5, 2.5))
    views = _views(T, _motions(0, 3))
    ends = iter(perturb(T, np.array([0.005, 0.0, 0.0, 0.0, 0.005, 0.0]) * (k % 2)) for k in range(100))
    refined = []
    monkeypatch.setattr(mask_start, "_refined", lambda *_: refined.append(1) or (0.5, next(ends)))
    assert len(mask_starts(views, CAMERA)) == 1
    rounds = len(MaskStartConfig().steps)
    assert len(refined) // rounds >= 2  # two starts or more were refined
    refined.clear()
    config = MaskStartConfig(distinct_rad=0.0, distinct_m=0.0)
    assert len(mask_starts(views, CAMERA, config)) == min(config.returned, len(refined) // rounds)


def test_fewer_than_three_changed_motions_give_no_start():
    T = sample_camera_pose(np.random.default_rng(100), distance=(1.5, 2.5))
    views = _views(T, _motions(0, 3))
    still = MaskView(ChangeMask(np.zeros_like(views[0].change.cells), views[0].change.cell_px), views[0].points)
    with pytest.raises(InsufficientMotionsError, match="2 motion"):
        mask_starts([still] + views[1:], CAMERA)


def test_mask_start_config_refuses_bad_settings():
    with pytest.raises(InvalidInputError):
        MaskStartConfig(min_motions=2)
    with pytest.raises(InvalidInputError):
        MaskStartConfig(refined=2, returned=3)
    with pytest.raises(InvalidInputError):
        MaskView(ChangeMask(np.zeros((2, 2), bool), 4), np.zeros((3, 5)))


#: chi-square of 6 dof at 0.999.
CHI2_6_999 = 22.46
#: Noise of the synthetic edge points, px.
EDGE_NOISE_PX = 0.2
#: Six spheres' outlines fix the camera's turn weakly (a sphere's outline is the same from every side): the outlines
#: alone reach the pose to a few mrad and mm (seen: 2.6 mrad / 1.2 mm, within their covariance); the starts were
#: 2-11 degrees and 30-110 mm off.
RESCUED_MAX_RAD = 5e-3
RESCUED_MAX_M = 5e-3


class SphereRobot(SphereSurface):
    """The spheres as a contour renderer draws them (all six) and as a ``MovingSurface`` (those a joint moves)."""

    def __call__(self, T, q):
        return sphere_contour(T, [(tuple(c), RADIUS) for c in _sphere_centres(q, 0)], n=240)


def _masked_calibrator(T_true, motions, T_masks=None, seed=0):
    """A calibrator given the motions' outline images (edges through T_true, change masks rendered through T_masks,
    default T_true) and no tracks (every motion pruned: nothing moved)."""
    rng = np.random.default_rng(seed)
    robot = SphereRobot()
    cal = Calibrator(CAMERA, PANDA.axis_and_point, contours=robot)
    T_masks = T_true if T_masks is None else T_masks
    for qs, joint in motions:
        greys = [render_spheres(T_masks, [(tuple(c), RADIUS) for c in _sphere_centres(q, joint)], supersample=1)
                 for q in qs]
        images = []
        for k, q in enumerate(qs):
            contour = robot(T_true, q)
            px = project_px(T_true, contour.points_base) + rng.normal(0.0, EDGE_NOISE_PX, (len(contour.points_base), 2))
            images.append(OutlineImage(ImageEdges(px, -contour.outward), q, 0,
                                       change_mask([greys[0], greys[k]]) if k else None))
        report = cal.add_motion(MotionObservation(q_start=qs[0], joint=joint, tracks=()), update=False,
                                outlines=images)
        assert "nothing moved" in report.reason
    return cal


@pytest.mark.parametrize("seed", [0, 2])
def test_the_calibrator_places_the_pose_from_the_masks_and_the_outlines_alone(seed):
    T = sample_camera_pose(np.random.default_rng(100 + seed), distance=(1.5, 2.5))
    cal = _masked_calibrator(T, _motions(seed, 4))
    assert sorted(cal._changes) == [0, 1, 2, 3]
    fused, why = cal._mask_rescue([])
    assert fused is not None, why
    rot, trans = pose_errors(fused.T_camera_base, T)
    assert rot < RESCUED_MAX_RAD and trans < RESCUED_MAX_M, (rot, trans, np.sqrt(np.diag(fused.covariance)))
    xi = pose_difference(fused.T_camera_base, T)
    assert xi @ np.linalg.solve(fused.covariance, xi) < CHI2_6_999


@pytest.mark.parametrize("seed", [3, 5])
def test_a_start_the_outlines_do_not_confirm_gives_no_pose(seed):
    """Where the masks' starts are far (seeds 3 and 5: the best 21.5 and 23.7 degrees off), the rescue refuses with a
    reason or the outlines mend the start: never a pose far off."""
    T = sample_camera_pose(np.random.default_rng(100 + seed), distance=(1.5, 2.5))
    fused, why = _masked_calibrator(T, _motions(seed, 4))._mask_rescue([])
    if fused is None:
        assert why.startswith("no start from the change masks")
    else:
        rot, trans = pose_errors(fused.T_camera_base, T)
        assert rot < RESCUED_MAX_RAD and trans < RESCUED_MAX_M, (rot, trans)


def test_masks_that_lie_give_no_pose_far_off():
    """Masks seen from another camera (turned 0.3 rad, moved 0.2 m) than the edges': a pose from them is refused by
    the outlines' tests, or is the edges' own."""
    T = sample_camera_pose(np.random.default_rng(100), distance=(1.5, 2.5))
    wrong = perturb(T, np.array([0.3, -0.2, 0.1, 0.2, 0.1, 0.0]))
    fused, why = _masked_calibrator(T, _motions(0, 4), T_masks=wrong)._mask_rescue([])
    if fused is not None:
        rot, trans = pose_errors(fused.T_camera_base, T)
        assert rot < RESCUED_MAX_RAD and trans < RESCUED_MAX_M, (rot, trans)
    else:
        assert why.startswith("no start from the change masks")


def test_the_masks_are_tried_before_the_one_axis_search(monkeypatch):
    """The rescue chain's order: a pose from the change masks ends it; only without one does the (costlier) search
    from one motion's axis run. The two rescues are stubbed: this is the chain's order, not their geometry."""
    T = sample_camera_pose(np.random.default_rng(100), distance=(1.5, 2.5))
    cal = _masked_calibrator(T, _motions(0, 4))
    cal._motions[0] = SimpleNamespace(point_base=np.zeros(3), search_axis=object(), geometry=None)  # an axis to search
    order: list[str] = []
    pose = SimpleNamespace(T_camera_base=T)
    for name, result in (("_mask_rescue", (pose, "")), ("_one_axis_rescue", (None, "no start from one motion's axis"))):
        monkeypatch.setattr(cal, name, lambda *_, name=name, result=result: order.append(name) or result)
    assert cal._outline_rescue([0], [], None, None) == (pose, "") and order == ["_mask_rescue"]
    refused = (None, "no start from the masks")
    monkeypatch.setattr(cal, "_mask_rescue", lambda *_: order.append("_mask_rescue") or refused)
    order.clear()
    fused, why = cal._outline_rescue([0], [], None, None)
    assert fused is None and order == ["_mask_rescue", "_one_axis_rescue"]
    assert why == "no start from the masks; no start from one motion's axis"


def test_without_a_moving_surface_the_calibrator_keeps_no_masks():
    T = sample_camera_pose(np.random.default_rng(100), distance=(1.5, 2.5))
    robot = SphereRobot()
    cal = Calibrator(CAMERA, PANDA.axis_and_point, contours=lambda T_, q: robot(T_, q))
    qs, joint = _motions(0, 1)[0]
    greys = [render_spheres(T, [(tuple(c), RADIUS) for c in _sphere_centres(q, joint)], supersample=1) for q in qs]
    contour = robot(T, qs[1])
    image = OutlineImage(ImageEdges(project_px(T, contour.points_base), -contour.outward), qs[1], 0,
                         change_mask([greys[0], greys[1]]))
    cal.add_motion(MotionObservation(q_start=qs[0], joint=joint, tracks=()), update=False, outlines=[image])
    assert cal._surface is None and cal._changes == {}
