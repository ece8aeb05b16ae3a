"""CollisionChecker on small inline MJCF scenes, cross-checked against MuJoCo's own collision detection."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

import planners
from planners.collision import CollisionChecker, FloatArray
from solver.errors import InvalidInputError

# A 3-link arm (yaw, pitch, pitch) on a static base, in a scene with one obstacle of every kind and
# a tilted plane behind the arm. Link 2 is a 0.3 m capsule at z = 0.4 m with a collar (a body welded
# to it) round joint 3; link 3 a 0.35 m box with a tetrahedron mesh at its tip.
ARM_XML = """
<mujoco model="three_link_arm">
  <compiler angle="radian"/>
  <asset>
    <mesh name="tetra" vertex="0 0 0  0.06 0 0  0 0.06 0  0 0 0.06"/>
    <mesh name="cube" vertex="-.05 -.05 -.05  .05 -.05 -.05  -.05 .05 -.05  .05 .05 -.05
                              -.05 -.05 .05  .05 -.05 .05  -.05 .05 .05  .05 .05 .05"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <geom name="backstop" type="plane" pos="-0.5 0 0" zaxis="1 0 0.3" size="1 1 0.1"/>
    <geom name="obstacle" type="box" pos="0.45 0.3 0.4" size="0.05 0.05 0.05"/>
    <geom name="crate" type="mesh" mesh="cube" pos="-0.45 0.2 0.35" euler="0.3 0.2 0.5"/>
    <geom name="ball" type="sphere" pos="-0.3 -0.45 0.45" size="0.06"/>
    <geom name="disc" type="cylinder" pos="0.0 -0.55 0.3" size="0.12 0.04"/>
    <geom name="egg" type="ellipsoid" pos="0.5 -0.35 0.2" size="0.05 0.08 0.12" euler="0.4 0 0.3"/>
    <body name="base" pos="0 0 0.05">
      <geom name="base" type="box" size="0.1 0.1 0.05"/>
      <body name="link1" pos="0 0 0.05">
        <joint name="j1" type="hinge" axis="0 0 1" range="-3.1 3.1"/>
        <geom name="link1" type="capsule" fromto="0 0 0.03  0 0 0.3" size="0.04"/>
        <body name="link2" pos="0 0 0.3">
          <joint name="j2" type="hinge" axis="0 1 0" range="-2.0 2.0"/>
          <geom name="link2" type="capsule" fromto="0 0 0  0.3 0 0" size="0.03"/>
          <body name="collar" pos="0.3 0 0">
            <geom name="collar" type="sphere" size="0.035"/>
          </body>
          <body name="link3" pos="0.3 0 0">
            <joint name="j3" type="hinge" axis="0 1 0" range="-3.1 3.1"/>
            <geom name="link3" type="box" pos="0.175 0 0" size="0.175 0.02 0.02"/>
            <geom name="tip" type="mesh" mesh="tetra" pos="0.35 0 0"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  CONTACT
</mujoco>
"""

# Body pairs the checker must not report, written out by hand for the cross-check: adjacent links
# (link1 on its static base; the collar belongs to link 2's weld group), the two static bodies, and
# the collar with link 2 (rigidly joined).
FILTERED_BODIES = {
    ("base", "link1"),
    ("link1", "link2"),
    ("link2", "link3"),
    ("link1", "collar"),
    ("collar", "link3"),
    ("link2", "collar"),
    ("world", "base"),
}

FREE_Q = np.array([math.pi / 2, 0.0, 0.0])  # arm along +y, clear of everything
OBSTACLE_Q = np.array([0.6, 0.0, 0.0])  # link 3 through the box obstacle
FLOOR_Q = np.array([0.0, 1.0, 0.6])  # links 2 and 3 pitched down, link 3 into the floor
FOLDED_Q = np.array([0.0, 0.0, 3.0])  # link 3 folded back over link 2, its end inside link 1
STRAIGHT_Q = np.zeros(3)  # adjacent links overlap at their joints

#: metres: configurations with any checked pair closer than this are left out of the MuJoCo
#: cross-check, where both engines' tolerances (GJK, MuJoCo's mesh collider) may differ.
NEAR_CONTACT = 0.003


def arm_model(contact: str = "") -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(ARM_XML.replace("CONTACT", contact))


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return arm_model()


@pytest.fixture(scope="module")
def checker(model) -> CollisionChecker:
    return CollisionChecker(model, [0, 1, 2])


def body_name(model, geom):
    return model.body(int(model.geom_bodyid[geom])).name


def mujoco_pairs(model, data, q) -> set[tuple[int, int]]:
    """Geom pairs in penetration by MuJoCo's mj_collision, minus the hand-listed filtered bodies."""
    data.qpos[:] = model.qpos0
    data.qpos[:3] = q
    mujoco.mj_forward(model, data)
    out = set()
    for contact in data.contact[: data.ncon]:
        g1, g2 = sorted((int(contact.geom1), int(contact.geom2)))
        bodies = (body_name(model, g1), body_name(model, g2))
        if contact.dist < 0 and bodies not in FILTERED_BODIES and bodies[::-1] not in FILTERED_BODIES:
            out.add((g1, g2))
    return out


def min_distance(model, data, pairs) -> float:
    """Smallest signed distance over the pairs by MuJoCo's mj_geomDistance (at the current data)."""
    return min(mujoco.mj_geomDistance(model, data, int(a), int(b), 0.1, None) for a, b in pairs)


def test_every_public_name_imports():
    for name in planners.__all__:
        assert getattr(planners, name) is not None


# --- single configurations -------------------------------------------------------------------------


def test_clear_configuration_is_free(checker):
    assert checker.in_collision(FREE_Q) == (False, "")


def test_link_inside_obstacle_collides(checker):
    colliding, reason = checker.in_collision(OBSTACLE_Q)
    assert colliding
    assert "'obstacle'" in reason and "'link3'" in reason


def test_link_into_floor_collides(checker):
    colliding, reason = checker.in_collision(FLOOR_Q)
    assert colliding
    assert "'floor'" in reason


def test_non_adjacent_links_folded_onto_each_other_collide(checker):
    colliding, reason = checker.in_collision(FOLDED_Q)
    assert colliding
    assert "body 'link1'" in reason and "body 'link3'" in reason


def test_adjacent_links_touching_at_their_joint_are_not_reported(model, checker):
    data = mujoco.MjData(model)
    data.qpos[:3] = STRAIGHT_Q
    mujoco.mj_kinematics(model, data)
    for a, b in [("link1", "link2"), ("link2", "link3"), ("collar", "link3")]:  # the case is real: they overlap
        assert mujoco.mj_geomDistance(model, data, model.geom(a).id, model.geom(b).id, 0.1, None) < -0.01
    assert checker.in_collision(STRAIGHT_Q) == (False, "")


def test_colliding_pairs_lists_every_pair(model, checker):
    names = {tuple(sorted((model.geom(a).name, model.geom(b).name))) for a, b in checker.colliding_pairs(FOLDED_Q)}
    assert ("link1", "link3") in names
    assert checker.colliding_pairs(FREE_Q) == []


# --- sweeps and paths ------------------------------------------------------------------------------


def test_sweep_through_obstacle_in_the_middle_is_not_free(checker):
    q = np.array([-0.5, 0.0, 0.0])
    delta = 2.0
    end = q.copy()
    end[0] += delta
    assert not checker.in_collision(q)[0] and not checker.in_collision(end)[0]  # endpoints free
    free, reason = checker.sweep_free(q, 0, delta)
    assert not free
    assert "'obstacle'" in reason and "joint 0 at" in reason
    angle = float(reason.split("joint 0 at ")[1].split()[0])
    assert -0.5 < angle < 1.5


def test_sweep_that_stays_clear_is_free(checker):
    assert checker.sweep_free(np.array([-0.5, 0.0, 0.0]), 0, -0.6) == (True, "")


def test_sweep_with_colliding_start_is_not_free(checker):
    free, reason = checker.sweep_free(OBSTACLE_Q, 1, 0.01)
    assert not free and "sample 0/" in reason


def test_path_through_obstacle_is_not_free(checker):
    free, reason = checker.path_free(np.array([-0.5, 0.0, 0.0]), np.array([1.5, 0.0, 0.0]))
    assert not free and "'obstacle'" in reason


def test_path_that_stays_clear_is_free(checker):
    assert checker.path_free(np.array([-0.5, 0.0, 0.0]), np.array([-1.1, -0.2, 0.2])) == (True, "")


def test_path_of_zero_length_checks_its_point(checker):
    assert not checker.path_free(OBSTACLE_Q, OBSTACLE_Q)[0]
    assert checker.path_free(FREE_Q, FREE_Q)[0]


# A 1 m rod turning about z, and a wall 1 cm thick that only the rod's last 10 cm cross, at 47 deg.
WALL_DEG = 47.0
THIN_WALL_XML = f"""
<mujoco>
  <compiler angle="radian"/>
  <worldbody>
    <body name="wall" pos="{0.97 * math.cos(math.radians(WALL_DEG))} {0.97 * math.sin(math.radians(WALL_DEG))} 0.5"
          euler="0 0 {math.radians(WALL_DEG)}">
      <geom name="wall" type="box" size="0.05 0.005 0.05"/>
    </body>
    <body name="rod" pos="0 0 0.5">
      <joint name="yaw" type="hinge" axis="0 0 1"/>
      <geom name="rod" type="capsule" fromto="0 0 0  1 0 0" size="0.005"/>
    </body>
    <body name="carriage" pos="2 0 0.5">
      <joint name="slide" type="slide" axis="0 1 0"/>
      <geom name="carriage" type="box" size="0.02 0.02 0.02"/>
    </body>
    <geom name="stop" type="box" pos="2 0.5 0.5" size="0.05 0.004 0.05"/>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def wall_checker() -> CollisionChecker:
    return CollisionChecker(mujoco.MjModel.from_xml_string(THIN_WALL_XML), [0, 1])


def test_thin_wall_crossed_mid_sweep_is_detected(wall_checker):
    q = np.zeros(2)
    assert not wall_checker.in_collision(q)[0]
    assert not wall_checker.in_collision(np.array([math.pi / 2, 0.0]))[0]
    free, reason = wall_checker.sweep_free(q, 0, math.pi / 2, max_step_m=0.005)
    assert not free and "'wall'" in reason
    angle = float(reason.split("joint 0 at ")[1].split()[0])
    assert abs(math.degrees(angle) - WALL_DEG) < 1.0
    assert not wall_checker.path_free(q, np.array([math.pi / 2, 0.0]), max_step_m=0.005)[0]


def test_coarse_step_misses_the_thin_wall(wall_checker):
    # 10 cm steps put samples 2 deg and 3.6 deg either side of the wall: the fine test is not vacuous.
    assert wall_checker.sweep_free(np.zeros(2), 0, math.pi / 2, max_step_m=0.1) == (True, "")


def test_slide_joint_sweep_hits_a_thin_stop(wall_checker):
    free, reason = wall_checker.sweep_free(np.zeros(2), 1, 1.0)
    assert not free and "'stop'" in reason and " m " in reason
    assert wall_checker.sweep_free(np.zeros(2), 1, 0.4) == (True, "")


# --- agreement with MuJoCo -------------------------------------------------------------------------


def sample_box(model, target: str | None) -> tuple[FloatArray, FloatArray]:
    """Joint box to sample: the whole range, or yaw facing one obstacle with the arm near level."""
    if target is None:
        return np.array([-math.pi, -2.0, -3.1]), np.array([math.pi, 2.0, 3.1])
    x, y, _ = model.geom(target).pos
    yaw = math.pi if target == "backstop" else math.atan2(y, x)
    return np.array([yaw - 0.4, -0.6, -1.2]), np.array([yaw + 0.4, 0.9, 1.2])


@pytest.mark.parametrize("target", [None, "obstacle", "crate", "ball", "disc", "egg", "backstop"], ids=str)
def test_agrees_with_mujoco_on_random_configurations(model, checker, target):
    rng = np.random.default_rng(11)
    data = mujoco.MjData(model)
    compared = colliding = hits = 0
    for q in rng.uniform(*sample_box(model, target), size=(60, 3)):
        expected = mujoco_pairs(model, data, q)  # leaves data at q for the distance query
        if abs(min_distance(model, data, checker.pairs)) < NEAR_CONTACT:
            continue
        compared += 1
        colliding += bool(expected)
        hits += any(target in (model.geom(a).name, model.geom(b).name) for a, b in expected)
        assert checker.in_collision(q)[0] == bool(expected), (q, expected)
        assert set(checker.colliding_pairs(q)) == expected, q
    assert compared >= 45
    assert 5 <= colliding <= compared - 5  # both outcomes are exercised
    assert target is None or hits >= 3  # and the targeted obstacle is hit


def test_checked_pairs_are_exactly_the_unfiltered_ones(model, checker):
    static = {"world", "base"}
    expected = set()
    for g1 in range(model.ngeom):
        for g2 in range(g1 + 1, model.ngeom):
            bodies = (body_name(model, g1), body_name(model, g2))
            if bodies[0] == bodies[1] or set(bodies) <= static:
                continue
            if bodies in FILTERED_BODIES or bodies[::-1] in FILTERED_BODIES:
                continue
            expected.add((g1, g2))
    assert {tuple(map(int, p)) for p in checker.pairs} == expected


# --- filters ---------------------------------------------------------------------------------------


def test_exclude_in_model_drops_the_pair():
    checker = CollisionChecker(arm_model('<contact><exclude body1="link1" body2="link3"/></contact>'), [0, 1, 2])
    assert checker.in_collision(FOLDED_Q) == (False, "")


def test_ignore_pairs_by_body_name():
    checker = CollisionChecker(arm_model(), [0, 1, 2], ignore_pairs=[("link3", "world")])
    assert not checker.in_collision(FLOOR_Q)[0]
    assert checker.in_collision(FOLDED_Q)[0]


def test_contype_conaffinity_bits_are_respected():
    xml = ARM_XML.replace(
        'name="obstacle" type="box"', 'name="obstacle" type="box" contype="2" conaffinity="2"'
    ).replace("CONTACT", "")
    checker = CollisionChecker(mujoco.MjModel.from_xml_string(xml), [0, 1, 2])
    assert checker.in_collision(OBSTACLE_Q) == (False, "")
    data = mujoco.MjData(checker.model)
    assert not mujoco_pairs(checker.model, data, OBSTACLE_Q)  # MuJoCo agrees


def test_explicit_pair_overrides_the_bits():
    xml = ARM_XML.replace(
        'name="obstacle" type="box"', 'name="obstacle" type="box" contype="2" conaffinity="2"'
    ).replace("CONTACT", '<contact><pair geom1="obstacle" geom2="link3"/></contact>')
    checker = CollisionChecker(mujoco.MjModel.from_xml_string(xml), [0, 1, 2])
    assert "'obstacle'" in checker.in_collision(OBSTACLE_Q)[1]


def test_rigid_pairs_touching_at_reference_are_listed(checker):
    assert any("'base'" in text and "'floor'" in text for text in checker.constant_contacts)


def test_unsupported_geom_is_skipped_with_a_warning():
    xml = ARM_XML.replace(
        "<asset>", '<asset><hfield name="terrain" nrow="2" ncol="2" elevation="0 0 0 0" size="1 1 0.1 0.1"/>'
    ).replace("<worldbody>", '<worldbody><geom name="terrain" type="hfield" hfield="terrain" pos="3 3 0"/>')
    with pytest.warns(UserWarning, match="terrain"):
        checker = CollisionChecker(mujoco.MjModel.from_xml_string(xml.replace("CONTACT", "")), [0, 1, 2])
    assert any("terrain" in label for label in checker.skipped_geoms)
    assert checker.in_collision(OBSTACLE_Q)[0]


# --- margin ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "q",
    [np.array([0.0, 0.35, 0.35]), np.array([0.38, 0.0, 0.0])],
    ids=["near-floor", "near-obstacle"],
)
def test_margin_reports_pairs_closer_than_margin(model, checker, q):
    data = mujoco.MjData(model)
    data.qpos[:3] = q
    mujoco.mj_kinematics(model, data)
    gap = min_distance(model, data, checker.pairs)
    assert 0.01 < gap < 0.08  # the case is a near miss
    assert not CollisionChecker(model, [0, 1, 2], margin=gap - 0.005).in_collision(q)[0]
    colliding, reason = CollisionChecker(model, [0, 1, 2], margin=gap + 0.005).in_collision(q)
    assert colliding and "within" in reason


# --- input validation ------------------------------------------------------------------------------


def test_invalid_queries_raise(checker):
    with pytest.raises(InvalidInputError, match=r"shape \(3,\)"):
        checker.in_collision(np.zeros(4))
    with pytest.raises(InvalidInputError, match="finite"):
        checker.in_collision(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(InvalidInputError, match=r"0\.\.2"):
        checker.sweep_free(FREE_Q, 3, 0.1)
    with pytest.raises(InvalidInputError, match=r"0\.\.2"):
        checker.sweep_free(FREE_Q, -1, 0.1)
    with pytest.raises(InvalidInputError, match="delta"):
        checker.sweep_free(FREE_Q, 0, math.inf)
    with pytest.raises(InvalidInputError, match="max_step_m"):
        checker.path_free(FREE_Q, FREE_Q, max_step_m=0.0)
    with pytest.raises(InvalidInputError, match="q_to"):
        checker.path_free(FREE_Q, np.zeros(2))


def test_invalid_construction_raises(model):
    with pytest.raises(InvalidInputError, match="out of range"):
        CollisionChecker(model, [0, 1, 7])
    with pytest.raises(InvalidInputError, match="repeat"):
        CollisionChecker(model, [0, 0])
    with pytest.raises(InvalidInputError, match="unknown body 'nope'"):
        CollisionChecker(model, [0, 1, 2], ignore_pairs=[("link1", "nope")])
    with pytest.raises(InvalidInputError, match="qpos_ref"):
        CollisionChecker(model, [0, 1, 2], qpos_ref=np.zeros(2))
    with pytest.raises(InvalidInputError, match="margin"):
        CollisionChecker(model, [0, 1, 2], margin=-0.1)


def test_free_and_ball_joints_are_not_arm_joints():
    xml = """<mujoco><worldbody>
      <body name="puck"><freejoint/><geom size="0.1"/></body>
      <body name="knob" pos="1 0 0"><joint type="ball"/><geom size="0.1"/></body>
    </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    with pytest.raises(InvalidInputError, match="FREE"):
        CollisionChecker(model, [0])
    with pytest.raises(InvalidInputError, match="BALL"):
        CollisionChecker(model, [1])


# --- sampling bound --------------------------------------------------------------------------------

# A gantry: a cart sliding along x, a hinge about z on it, and a telescoping arm sliding along the
# arm (so a slide joint sits below a hinge in the chain), next to a floor that never moves.
GANTRY_XML = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="2 2 0.1"/>
    <body name="cart" pos="0 0 0.5">
      <joint name="x" type="slide" axis="1 0 0"/>
      <geom name="cart" type="box" size="0.1 0.1 0.05"/>
      <body name="arm" pos="0.05 0 0.1">
        <joint name="yaw" type="hinge" axis="0 0 1"/>
        <geom name="arm" type="capsule" fromto="0 0 0  0.4 0 0" size="0.02"/>
        <body name="ram" pos="0.2 0 0">
          <joint name="extend" type="slide" axis="1 0 0"/>
          <geom name="ram" type="box" pos="0.3 0 0" size="0.3 0.015 0.015"/>
          <geom name="head" type="sphere" pos="0.6 0.05 0" size="0.04"/>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

#: metres: the sampling step used by the bound tests (large, to keep the sample count small).
STEP = 0.02


def max_travel(model, samples, arm_qadr) -> float:
    """Largest travel between consecutive samples of any point of a moving geom's bounding sphere.

    A point c + R u (|u| <= rbound) moves by at most |c2 - c1| + ||R2 - R1|| rbound, and
    ||R2 - R1|| = 2 sin(theta / 2) = sqrt(3 - trace(R1^T R2)). rbound is MuJoCo's geom_rbound, exact
    for primitives; for meshes MuJoCo's is padded (box corners), so we take the farthest vertex.
    """
    data = mujoco.MjData(model)
    solid = [g for g in range(model.ngeom) if model.geom_type[g] != mujoco.mjtGeom.mjGEOM_PLANE]
    poses = []
    for q in samples:
        data.qpos[arm_qadr] = q
        mujoco.mj_kinematics(model, data)
        poses.append((data.geom_xpos[solid].copy(), data.geom_xmat[solid].reshape(-1, 3, 3).copy()))
    rbound = model.geom_rbound[solid].copy()
    for i, g in enumerate(solid):
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            mesh = model.geom_dataid[g]
            verts = model.mesh_vert[model.mesh_vertadr[mesh] : model.mesh_vertadr[mesh] + model.mesh_vertnum[mesh]]
            rbound[i] = np.linalg.norm(verts, axis=1).max()
    travel = 0.0
    for (c1, R1), (c2, R2) in zip(poses, poses[1:], strict=False):
        trace = np.einsum("gij,gij->g", R1, R2)
        chord = np.sqrt(np.clip(3.0 - trace, 0.0, None))
        travel = max(travel, float(np.max(np.linalg.norm(c2 - c1, axis=1) + chord * rbound)))
    return travel


@pytest.mark.parametrize("scene", ["arm", "gantry"])
def test_samples_respect_max_step(scene):
    model = arm_model() if scene == "arm" else mujoco.MjModel.from_xml_string(GANTRY_XML)
    checker = CollisionChecker(model, [0, 1, 2])
    arm_qadr = model.jnt_qposadr[:3]
    rng = np.random.default_rng(3)
    span = np.array([math.pi, 1.5, 1.5]) if scene == "arm" else np.array([0.5, math.pi, 0.3])
    for _ in range(10):
        q = rng.uniform(-span, span)
        for joint in range(3):
            samples = checker.sweep_samples(q, joint, rng.uniform(-2.0, 2.0), max_step_m=STEP)
            travel, n_steps = max_travel(model, samples, arm_qadr), len(samples) - 1
            assert travel <= STEP + 1e-9, (scene, joint, travel)
            # The sweep rule uses the exact reach about the axis: one step fewer would break it.
            assert n_steps == 1 or travel * n_steps / (n_steps - 1) > 0.98 * STEP, (scene, joint, travel)
        samples = checker.path_samples(q, rng.uniform(-span, span), max_step_m=STEP)
        assert max_travel(model, samples, arm_qadr) <= STEP + 1e-9
        assert np.allclose(samples[0], q) and len(samples) >= 2
