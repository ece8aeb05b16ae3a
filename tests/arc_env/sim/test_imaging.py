"""Realistic imaging: appearances change only the robot's pixels, effects have their stated sizes, seeded."""

import numpy as np
import pytest

from arc_env.bench.poses import benchmark_camera_pose
from arc_env.sim.imaging import CameraEffects, h264_round_trip, realism_settings
from arc_env.sim.scene import Scene, SceneConfig
from solver.errors import InvalidInputError

#: Grey levels: the realistic preset's noise is "about 3" (read 2, shot ~2 at the robot's white).
NOISE_RANGE = (2.0, 3.5)


def _scene(**kwargs):
    scene = Scene(SceneConfig(width=320, height=180, blur_px=0.0, **kwargs))
    scene.set_camera(benchmark_camera_pose(0))
    return scene


def test_appearances_differ_only_on_the_robot():
    images, masks = {}, None
    for look in ("painted", "as_shipped", "realistic"):
        scene = _scene(appearance=look)
        images[look] = scene.render().astype(int)
        masks = scene.robot_mask()
        scene.close()
    for a, b in (("painted", "as_shipped"), ("realistic", "as_shipped")):
        changed = np.abs(images[a] - images[b]).max(axis=2) > 0
        assert changed.any() and not (changed & ~masks).any()
    # paint covers every link; the realistic marks only some
    changed = {k: (np.abs(images[k] - images["as_shipped"]).max(axis=2) > 8)[masks].mean()
               for k in ("painted", "realistic")}
    assert changed["painted"] > changed["realistic"] > 0.0


def test_noise_and_gain_have_their_stated_sizes_and_are_seeded():
    effects = CameraEffects(read_noise_grey=2.0, shot_noise_grey2=0.016, gain_drift=0.05)
    flat = [np.full((60, 80, 3), 200, np.uint8) for _ in range(12)]
    a = effects.apply(flat, np.random.default_rng(1))
    b = effects.apply(flat, np.random.default_rng(1))
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    expected = np.sqrt(2.0**2 + 0.016 * 200)
    residual = np.std([f.astype(float) - f.astype(float).mean() for f in a])
    assert abs(residual - expected) < 0.15 * expected
    means = np.array([f.mean() for f in a]) / 200
    assert 0.005 < np.ptp(means) <= 2 * 0.05 + 0.01


def test_motion_blur_averages_over_the_exposure():
    sharp = _scene()
    blurred = _scene(effects=CameraEffects(exposure_s=0.05, subframes=5))
    q = sharp.robot.home
    a = sharp.render_sweep(q, 0, np.array([0.0, 0.3]), joint_speed=1.0)
    b = blurred.render_sweep(q, 0, np.array([0.0, 0.3]), joint_speed=1.0)
    mask = sharp.robot_mask()
    gradient = [np.abs(np.diff(f.mean(axis=2), axis=1))[mask[:, 1:]].mean() for f in (a[1], b[1])]
    assert gradient[1] < gradient[0]  # edges smeared along the motion
    np.testing.assert_array_equal(sharp.robot.q, blurred.robot.q)  # both left at the last frame
    with pytest.raises(InvalidInputError, match="random generator"):
        _scene(effects=CameraEffects(read_noise_grey=1.0)).render_sweep(q, 0, np.array([0.0, 0.3]))


def test_h264_round_trip_is_lossy_but_close():
    y, x = np.mgrid[0:72, 0:128]
    base = np.stack([x * 2, y * 3, (x + y) % 256], axis=2).astype(np.uint8)  # smooth, like a scene
    base[20:40, 30:60] = 30
    frames = [np.roll(base, k, axis=1) for k in range(8)]
    out = h264_round_trip(frames, 8_000_000)
    assert len(out) == 8 and out[0].shape == frames[0].shape
    error = np.mean([np.abs(o.astype(int) - f.astype(int)).mean() for o, f in zip(out, frames, strict=True)])
    assert 0 < error < 8  # lossy, yet the same pictures (grey levels)


def test_presets():
    clean = realism_settings("clean")
    assert clean["appearance"] == "painted" and not clean["effects"].active and not clean["shadows"]
    real = realism_settings("realistic")
    assert real["appearance"] == "realistic" and real["effects"].video_bitrate and real["shadows"]
    assert realism_settings("realistic", "as_shipped")["appearance"] == "as_shipped"
    with pytest.raises(InvalidInputError, match="realism must be one of"):
        realism_settings("filmic")
