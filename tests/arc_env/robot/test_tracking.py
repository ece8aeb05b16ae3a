"""Tests of arc_env/robot/tracking.py: moving mask, Shi–Tomasi + LK tracks against synthetic sweeps.

The sweeps are built here with numpy and cv2.warpAffine / cv2.warpPerspective, independently of the
tracker: a static blurred-noise background and a textured plate that turns about a known centre, either
in the image plane or on a tilted plane seen by a pinhole camera (points then trace ellipses). The plate
is off-centre, so it sweeps over background corners that the tracker must not keep. Ground truth maps a
track's first point through the known transforms at the track's own delta values (the plate turns by
exactly delta), so it checks positions and the delta bookkeeping at once.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
import pytest

from arc_env.robot.tracking import (
    TrackerConfig,
    TrackingResult,
    _centred,
    _patch_offsets,
    _photometric_basis,
    _root_weights,
    moving_mask,
    static_fraction,
    static_tolerance,
    track_keypoints,
)
from solver.errors import InvalidInputError
from solver.observations import KeypointTrack

#: Accuracy the tracker must reach on the noise-free sweeps (the brief's figures). The renderings'
#: own error (bicubic texture warp, uint8 rounding) is ~0.01 px; measured: median ~0.05, max ~0.3 px.
MEDIAN_TOL_PX = 0.2
MAX_TOL_PX = 1.0

#: Translation-only LK must be measurably worse over the same sweep (it drifts 1-2 px), or the
#: accuracy test above would not be able to tell the refinement from plain LK.
PLAIN_LK_MIN_MEDIAN_PX = 0.5

#: A sweep: 40 frames, the plate turns by 0.8 rad with a smooth start and stop (like a joint move).
N_FRAMES = 40
SPAN_RAD = 0.8

#: Small images for speed; the plate turns about CENTRE and is a disc of PLATE_RADIUS about PLATE_CENTRE.
SIZE = (240, 320)  # (H, W)
CENTRE = np.array([160.0, 120.0])
PLATE_CENTRE = np.array([200.0, 120.0])
PLATE_RADIUS = 60.0

#: Tracker settings for the 320x240 sweeps: denser corners than the 1080p defaults.
SMALL = TrackerConfig(max_corners=200, min_distance_px=7.0)

PointMap = Callable[[np.ndarray, float, float], np.ndarray]


@dataclass(frozen=True)
class Sweep:
    """A rendered sweep and its ground truth.

    Attributes:
        frames: F (H, W) uint8 images.
        delta: (F,) float64, rad: the plate's turn in each frame.
        move: move(p, d_from, d_to): where the plate point at pixel p (2,) when the plate had turned by
            d_from is when it has turned by d_to.
        plate_distance: plate_distance(p, d): distance of pixel p from the plate's centre, in plate
            units, when the plate has turned by d (inside the plate when < PLATE_RADIUS).
    """

    frames: list[np.ndarray]
    delta: np.ndarray
    move: PointMap
    plate_distance: Callable[[np.ndarray, float], float]


def smooth_delta(n: int = N_FRAMES, span: float = SPAN_RAD) -> np.ndarray:
    """(n,) rad: a smoothstep from 0 to span (slow start and stop)."""
    s = np.linspace(0.0, 1.0, n)
    return span * s * s * (3.0 - 2.0 * s)


def noise_texture(rng: np.random.Generator, shape: tuple[int, int], sigma: float = 2.0) -> np.ndarray:
    """(H, W) float32 grey levels: blurred uniform noise, mean 128, standard deviation 50 (has corners)."""
    image = cv2.GaussianBlur(rng.uniform(0.0, 255.0, shape).astype(np.float32), (0, 0), sigma)
    return np.clip((image - image.mean()) / image.std() * 50.0 + 128.0, 0.0, 255.0).astype(np.float32)


def disc(shape: tuple[int, int], centre: np.ndarray, radius: float) -> np.ndarray:
    """(H, W) float32 coverage of a disc with a slightly soft edge."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    inside = ((xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius**2).astype(np.float32)
    return cv2.GaussianBlur(inside, (0, 0), 0.7)


def composite(background: np.ndarray, texture: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(alpha * texture + (1.0 - alpha) * background), 0, 255).astype(np.uint8)


def apply(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    q = H @ np.array([p[0], p[1], 1.0])
    return q[:2] / q[2]


def rotation_about(centre: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3): turn image points about centre by angle rad (counter-clockwise on screen, y down)."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, s], [-s, c]])
    M = np.eye(3)
    M[:2, :2] = R
    M[:2, 2] = centre - R @ centre
    return M


def in_plane_sweep(rng: np.random.Generator, delta: np.ndarray | None = None,
                   size: tuple[int, int] = SIZE, scale: float = 1.0) -> Sweep:
    """The plate turning in the image plane (cv2.warpAffine of its texture and coverage)."""
    delta = smooth_delta() if delta is None else delta
    centre, plate_centre, radius = CENTRE * scale, PLATE_CENTRE * scale, PLATE_RADIUS * scale
    background = noise_texture(rng, size)
    texture = noise_texture(rng, size)
    alpha = disc(size, plate_centre, radius)
    frames = []
    for d in delta:
        M = rotation_about(centre, d)[:2]
        frames.append(composite(background,
                                cv2.warpAffine(texture, M, size[::-1], flags=cv2.INTER_CUBIC),
                                cv2.warpAffine(alpha, M, size[::-1], flags=cv2.INTER_LINEAR)))

    def move(p: np.ndarray, d_from: float, d_to: float) -> np.ndarray:
        return apply(rotation_about(centre, d_to) @ np.linalg.inv(rotation_about(centre, d_from)), p)

    def plate_distance(p: np.ndarray, d: float) -> float:
        return float(np.linalg.norm(move(p, d, 0.0) - plate_centre) / scale)

    return Sweep(frames, delta, move, plate_distance)


#: The pinhole camera of the perspective sweep (320x240) and the plate's plane: 1 m away, tilted 50 deg.
FX = 300.0
K = np.array([[FX, 0.0, 159.5], [0.0, FX, 119.5], [0.0, 0.0, 1.0]])
TILT_RAD = np.deg2rad(50.0)
PLANE_ORIGIN = np.array([0.0, 0.0, 1.0])  # m, camera frame: where the turning axis meets the plane
METRES_PER_TEXEL = 0.003
TEXTURE_SIZE = (300, 300)


def plane_homography(angle: float) -> np.ndarray:
    """(3, 3): texture pixels -> image pixels with the plate turned by angle rad about its normal.

    Texture pixel (s, t) is the plane point ((s - sc) m, (t - tc) m, 0) in the plate frame, turned about
    the plate's z axis (its normal, through the texture centre), then placed by R_camera_plane (a tilt
    about the camera x axis) at PLANE_ORIGIN, and projected by K.
    """
    c, s = np.cos(angle), np.sin(angle)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    ct, st = np.cos(TILT_RAD), np.sin(TILT_RAD)
    R_camera_plane = np.array([[1.0, 0.0, 0.0], [0.0, ct, -st], [0.0, st, ct]])
    R = R_camera_plane @ turn
    sc, tc = (TEXTURE_SIZE[1] - 1) / 2, (TEXTURE_SIZE[0] - 1) / 2
    m = METRES_PER_TEXEL
    columns = np.column_stack([m * R[:, 0], m * R[:, 1], PLANE_ORIGIN - m * sc * R[:, 0] - m * tc * R[:, 1]])
    return K @ columns


def perspective_sweep(rng: np.random.Generator, delta: np.ndarray | None = None) -> Sweep:
    """The plate turning on a tilted plane seen in perspective (cv2.warpPerspective)."""
    delta = smooth_delta() if delta is None else delta
    background = noise_texture(rng, SIZE)
    texture = noise_texture(rng, TEXTURE_SIZE, sigma=2.5)
    centre_tex = np.array([(TEXTURE_SIZE[1] - 1) / 2 + 45.0, (TEXTURE_SIZE[0] - 1) / 2])
    radius_tex = 70.0
    alpha = disc(TEXTURE_SIZE, centre_tex, radius_tex)
    frames = []
    for d in delta:
        H = plane_homography(d)
        frames.append(composite(background,
                                cv2.warpPerspective(texture, H, SIZE[::-1], flags=cv2.INTER_CUBIC),
                                cv2.warpPerspective(alpha, H, SIZE[::-1], flags=cv2.INTER_LINEAR)))

    def move(p: np.ndarray, d_from: float, d_to: float) -> np.ndarray:
        return apply(plane_homography(d_to) @ np.linalg.inv(plane_homography(d_from)), p)

    def plate_distance(p: np.ndarray, d: float) -> float:
        # In texels, rescaled so that the plate's edge is at PLATE_RADIUS like the in-plane sweep.
        texel = apply(np.linalg.inv(plane_homography(d)), p)
        return float(np.linalg.norm(texel - centre_tex) / radius_tex * PLATE_RADIUS)

    return Sweep(frames, delta, move, plate_distance)


def track_errors(track: KeypointTrack, sweep: Sweep) -> np.ndarray:
    """(M,) px: distance of each tracked point from the ground truth of the track's first point."""
    truth = np.array([sweep.move(track.pixels[0], track.delta[0], d) for d in track.delta])
    return np.linalg.norm(track.pixels - truth, axis=1)


def max_errors(result: TrackingResult, sweep: Sweep) -> np.ndarray:
    return np.array([track_errors(t, sweep).max() for t in result.tracks])


def assert_counts_add_up(result: TrackingResult) -> None:
    assert result.n_detected == (len(result.tracks) + result.n_dropped_fb + result.n_dropped_dissimilar
                                 + result.n_dropped_short + result.n_dropped_static + result.n_dropped_background)


SWEEPS = {"in_plane": in_plane_sweep, "perspective": perspective_sweep}


@pytest.fixture(scope="module", params=list(SWEEPS), ids=list(SWEEPS))
def sweep(request) -> Sweep:
    return SWEEPS[request.param](np.random.default_rng(7))


@pytest.fixture(scope="module")
def tracked(sweep) -> TrackingResult:
    return track_keypoints(sweep.frames, sweep.delta, SMALL)


# --- accuracy -------------------------------------------------------------------------------------


def test_tracks_follow_ground_truth(sweep, tracked):
    assert len(tracked.tracks) >= 30
    errors = np.concatenate([track_errors(t, sweep) for t in tracked.tracks])
    assert np.median(errors) < MEDIAN_TOL_PX
    assert errors.max() < MAX_TOL_PX


def test_tracks_are_long_and_move(sweep, tracked):
    lengths = np.array([len(t) for t in tracked.tracks])
    assert lengths.min() >= SMALL.min_track_frames
    assert np.median(lengths) == N_FRAMES  # most corners survive the whole sweep
    for t in tracked.tracks:
        assert np.max(np.linalg.norm(t.pixels - t.pixels[0], axis=1)) > SMALL.min_displacement_px


def test_perspective_tracks_are_ellipses_not_circles(rng):
    # The perspective sweep must really be perspective: the ground-truth path of a plate point is an
    # ellipse with a clearly unequal aspect (cos 50 deg = 0.64), or that test would repeat the in-plane one.
    full_turn = np.linspace(0.0, 2.0 * np.pi, 73)
    path = np.array([apply(plane_homography(d), np.array([230.0, 150.0])) for d in full_turn])
    extent = path.max(axis=0) - path.min(axis=0)
    assert extent[1] / extent[0] < 0.8


def test_no_tracks_on_static_background(sweep, tracked):
    # Corners of the background the plate sweeps over are detected (the moving mask covers them) ...
    assert tracked.n_dropped_static + tracked.n_dropped_dissimilar + tracked.n_dropped_fb > 0
    # ... but every kept track starts on the plate.
    for t in tracked.tracks:
        assert sweep.plate_distance(t.pixels[0], t.delta[0]) < PLATE_RADIUS


def test_translation_only_lk_drifts(sweep):
    # Teeth for the accuracy test: plain LK (no affine refinement) on the same sweep misses the ground
    # truth by far more than the tolerance, even when only the tracks that start on the plate count.
    result = track_keypoints(sweep.frames, sweep.delta, TrackerConfig(max_corners=200, min_distance_px=7.0,
                                                                      affine_iterations=0))
    on_plate = [t for t in result.tracks if sweep.plate_distance(t.pixels[0], t.delta[0]) < PLATE_RADIUS - 12]
    errors = np.array([track_errors(t, sweep).max() for t in on_plate])
    assert np.median(errors) > PLAIN_LK_MIN_MEDIAN_PX


def test_counts_add_up(tracked):
    assert_counts_add_up(tracked)
    assert tracked.seconds > 0


# --- appearance changes: exposure -------------------------------------------------------------------


def with_contrast(frames: list[np.ndarray], gains: np.ndarray) -> list[np.ndarray]:
    """The frames with their contrast about mid-grey scaled by gains (F,) (an auto-exposure change)."""
    return [np.clip(np.rint(128.0 + g * (f.astype(np.float32) - 128.0)), 0, 255).astype(np.uint8)
            for f, g in zip(frames, gains, strict=True)]


#: The patches compared at unit gain, as before the gain-invariant check (the teeth of the test below).
STRICT = TrackerConfig(max_corners=200, min_distance_px=7.0, max_gain_change=1.0)


def test_a_contrast_change_does_not_end_tracks(rng):
    # The contrast falls by 45 % over the sweep: the patches still match at the best gain.
    sweep = in_plane_sweep(rng)
    frames = with_contrast(sweep.frames, np.linspace(1.0, 0.55, N_FRAMES))
    # (The background's contrast changes too, so the moving mask covers it and corners are found all
    # over the image; the checks drop those. The plate's inner corners of the first frame are followed.)
    result = track_keypoints(frames, sweep.delta, SMALL)
    errors = np.concatenate([track_errors(t, sweep) for t in result.tracks])
    assert np.median(errors) < MEDIAN_TOL_PX and errors.max() < MAX_TOL_PX

    def inner_lengths(r: TrackingResult) -> list[int]:
        return [len(t) for t in r.tracks if t.delta[0] == 0.0 and sweep.plate_distance(t.pixels[0], 0.0) < 45]

    assert len(inner_lengths(result)) >= 10 and min(inner_lengths(result)) == N_FRAMES
    assert np.median(inner_lengths(track_keypoints(frames, sweep.delta, STRICT))) < 0.95 * N_FRAMES


def test_a_corner_floor_keeps_strong_corners_and_drops_weak_ones(rng):
    # The same sweep at full contrast and at 15 %: corner strength scales with contrast squared, so a floor
    # above every low-contrast corner (yet far below the full-contrast ones) leaves only the strong sweep tracks.
    sweep = in_plane_sweep(rng)
    weak = with_contrast(sweep.frames, np.full(N_FRAMES, 0.15))
    floor = 4.0 * float(cv2.cornerMinEigenVal(weak[0], SMALL.block_size).max())
    assert len(track_keypoints(weak, sweep.delta, SMALL).tracks) >= 10  # found without the floor
    floored = replace(SMALL, min_eigenvalue=floor)
    assert track_keypoints(weak, sweep.delta, floored).tracks == []
    strong = track_keypoints(sweep.frames, sweep.delta, floored)
    assert len(strong.tracks) >= 10
    errors = np.concatenate([track_errors(t, sweep) for t in strong.tracks])
    assert np.median(errors) < MEDIAN_TOL_PX and errors.max() < MAX_TOL_PX


# --- delta bookkeeping ----------------------------------------------------------------------------


#: The bar sweep: a smooth bar (uniform but for a few textured labels) slides by BAR_STEP px a frame over a
#: background of horizontal stripes; where its upright edges cross a stripe edge they make corners that slide
#: along the stripe (sideways only), not with the bar.
BAR_STEP = np.array([1.0, 0.6])
BAR_FRAMES = 30


def bar_sweep(rng: np.random.Generator) -> tuple[list[np.ndarray], np.ndarray]:
    """F (H, W) uint8 frames of the bar sweep and (F,) its 'delta' (the frame number)."""
    h, w = SIZE
    rows = np.arange(h, dtype=np.float32)[:, None]
    stripes = np.broadcast_to(np.where((rows // 12) % 2 == 0, 70.0, 170.0), (h, w)).astype(np.float32)
    background = cv2.GaussianBlur(stripes, (0, 0), 1.0)
    bar = np.full((h, w), 215.0, np.float32)
    cover = np.zeros((h, w), np.float32)
    cover[70:170, 60:150] = 1.0
    for x, y in ((75, 85), (115, 95), (80, 135), (120, 145)):  # the labels: small textured patches
        bar[y:y + 14, x:x + 14] = noise_texture(rng, (14, 14), 1.0)
    cover = cv2.GaussianBlur(cover, (0, 0), 0.7)
    frames = []
    for k in range(BAR_FRAMES):
        M = np.array([[1.0, 0.0, BAR_STEP[0] * k], [0.0, 1.0, BAR_STEP[1] * k]])
        moved = cv2.warpAffine(bar, M, (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        alpha = cv2.warpAffine(cover, M, (w, h), flags=cv2.INTER_LINEAR)
        frames.append(composite(background, moved, alpha))
    return frames, np.arange(BAR_FRAMES, dtype=np.float64)


def bar_errors(result: TrackingResult) -> np.ndarray:
    """(M,) px: each kept track's largest distance from where the bar carries its first point."""
    return np.array([np.max(np.linalg.norm(t.pixels - t.pixels[0] - np.outer(t.delta - t.delta[0], BAR_STEP), axis=1))
                     for t in result.tracks])


def test_the_still_window_check_drops_corners_that_slide_along_the_background(rng):
    frames, delta = bar_sweep(rng)
    config = replace(SMALL, min_distance_px=5.0)
    unchecked = track_keypoints(frames, delta, config)
    assert np.sum(bar_errors(unchecked) > 3.0) >= 2  # teeth: sliding corners pass every other check
    checked = track_keypoints(frames, delta, replace(config, max_static_fraction=0.6))
    assert checked.n_dropped_background >= 2
    assert_counts_add_up(checked)
    assert len(checked.tracks) >= 8  # the labels' corners stay
    assert np.max(bar_errors(checked)) < MAX_TOL_PX


def test_static_fraction_and_tolerance_against_a_shifted_image(rng):
    image = np.clip(noise_texture(rng, (60, 80)), 0, 255).astype(np.uint8)
    shifted = np.roll(image, 3, axis=1)
    shifted[:, :40] = image[:, :40]  # the left half stays, the right half moves by 3 px
    centres = np.array([[20.0, 30.0], [60.0, 30.0], [40.0, 30.0], [0.0, 0.0]])
    fraction = static_fraction(image, shifted, centres, 5, 1.0)
    assert fraction[0] == 1.0 and fraction[1] < 0.2 and 0.4 < fraction[2] < 0.6
    assert fraction[3] == 1.0  # cut at the corner: the 6 x 6 inside are all still
    noisy = np.clip(image + rng.normal(0.0, 3.0, image.shape), 0, 255).astype(np.uint8)
    still = np.arange(image.size)
    assert static_tolerance(image, image, still) == 1.0
    # the difference of one noisy frame from a clean one: sigma 3, MAD-based, times 2.5
    assert 2.5 * 3.0 * 0.8 < static_tolerance(image, noisy, still) < 2.5 * 3.0 * 1.25


def test_delta_is_carried_through(rng):
    # Uneven steps, so a track whose delta were shifted by a frame would miss the ground truth.
    delta = np.concatenate([[0.0], np.cumsum(rng.uniform(0.005, 0.04, N_FRAMES - 1))])
    sweep = in_plane_sweep(rng, delta)
    result = track_keypoints(sweep.frames, delta, SMALL)
    starts = []
    for t in result.tracks:
        (first,) = np.flatnonzero(delta == t.delta[0])
        np.testing.assert_array_equal(t.delta, delta[first:first + len(t)])
        starts.append(first)
    assert min(starts) == 0 and max(starts) > 0  # re-detected tracks start later and are checked too
    assert np.max(max_errors(result, sweep)) < MAX_TOL_PX


def test_the_whole_window_check_ends_tracks_whose_rim_slid(rng):
    # Teeth for the test above: the Gaussian-weighted fit and dissimilarity weigh the patch's rim little, and
    # without the unweighted second check a track whose rim slid onto the background goes on (seen: 18.3 px).
    # Which track slides depends on the fit's path: on this sweep it shows with the fit iterated to 0.01 px
    # (with the default 0.03 px the same tracks end 0.85 px off at most, so this sweep alone has no teeth there),
    # and without the shading ramp (with it, 0.85 px at most on this sweep: the check is the same either way).
    delta = np.concatenate([[0.0], np.cumsum(rng.uniform(0.005, 0.04, N_FRAMES - 1))])
    sweep = in_plane_sweep(rng, delta)
    unchecked = track_keypoints(sweep.frames, delta, replace(SMALL, max_window_dissimilarity=1e9, affine_step_px=0.01,
                                                             shading_ramp=False))
    assert np.max(max_errors(unchecked, sweep)) > MAX_TOL_PX


def test_lk_starts_from_the_last_step(rng):
    # A fast sweep (0.8 rad in 12 frames: up to ~11 px per frame at the plate's rim). LK searching one level
    # from each track's last step keeps every track that the full pyramid from rest keeps, at the same error;
    # one level from rest (what the crop and levels would be without the prediction) loses the fast ones.
    delta = smooth_delta(12)
    sweep = in_plane_sweep(rng, delta)
    cold = track_keypoints(sweep.frames, delta, replace(SMALL, predicted_max_level=None))
    warm = track_keypoints(sweep.frames, delta, replace(SMALL, predicted_max_level=0))
    blind = track_keypoints(sweep.frames, delta, replace(SMALL, max_level=0, predicted_max_level=None))
    assert len(cold.tracks) >= 50
    assert len(warm.tracks) >= len(cold.tracks) - 1
    assert np.max(max_errors(warm, sweep)) < MAX_TOL_PX
    assert np.median(max_errors(warm, sweep)) < MEDIAN_TOL_PX
    assert len(blind.tracks) < 0.9 * len(cold.tracks)


def test_tracks_feed_the_solver_types(tracked):
    for t in tracked.tracks:
        assert isinstance(t, KeypointTrack)
        assert t.pixels.dtype == np.float64 and t.pixels.shape == (len(t), 2)
        assert t.delta.dtype == np.float64 and t.delta.shape == (len(t),)


# --- failures the checks must catch ---------------------------------------------------------------


@pytest.mark.parametrize("affine_iterations", [0, 10], ids=["fb_only", "fb_and_affine"])
def test_corrupted_frame_ends_tracks(rng, affine_iterations):
    sweep = in_plane_sweep(rng)
    bad = 25
    frames = list(sweep.frames)
    frames[bad] = rng.integers(0, 256, SIZE, dtype=np.uint8)
    config = TrackerConfig(max_corners=200, min_distance_px=7.0, redetect_every=0,
                           affine_iterations=affine_iterations)
    result = track_keypoints(frames, sweep.delta, config)
    # Every track started in frame 0 (no re-detection) and none reaches the bad frame; the corners that
    # were still alive before it end exactly there.
    for t in result.tracks:
        assert len(t) <= bad
        np.testing.assert_array_equal(t.delta, sweep.delta[:len(t)])
    assert sum(len(t) == bad for t in result.tracks) >= 30
    assert result.n_truncated == len(result.tracks)
    assert_counts_add_up(result)


def test_fb_check_ends_tracks_without_affine_check(rng):
    # The noise frame must be caught by the forward-backward check itself: with a huge fb threshold
    # and no affine check, the tracks run through it (so the test above really exercises the fb check).
    sweep = in_plane_sweep(rng)
    frames = list(sweep.frames)
    frames[25] = rng.integers(0, 256, SIZE, dtype=np.uint8)
    lax = TrackerConfig(max_corners=200, min_distance_px=7.0, redetect_every=0, affine_iterations=0,
                        fb_max_px=1e6)
    result = track_keypoints(frames, sweep.delta, lax)
    assert max(len(t) for t in result.tracks) > 25


def test_static_sweep_gives_no_tracks(rng):
    still = noise_texture(rng, SIZE).astype(np.uint8)
    result = track_keypoints([still] * 10, np.linspace(0.0, 0.5, 10))
    assert result.tracks == [] and result.n_detected == 0
    assert_counts_add_up(result)


def test_static_sweep_with_sensor_noise_gives_no_tracks(rng):
    # Noise under the motion threshold never reaches detection; noise over it does, but the corners
    # found there do not move and are dropped as static.
    still = noise_texture(rng, SIZE)
    frames = [np.clip(np.rint(still + rng.normal(0.0, 2.0, SIZE)), 0, 255).astype(np.uint8) for _ in range(12)]
    quiet = track_keypoints(frames, np.zeros(12), SMALL)
    assert quiet.tracks == [] and quiet.n_detected == 0
    noisy = track_keypoints(frames, np.zeros(12), TrackerConfig(motion_threshold=3, mask_open_px=0))
    assert noisy.tracks == [] and noisy.n_detected > 0
    assert_counts_add_up(noisy)



@pytest.mark.parametrize("config", [SMALL, replace(SMALL, quadratic_warp=True), replace(SMALL, affine_iterations=0)],
                         ids=["default", "quadratic", "plain-lk"])
def test_a_blank_first_frame_leaves_the_tracks_to_re_detection(rng, config):
    """A first frame with no corners on the moving plate (a camera still settling its exposure): no track
    starts there, re-detection starts them later (this crashed once: the empty first set could not take them)."""
    sweep = in_plane_sweep(rng)
    frames = [np.full(SIZE, 128, np.uint8)] + list(sweep.frames[1:])
    result = track_keypoints(frames, sweep.delta, config)
    assert_counts_add_up(result)
    assert len(result.tracks) >= 20
    assert min(t.delta[0] for t in result.tracks) == sweep.delta[config.redetect_every]
    if config.affine_iterations:
        assert np.median(max_errors(result, sweep)) < MEDIAN_TOL_PX

# --- moving mask ----------------------------------------------------------------------------------


def test_moving_mask_covers_the_swept_plate_only(rng):
    sweep = in_plane_sweep(rng)
    mask = moving_mask(sweep.frames, SMALL)
    assert mask.shape == SIZE and mask.dtype == np.bool_
    alpha = disc(SIZE, PLATE_CENTRE, PLATE_RADIUS)
    swept = np.zeros(SIZE, dtype=bool)
    for d in sweep.delta:
        swept |= cv2.warpAffine(alpha, rotation_about(CENTRE, d)[:2], SIZE[::-1]) > 0.5
    assert mask[swept].mean() > 0.98
    reach = cv2.dilate(swept.astype(np.uint8), np.ones((2 * SMALL.mask_dilate_px + 3,) * 2, np.uint8)) > 0
    assert not np.any(mask & ~reach)


def test_moving_mask_accepts_rgb(rng):
    sweep = in_plane_sweep(rng, smooth_delta(6))
    rgb = [np.repeat(f[..., None], 3, axis=2) for f in sweep.frames]
    np.testing.assert_array_equal(moving_mask(rgb), moving_mask(sweep.frames))


def test_rgb_frames_give_the_same_tracks(rng):
    sweep = in_plane_sweep(rng, smooth_delta(15, 0.3))
    rgb = [np.repeat(f[..., None], 3, axis=2) for f in sweep.frames]
    grey_result = track_keypoints(sweep.frames, sweep.delta, SMALL)
    rgb_result = track_keypoints(rgb, sweep.delta, SMALL)
    assert len(grey_result.tracks) == len(rgb_result.tracks) > 0
    for a, b in zip(grey_result.tracks, rgb_result.tracks, strict=True):
        np.testing.assert_array_equal(a.pixels, b.pixels)


# --- curved surfaces ------------------------------------------------------------------------------

#: The rolling cylinder: its axis is the image column CYLINDER_COLUMN, radius CYLINDER_RADIUS px, seen
#: orthographically, so a surface point at angle phi from the view direction is at column c + R sin(phi).
CYLINDER_COLUMN = 160.0
CYLINDER_RADIUS = 80.0
CYLINDER_FRAMES = 30
CYLINDER_SPAN_RAD = 0.6
#: Tracks whose surface angle stays within this of the view direction are scored (nearer the rim the
#: texture is foreshortened by more than half, and no patch model holds).
CYLINDER_SCORED_RAD = 0.7

#: The small sweeps' settings with a uniform patch window (the default weighs it by a Gaussian), and with the
#: quadratic patch warp over it (its prior and bend check at their defaults).
UNIFORM = replace(SMALL, window_sigma_px=0.0)
QUADRATIC = replace(UNIFORM, quadratic_warp=True)


def cylinder_sweep(rng: np.random.Generator) -> tuple[list[np.ndarray], np.ndarray, PointMap]:
    """A textured cylinder rolling about its own (vertical) axis in front of a static background.

    Each frame is built column by column: pixel column u shows the surface at angle
    phi = arcsin((u - c) / R), i.e. the texture at arc length (phi - delta) R. The image motion of a
    surface point, R cos(phi) per radian, is curved across any patch (fastest facing the camera, zero at
    the rim), which an affine patch model cannot follow: it lags the point.

    Returns:
        frames (F, uint8 (H, W)), delta (F,) rad and move(p, d_from, d_to), the ground truth.
    """
    s = np.linspace(0.0, 1.0, CYLINDER_FRAMES)
    delta = CYLINDER_SPAN_RAD * s * s * (3.0 - 2.0 * s)
    background = noise_texture(rng, SIZE)
    texture = noise_texture(rng, (SIZE[0], int(2 * np.pi * CYLINDER_RADIUS) + 8))  # rows x arc length
    u = np.arange(SIZE[1], dtype=np.float64)
    inside = np.abs(u - CYLINDER_COLUMN) < CYLINDER_RADIUS - 0.5
    phi = np.arcsin(np.clip((u - CYLINDER_COLUMN) / CYLINDER_RADIUS, -1.0, 1.0))
    rows = np.tile(np.arange(SIZE[0], dtype=np.float32)[:, None], (1, SIZE[1]))
    frames = []
    for d in delta:
        arc = np.tile(((phi - d + np.pi) * CYLINDER_RADIUS).astype(np.float32), (SIZE[0], 1))
        surface = cv2.remap(texture, arc, rows, cv2.INTER_CUBIC)
        frames.append(np.clip(np.rint(np.where(inside[None, :], surface, background)), 0, 255).astype(np.uint8))

    def move(p: np.ndarray, d_from: float, d_to: float) -> np.ndarray:
        angle = np.arcsin(np.clip((p[0] - CYLINDER_COLUMN) / CYLINDER_RADIUS, -1.0, 1.0)) - d_from
        return np.array([CYLINDER_COLUMN + CYLINDER_RADIUS * np.sin(angle + d_to), p[1]])

    return frames, delta, move


def cylinder_end_errors(config: TrackerConfig) -> np.ndarray:
    """(T,) px: signed error along the motion at the last frame of the scored full-sweep tracks."""
    frames, delta, move = cylinder_sweep(np.random.default_rng(3))
    result = track_keypoints(frames, delta, config)
    errors = []
    for t in result.tracks:
        start = np.arcsin(np.clip((t.pixels[0, 0] - CYLINDER_COLUMN) / CYLINDER_RADIUS, -1, 1)) - t.delta[0]
        if len(t) < CYLINDER_FRAMES - 2 or max(abs(start + t.delta[0]), abs(start + t.delta[-1])) > CYLINDER_SCORED_RAD:
            continue
        errors.append(t.pixels[-1, 0] - move(t.pixels[0], t.delta[0], t.delta[-1])[0])
    return np.array(errors)


def test_quadratic_warp_follows_a_rolling_cylinder():
    # Seen 2026-11-26: median -0.016 px (quadratic, the default prior) against -0.13 px (affine).
    errors = cylinder_end_errors(QUADRATIC)
    assert len(errors) >= 30
    assert abs(np.median(errors)) < 0.04
    assert np.median(np.abs(errors)) < 0.08


def test_the_bend_check_ends_tracks_that_straddle_the_plate_rim():
    # Teeth for the accuracy test's tolerance with the quadratic warp: without the bend check, patches on
    # the turning plate's rim bend to follow the background too and slide (seen: 1.44 px).
    sweep = in_plane_sweep(np.random.default_rng(7))
    unchecked = track_keypoints(sweep.frames, sweep.delta, replace(QUADRATIC, max_bend_px=1e9))
    assert max_errors(unchecked, sweep).max() > MAX_TOL_PX


@pytest.mark.parametrize("config", [QUADRATIC, UNIFORM], ids=["quadratic", "uniform"])
def test_patch_model_variants_follow_ground_truth(sweep, config):
    # The plates turn rigidly on flat surfaces: the quadratic warp and the uniform window must be as exact
    # there as the default (an affine fit over a Gaussian-weighted window).
    result = track_keypoints(sweep.frames, sweep.delta, config)
    assert len(result.tracks) >= 30
    errors = np.concatenate([track_errors(t, sweep) for t in result.tracks])
    assert np.median(errors) < MEDIAN_TOL_PX
    assert errors.max() < MAX_TOL_PX


def test_a_gaussian_window_halves_the_lag_on_a_rolling_cylinder():
    # The lag is the window's curvature bias (~ its second moment): a Gaussian of 4 px over the 21 px window
    # weighs the centre. Seen 2026-11-26: median -0.060 px (4 px), -0.031 (3 px) against -0.132 (uniform).
    errors = cylinder_end_errors(SMALL)
    assert len(errors) >= 30
    assert -0.08 < np.median(errors) < 0.0
    assert np.median(np.abs(errors)) < 0.09


def test_a_very_wide_gaussian_window_is_the_uniform_window(sweep):
    # An independent check of the weighting's algebra: weights that are all ~1 change nothing.
    uniform = track_keypoints(sweep.frames, sweep.delta, UNIFORM)
    wide = track_keypoints(sweep.frames, sweep.delta, replace(SMALL, window_sigma_px=1e5))
    assert len(wide.tracks) == len(uniform.tracks)
    for a, b in zip(uniform.tracks, wide.tracks, strict=True):
        np.testing.assert_allclose(a.pixels, b.pixels, atol=1e-3)


def test_affine_warp_lags_on_a_rolling_cylinder():
    # Teeth for the test above: the affine patch fit lags every point on the curved surface.
    errors = cylinder_end_errors(UNIFORM)
    assert len(errors) >= 30
    assert np.median(errors) < -0.08


def shaded_sweep(rng: np.random.Generator, contrast: float = 12.0, slope: float = 0.008) -> Sweep:
    """The in-plane plate with a faint texture (standard deviation ``contrast`` grey levels about 150) under a
    light fixed to the image: brightness times 1 + slope (y - 120) + slope / 2 (x - 160), as a casting turning
    under a lamp (the shading stays while the texture turns through it)."""
    delta = smooth_delta()
    background = noise_texture(rng, SIZE)
    texture = 150.0 + (noise_texture(rng, SIZE) - 128.0) * contrast / 50.0
    alpha = disc(SIZE, PLATE_CENTRE, PLATE_RADIUS)
    yy, xx = np.mgrid[0:SIZE[0], 0:SIZE[1]].astype(np.float32)
    shade = 1.0 + slope * (yy - 120.0) + 0.5 * slope * (xx - 160.0)
    frames = []
    for d in delta:
        M = rotation_about(CENTRE, d)[:2]
        frames.append(composite(background, cv2.warpAffine(texture, M, SIZE[::-1], flags=cv2.INTER_CUBIC) * shade,
                                cv2.warpAffine(alpha, M, SIZE[::-1], flags=cv2.INTER_LINEAR)))
    plate = in_plane_sweep(np.random.default_rng(0), delta)  # its geometry only
    return Sweep(frames, delta, plate.move, plate.plate_distance)


def shaded_end_errors(config: TrackerConfig) -> np.ndarray:
    """(T,) px: distance from the truth at the last frame of the tracks well inside the shaded plate."""
    sweep = shaded_sweep(np.random.default_rng(7))
    result = track_keypoints(sweep.frames, sweep.delta, config)
    inside = [t for t in result.tracks if sweep.plate_distance(t.pixels[0], t.delta[0]) < PLATE_RADIUS - 12.0]
    return np.array([np.linalg.norm(t.pixels[-1] - sweep.move(t.pixels[0], t.delta[0], t.delta[-1]))
                     for t in inside])


def test_the_shading_ramp_keeps_faint_texture_on_its_point_under_a_fixed_light():
    # Seen 2026-11-29: mean end error 0.042 px with the ramp, 0.259 px without (the next test).
    errors = shaded_end_errors(SMALL)
    assert len(errors) >= 40
    assert np.mean(errors) < 0.08


def test_without_the_shading_ramp_faint_texture_is_pulled_by_the_shading():
    # Teeth for the test above: the same sweep, the fit modelling only an offset and a gain.
    errors = shaded_end_errors(replace(SMALL, shading_ramp=False))
    assert len(errors) >= 40
    assert np.mean(errors) > 0.15


def test_the_ramp_basis_removes_exactly_a_weighted_plane_fit():
    # Independent construction: weighted least squares of the patch on (1, x, y), its residual times the root weights.
    config = SMALL
    basis = _photometric_basis(config)
    root = _root_weights(config)
    assert basis is not None and root is not None
    np.testing.assert_allclose(basis.T @ basis, np.eye(3), atol=1e-5)
    rng = np.random.default_rng(1)
    patches = rng.normal(100.0, 20.0, (4, config.win_size_px ** 2)).astype(np.float32)
    offsets = _patch_offsets(config.win_size_px).astype(np.float64)
    design = np.column_stack([np.ones(len(offsets)), offsets]) * root[:, None]
    for patch, got in zip(patches, _centred(patches, root, basis), strict=True):
        coef = np.linalg.lstsq(design, patch * root, rcond=None)[0]
        np.testing.assert_allclose(got, patch * root - design @ coef, atol=2e-3)
    ramp = 30.0 + 0.7 * offsets[:, 0] - 1.3 * offsets[:, 1]
    assert np.abs(_centred(ramp[None].astype(np.float32), root, basis)).max() < 1e-3
    assert _photometric_basis(replace(SMALL, shading_ramp=False)) is None


# --- full resolution ------------------------------------------------------------------------------


def test_full_hd_sweep(rng):
    # One 1920x1080 sweep through the default settings (timing-free; the figure is in the report).
    delta = smooth_delta(12, 0.3)
    sweep = in_plane_sweep(rng, delta, size=(1080, 1920), scale=4.5)
    result = track_keypoints(sweep.frames, delta)
    assert len(result.tracks) >= 100
    errors = np.concatenate([track_errors(t, sweep) for t in result.tracks])
    assert np.median(errors) < MEDIAN_TOL_PX and errors.max() < MAX_TOL_PX


# --- input checks ---------------------------------------------------------------------------------


def _frames(n: int = 3, shape: tuple[int, ...] = (24, 32)) -> list[np.ndarray]:
    return [np.zeros(shape, np.uint8) for _ in range(n)]


@pytest.mark.parametrize(
    ("frames", "delta", "match"),
    [
        (_frames(1), np.zeros(1), "at least 2 frames"),
        ([], np.zeros(0), "at least 2 frames"),
        (_frames(2) + _frames(1, (24, 31)), np.zeros(3), "frame 2 has shape"),
        (_frames(3), np.zeros(4), r"delta must be \(3,\)"),
        (_frames(3), np.zeros((3, 1)), r"delta must be \(3,\)"),
        (_frames(3), np.array([0.0, np.nan, 0.1]), "NaN"),
        (_frames(3, (0, 32)), np.zeros(3), "frame 0 is empty"),
        ([np.zeros((24, 32), np.float32)] * 3, np.zeros(3), "must be uint8"),
        (_frames(3, (24, 32, 4)), np.zeros(3), r"\(H, W, 3\) RGB"),
        (np.zeros(5, np.uint8), np.zeros(5), r"\(H, W\) grey"),
    ],
    ids=["one_frame", "no_frames", "shape_mismatch", "delta_length", "delta_2d", "delta_nan", "empty_image",
         "float_image", "four_channels", "scalar_frames"],
)
def test_bad_input_raises(frames, delta, match):
    with pytest.raises(InvalidInputError, match=match):
        track_keypoints(frames, delta)


def test_moving_mask_rejects_bad_input():
    with pytest.raises(InvalidInputError, match="at least 2 frames"):
        moving_mask(_frames(1))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"win_size_px": 20}, "win_size_px must be odd"),
        ({"quality_level": 0.0}, "quality_level"),
        ({"fb_max_px": 0.0}, "fb_max_px"),
        ({"min_track_frames": 1}, "min_track_frames"),
        ({"redetect_every": -1}, "redetect_every"),
        ({"criteria": (3, 0, 0.01)}, "criteria"),
        ({"max_dissimilarity": -1.0}, "max_dissimilarity"),
        ({"quadratic_ridge": -0.1}, "quadratic_ridge"),
        ({"window_sigma_px": -1.0}, "window_sigma_px"),
        ({"window_sigma_px": float("nan")}, "window_sigma_px"),
        ({"max_window_dissimilarity": 0.0}, "max_window_dissimilarity"),
        ({"max_window_dissimilarity": float("nan")}, "max_window_dissimilarity"),
        ({"max_bend_px": 0.0}, "max_bend_px"),
        ({"affine_step_px": 0.0}, "affine_step_px"),
        ({"affine_step_px": float("nan")}, "affine_step_px"),
        ({"predicted_max_level": -1}, "predicted_max_level"),
        ({"max_level": 1, "predicted_max_level": 2}, "predicted_max_level"),
        ({"blas_threads": 0}, "blas_threads"),
        ({"blas_threads": 1.5}, "blas_threads"),
    ],
    ids=lambda v: str(v) if isinstance(v, dict) else "",
)
def test_bad_config_raises(kwargs, match):
    with pytest.raises(InvalidInputError, match=match):
        TrackerConfig(**kwargs)


def test_tracking_runs_blas_on_the_configured_threads_and_restores_them(rng, monkeypatch):
    from threadpoolctl import threadpool_info, threadpool_limits

    import arc_env.robot.tracking as tracking

    seen: list[int] = []
    grey_frames = tracking._grey_frames

    def spy(frames):  # called inside track_keypoints
        seen.extend(info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas")
        return grey_frames(frames)

    monkeypatch.setattr(tracking, "_grey_frames", spy)
    sweep = in_plane_sweep(rng)
    with threadpool_limits(limits=2, user_api="blas"):
        for threads in (1, None):
            seen.clear()
            track_keypoints(sweep.frames, sweep.delta, TrackerConfig(max_corners=50, blas_threads=threads))
            assert seen and set(seen) == ({1} if threads == 1 else {2})
        assert {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"} == {2}


def test_tracking_never_imports_mujoco():
    code = "import sys, arc_env.robot.tracking; print('mujoco' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_a_track_lost_for_a_frame_is_found_again(rng):
    """Noise over the plate's left half in one frame: LK loses those tracks there; refind_frames brings them back."""
    sweep = in_plane_sweep(rng)
    bad, edge = 25, int(PLATE_CENTRE[0])
    frames = list(sweep.frames)
    frames[bad] = frames[bad].copy()
    frames[bad][:, :edge] = rng.integers(0, 256, (SIZE[0], edge), dtype=np.uint8)
    base = TrackerConfig(max_corners=200, min_distance_px=7.0, redetect_every=0)
    ended = track_keypoints(frames, sweep.delta, base)
    found = track_keypoints(frames, sweep.delta, replace(base, refind_frames=3))
    assert_counts_add_up(found)

    def crossing_the_noise(result: TrackingResult) -> list[KeypointTrack]:
        """Tracks that were in the noisy half just before the bad frame and go on after it."""
        return [t for t in result.tracks if sweep.delta[bad - 1] in t.delta and t.delta[-1] > sweep.delta[bad]
                and t.pixels[list(t.delta).index(sweep.delta[bad - 1]), 0] < edge - 15]

    assert crossing_the_noise(ended) == []
    back = crossing_the_noise(found)
    assert len(back) >= 15
    for t in back:  # found again one frame later, following the same point
        assert sweep.delta[bad] not in t.delta and len(t) == N_FRAMES - 1
        assert track_errors(t, sweep).max() < MAX_TOL_PX
    with pytest.raises(InvalidInputError, match="refind_frames"):
        TrackerConfig(refind_frames=-1)
