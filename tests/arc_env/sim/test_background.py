"""arc_env.sim.background: a lab behind the robot, never in front of it, never in the planners' way."""

import numpy as np
import pytest

from arc_env.bench.episodes import EpisodeSpec
from arc_env.sim.background import CLUTTER_ITEMS, DISTANCE_M, plan_clutter
from arc_env.sim.scene import Scene, SceneConfig
from planners.collision import CollisionChecker
from solver import InvalidInputError
from solver.synthetic import look_at

#: Cameras around the arm (eye, target): front right, behind left, high above the side.
CAMERAS = [(np.array([1.6, 0.7, 1.0]), np.array([0.3, 0.0, 0.45])),
           (np.array([-1.4, -1.2, 0.8]), np.array([0.2, 0.0, 0.5])),
           (np.array([0.2, 2.0, 1.8]), np.array([0.3, 0.0, 0.4]))]


@pytest.fixture(scope="module")
def scenes():
    floor = Scene(SceneConfig(width=480, height=270))
    lab = Scene(SceneConfig(width=480, height=270, background="lab", background_seed=3))
    yield floor, lab
    floor.close()
    lab.close()


def test_the_same_seed_gives_the_same_lab():
    a, b, c = plan_clutter(3), plan_clutter(3), plan_clutter(4)
    assert len(a) == CLUTTER_ITEMS
    assert all(x.half_size == y.half_size and np.array_equal(x.pattern, y.pattern) for x, y in zip(a, b, strict=True))
    assert any(x.half_size != y.half_size for x, y in zip(a, c, strict=True))
    assert all(DISTANCE_M[0] <= x.distance <= DISTANCE_M[1] for x in a)


@pytest.mark.parametrize("camera", range(len(CAMERAS)))
def test_the_lab_stands_behind_the_robot_and_shows(scenes, camera):
    """From any camera the robot's pixels are the same with the lab as without; the lab fills others."""
    floor, lab = scenes
    T = look_at(*CAMERAS[camera])
    for scene in scenes:
        scene.set_camera(T)
    np.testing.assert_array_equal(lab.robot_mask(), floor.robot_mask())
    changed = np.any(lab.render().astype(int) != floor.render().astype(int), axis=-1) & ~floor.robot_mask()
    assert changed.mean() > 0.05  # the clutter is in the picture (measured: 22-36 % of the pixels)
    # every item stands on the floor, beyond the arm's reach, on the far side of the base from the camera
    base = lab.robot.T_world_base[:3, 3]
    eye = (lab.robot.T_world_base @ np.linalg.inv(T))[:3, 3]
    for body in lab._clutter_bodies:
        pos = lab.data.xpos[body]
        assert np.linalg.norm(pos[:2] - base[:2]) >= DISTANCE_M[0] - 1e-9
        assert (pos[:2] - base[:2]) @ (eye[:2] - base[:2]) < 0


def test_the_planners_never_see_the_lab(scenes):
    floor, lab = scenes
    checkers = [CollisionChecker(s.model, s.robot.arm_joints) for s in scenes]
    names = [{lab_or_floor.model.geom(int(g)).name for pair in c.pairs for g in pair}
             for lab_or_floor, c in zip(scenes, checkers, strict=True)]
    assert names[0] == names[1] and not any(n.startswith("arc_clutter_") for n in names[1])


def test_bad_backgrounds_are_refused():
    with pytest.raises(InvalidInputError, match="background"):
        SceneConfig(background="garage")
    with pytest.raises(InvalidInputError, match="background"):
        EpisodeSpec("random", 0, 0, background="garage")
    assert EpisodeSpec("random", 0, 0).key == "random_1920x1080_m25_p0_s0"  # the floor keeps the old keys
    assert EpisodeSpec("random", 0, 0, realism="realistic", background="lab").key == \
        "random_realistic-default_lab_1920x1080_m25_p0_s0"
