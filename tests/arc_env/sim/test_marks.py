"""Labels and cables of the realistic appearance: drawn and part of the robot's image, seeded, and invisible to
everything else (collision, kinematics, inertia, the oracle's surface points)."""

import mujoco
import numpy as np
import pytest

from arc_env.robot.model import RobotSource
from arc_env.sim.marks import MARK_GROUP, label_design
from arc_env.sim.scene import Scene, SceneConfig
from planners.collision import CollisionChecker
from solver import look_at

#: A camera close enough that 5-10 mm cables cover whole pixels at 320x240.
CAMERA = look_at(np.array([1.6, 0.7, 1.0]), np.array([0.3, 0.0, 0.45]), 0.2)
#: Grey levels: a link whose material is near black stays within this of its as-shipped shade under marks.
SHADE_TOL = 12.0


def _scene(look: str, seed: int = 0, robot: RobotSource | None = None) -> Scene:
    scene = Scene(SceneConfig(robot=robot or RobotSource(), width=320, height=240, blur_px=0.0, appearance=look,
                              appearance_seed=seed))
    scene.set_camera(CAMERA)
    return scene


@pytest.fixture(scope="module")
def scenes():
    made = {"as_shipped": _scene("as_shipped"), "realistic": _scene("realistic"),
            "again": _scene("realistic"), "other": _scene("realistic", seed=3)}
    yield made
    for scene in made.values():
        scene.close()


def _mark_geoms(scene: Scene) -> np.ndarray:
    return np.nonzero(scene.model.geom_group == MARK_GROUP)[0]


def test_realistic_adds_visual_only_labels_and_cables(scenes):
    plain, real = scenes["as_shipped"], scenes["realistic"]
    marks = real.marks
    assert marks is not None and len(marks.labels) >= 1 and len(marks.cables) >= 1
    added = _mark_geoms(real)
    assert len(added) == len(marks.labels) + sum(len(c.points) - 1 for c in marks.cables)
    m = real.model
    assert np.all(m.geom_contype[added] == 0) and np.all(m.geom_conaffinity[added] == 0)
    # the bodies keep their ids, masses and inertias (the marks weigh nothing); the original geoms their order
    kept = np.nonzero(m.geom_group != MARK_GROUP)[0]
    assert m.nbody == plain.model.nbody and len(kept) == plain.model.ngeom
    assert len(set(m.geom_bodyid[added])) > 1 and kept[-1] > added.min()  # marks sit between other links' geoms
    for name in ("geom_bodyid", "geom_type", "geom_dataid", "geom_group"):
        np.testing.assert_array_equal(getattr(m, name)[kept], getattr(plain.model, name), err_msg=name)
    for name in ("body_mass", "body_inertia", "body_ipos", "body_iquat", "body_subtreemass"):
        np.testing.assert_array_equal(getattr(m, name), getattr(plain.model, name), err_msg=name)
    # what the planners and the oracle read of the robot is unchanged
    assert real.robot.rendered_geoms() == kept[plain.robot.rendered_geoms()].tolist()
    for joint in range(real.robot.n_joints):
        for a, b in zip(real.robot.surface_points(joint), plain.robot.surface_points(joint), strict=True):
            np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(4)
    qs = rng.uniform(real.robot.lower, real.robot.upper, (60, real.robot.n_joints))
    for q in qs[:5]:
        for joint in (0, 3, 6):
            for a, b in zip(real.robot.axis_and_point(q, joint), plain.robot.axis_and_point(q, joint), strict=True):
                np.testing.assert_array_equal(a, b)
    checkers = [CollisionChecker(s.model, s.robot.arm_joints, qpos_ref=s.robot.data.qpos.copy()) for s in (real, plain)]
    np.testing.assert_array_equal(kept[checkers[1].pairs], checkers[0].pairs)  # the same pairs of the same geoms
    hits = [[c.in_collision(q)[0] for q in qs] for c in checkers]
    assert hits[0] == hits[1] and 0 < sum(hits[0]) < len(qs)  # both answers occur among the samples


def test_marks_wear_their_own_colours_whatever_the_links_class(scenes):
    other = scenes["other"]  # seed 3 puts cables on the fingers, whose class colours geoms light blue
    m = other.model
    fingers = [m.body(n).id for n in ("panda0_leftfinger", "panda0_rightfinger")]
    assert any(c.body in fingers for c in other.marks.cables)
    for g in _mark_geoms(other):
        cable = m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE
        assert np.all(m.geom_rgba[g][:3] < 0.15) if cable else np.all(m.geom_rgba[g] == 1.0), m.geom(g).name


def test_marks_are_part_of_the_robot_image_and_mask(scenes):
    plain, real = scenes["as_shipped"], scenes["realistic"]
    mask_plain, mask_real = plain.robot_mask(), real.robot_mask()
    assert not (mask_plain & ~mask_real).any()  # marks cover only the robot or add to it
    assert (mask_real & ~mask_plain).sum() >= 10  # cables stand out of the silhouette
    # the marks' own pixels: dark cable and label print over the near-white Panda
    dark = real.render().mean(axis=2) < 60
    assert (dark & mask_real).sum() > 2 * (plain.render().mean(axis=2) < 60)[mask_plain].sum()


def test_marks_are_seeded(scenes):
    real, again, other = scenes["realistic"], scenes["again"], scenes["other"]
    for a, b in zip(real.marks.labels, again.marks.labels, strict=True):
        np.testing.assert_array_equal(a.pos, b.pos)
        np.testing.assert_array_equal(a.design, b.design)
    for a, b in zip(real.marks.cables, again.marks.cables, strict=True):
        np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(real.render(), again.render())
    placed = [sorted((c.body, tuple(np.round(c.points[0], 6))) for c in s.marks.cables) for s in (real, other)]
    assert placed[0] != placed[1]
    assert real.marks.patterns != other.marks.patterns


@pytest.mark.parametrize("look", ["painted", "as_shipped"])
def test_no_marks_under_the_other_appearances(scenes, look):
    scene = scenes["as_shipped"] if look == "as_shipped" else _scene(look)
    assert scene.marks is None and len(_mark_geoms(scene)) == 0
    assert scene.model.nbody == scenes["as_shipped"].model.nbody


ONE_LINK = """<mujoco><asset><material name="black" rgba=".06 .06 .07 1"/></asset><worldbody>
  <body name="base"><geom type="cylinder" size=".08 .05" pos="0 0 .05" rgba=".8 .8 .8 1"/>
    <body name="link" pos="0 0 .1"><joint name="j" axis="0 0 1" range="-2 2"/>
      <geom type="box" size=".05 .05 .25" pos="0 0 .25" material="black"/></body></body></worldbody></mujoco>"""


def test_seams_and_screws_keep_the_links_own_colour(tmp_path):
    path = tmp_path / "one_link.xml"
    path.write_text(ONE_LINK)
    robot = RobotSource(str(path), "base", home=())
    plain = _scene("as_shipped", robot=robot)
    box = int(np.nonzero(plain.model.geom_bodyid == plain.model.body("link").id)[0][0])
    seed = next(s for s in range(20) if box in _scene("realistic", s, robot).marks.patterns)
    real = _scene("realistic", seed, robot)
    assert box in real.marks.materials  # the black box wears seams or screws
    image = plain.render().mean(axis=2)
    black = plain.robot_mask() & (image < 60)  # the box's pixels (the base is light grey)
    assert black.sum() > 200
    shade = np.median(real.render().mean(axis=2)[black])
    assert abs(shade - np.median(image[black])) < SHADE_TOL  # a white material would give ~200
    plain.close()
    real.close()


def test_label_design_is_a_light_ground_with_dark_print():
    rng = np.random.default_rng(0)
    for _ in range(5):
        image = label_design(rng).astype(float).mean(axis=2)
        assert np.median(image) > 150
        assert 0.03 < (image < 60).mean() < 0.5
