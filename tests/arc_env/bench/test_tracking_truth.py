"""The simulator's tracking truth: ray-cast surface points and the tracker-error summary, against
surface points built from the depth and segmentation renders and projected with ``project_points``."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from arc_env.bench.tracking_truth import motion_truth, summary, true_pixels
from arc_env.robot.session import SeenMotion
from arc_env.sim.scene import Scene
from solver.observations import KeypointTrack

JOINT = 3
DELTAS = np.linspace(0.0, 0.4, 9)


def rendered_surface_points(scene: Scene, q: np.ndarray, n: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points on the links JOINT moves, built from the depth and segmentation renders (not ray casts).

    Random pixels that show those links at delta 0 are lifted to 3D with the rendered depth and put in the
    frame of the body the segmentation names. Returns body ids (P,), local points (P, 3) m and their
    projections at every delta (F, P, 2) px (``project_points``), the first frame's being the pixels.
    """
    robot = scene.robot
    robot.set_swept(q, JOINT, 0.0)
    depth = scene.depth()
    renderer = scene.renderer
    scene._update(None)
    renderer.enable_segmentation_rendering()
    try:
        segmentation = renderer.render().copy()
    finally:
        renderer.disable_segmentation_rendering()
    moved = np.unique(robot.surface_points(JOINT)[0])
    geom = np.where(segmentation[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), segmentation[..., 0], -1)
    body_of = np.where(geom >= 0, scene.model.geom_bodyid[np.clip(geom, 0, None)], -1)
    rows, cols = np.nonzero(np.isin(body_of, moved))
    pick = np.random.default_rng(0).choice(len(rows), n, replace=False)
    rows, cols = rows[pick], cols[pick]
    ray = np.linalg.inv(scene.intrinsics.K) @ np.vstack([cols, rows, np.ones(n)])
    camera = (ray * depth[rows, cols]).T
    base = (camera - scene.T_camera_base[:3, 3]) @ scene.T_camera_base[:3, :3]
    world = base @ robot.T_world_base[:3, :3].T + robot.T_world_base[:3, 3]
    body = body_of[rows, cols]
    local = np.einsum("pji,pj->pi", scene.data.xmat[body].reshape(-1, 3, 3), world - scene.data.xpos[body])
    pixels = []
    for d in DELTAS:
        robot.set_swept(q, JOINT, d)
        pixels.append(scene.project_points(body, local, min_depth=0.05)[0])
    return body, local, np.array(pixels)


def test_a_surface_point_lies_under_its_pixel_at_the_rendered_depth(panda_scene):
    q = panda_scene.robot.home
    panda_scene.robot.set_q(q)
    depth = panda_scene.depth()
    mask = panda_scene.robot_mask()
    rows, cols = np.nonzero(mask)
    pick = np.random.default_rng(1).choice(len(rows), 50, replace=False)
    for v, u in zip(rows[pick], cols[pick], strict=True):
        hit = panda_scene.surface_point_at(np.array([u, v], dtype=float))
        assert hit is not None
        body, local = hit
        assert body in panda_scene.robot.robot_bodies
        uv, _ = panda_scene.project_points(np.array([body]), local[None, :], min_depth=0.0)
        np.testing.assert_allclose(uv[0], [u, v], atol=1e-6)
        point = panda_scene.robot.points_base(np.array([body]), local[None, :])[0]
        z = (panda_scene.T_camera_base[:3, :3] @ point + panda_scene.T_camera_base[:3, 3])[2]
        assert abs(z - depth[v, u]) < 1e-3
    assert panda_scene.surface_point_at(np.array([2.0, 2.0])) is None  # the corner shows floor or sky


def test_true_pixels_follow_the_mesh_points(panda_scene):
    q = panda_scene.robot.home
    body, local, pixels = rendered_surface_points(panda_scene, q)
    np.testing.assert_allclose(pixels[0], pixels[0].round(), atol=1e-3)  # the construction starts on pixels
    for p in range(len(body)):
        track = KeypointTrack(pixels[:, p], DELTAS)
        truth = true_pixels(panda_scene, q, JOINT, DELTAS, track)
        assert truth is not None
        np.testing.assert_allclose(truth, pixels[:, p], atol=0.05)  # the depth buffer's precision


def test_motion_truth_scores_a_lag(panda_scene):
    q = panda_scene.robot.home
    body, local, pixels = rendered_surface_points(panda_scene, q)
    exact = [KeypointTrack(pixels[:, p], DELTAS) for p in range(len(body))]
    # The same tracks lagging: each point 1 % short of its true displacement from the first frame.
    lagging = [KeypointTrack(t.pixels[0] + 0.99 * (t.pixels - t.pixels[0]), t.delta) for t in exact]
    rows = []
    for tracks in (exact, lagging):
        seen = SeenMotion(0, q, JOINT, DELTAS, None, tracks, None, None)  # type: ignore[arg-type]
        rows.append(motion_truth(panda_scene, seen))
    assert rows[0].on_links == len(exact) and rows[0].within_1px == 1.0
    assert abs(rows[0].chord_scale) < 1e-3 and rows[0].end_error_px < 0.05
    assert rows[1].chord_scale == pytest.approx(-0.01, abs=1e-3)
    result = summary(rows)
    assert result["motions"] == 2 and len(result["per_motion"]) == 2
