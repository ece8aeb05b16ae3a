"""Procedural arms (arc_env.robots): MuJoCo loads both formats, and its kinematics match an independent FK."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from solver.errors import InvalidInputError
from tests.support.arms import ArmSpec, arm_mjcf, arm_urdf, forward_axes, random_arm

FORMATS = {"mjcf": arm_mjcf, "urdf": arm_urdf}
#: Both sides compose the same few rotations in float64: agreement is ~1e-16, so 1e-9 only allows
#: for the decimal round trip of the written XML, and any real modelling error (>= 1e-6 m) fails it.
KINEMATICS_TOL = 1e-9
SEEDS = range(20)


def load(fmt: str, spec: ArmSpec, name: str = "arm") -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(FORMATS[fmt](spec, name))


def joint_ids(model: mujoco.MjModel, n: int, name: str = "arm") -> list[int]:
    return [model.joint(f"{name}_joint{i + 1}").id for i in range(n)]


def set_q(model: mujoco.MjModel, data: mujoco.MjData, ids: list[int], q: np.ndarray) -> None:
    data.qpos[model.jnt_qposadr[ids]] = q


def axes_in_base(model: mujoco.MjModel, data: mujoco.MjData, ids: list[int], name: str = "arm"):
    """MuJoCo's joint axes and anchors, (N, 3) each, in the base body's frame."""
    base = model.body(f"{name}_base").id
    R_world_base = data.xmat[base].reshape(3, 3)
    p_world_base = data.xpos[base]
    return data.xaxis[ids] @ R_world_base, (data.xanchor[ids] - p_world_base) @ R_world_base


def random_qs(spec: ArmSpec, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(spec.joint_limits[:, 0], spec.joint_limits[:, 1], size=(count, spec.n_joints))


def non_adjacent_contacts(model: mujoco.MjModel, data: mujoco.MjData) -> list[tuple[str, str]]:
    mujoco.mj_forward(model, data)
    pairs = []
    for c in data.contact[: data.ncon]:
        b1, b2 = model.geom_bodyid[c.geom1], model.geom_bodyid[c.geom2]
        if model.body_parentid[b1] != b2 and model.body_parentid[b2] != b1:
            pairs.append((model.body(b1).name, model.body(b2).name))
    return pairs


def folded_arm() -> ArmSpec:
    """Link 3 comes straight back down beside link 1, 6 cm away: shafts of radius 4 cm overlap."""
    offsets = np.array([[0.0, 0.0, 0.4], [0.06, 0.0, 0.0], [0.0, 0.0, -0.35]])
    return ArmSpec(
        n_joints=3,
        link_lengths=np.linalg.norm(offsets, axis=1),
        joint_axes=np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
        link_offsets=offsets,
        joint_limits=np.array([[-2.0, 2.0]] * 3),
        link_radius=np.full(3, 0.04),
        base_height=0.15,
    )


@pytest.fixture(scope="module")
def arms() -> dict[int, ArmSpec]:
    return {seed: random_arm(seed) for seed in SEEDS}


# ----------------------------------------------------------------------------- the generator


@pytest.mark.parametrize("n_joints", [2, 3, 6, 7, 8])
def test_random_arm_ranges(n_joints):
    for seed in range(10):
        spec = random_arm(seed, n_joints)
        assert spec.n_joints == n_joints
        assert np.all((spec.link_lengths >= 0.1 - 1e-12) & (spec.link_lengths <= 0.35 + 1e-12))
        reach = spec.link_lengths.sum()
        assert min(0.8, 0.35 * n_joints) - 1e-6 <= reach <= 1.2 + 1e-6
        np.testing.assert_allclose(np.linalg.norm(spec.joint_axes, axis=1), 1.0, atol=1e-12)
        cos = np.abs(np.sum(spec.joint_axes[1:] * spec.joint_axes[:-1], axis=1))
        assert np.all(cos <= np.cos(np.deg2rad(30.0)) + 1e-12), "consecutive axes nearly parallel"
        lo, hi = spec.joint_limits.T
        np.testing.assert_array_equal(lo, -hi)
        assert np.all((hi >= 1.5) & (hi <= 2.8))


def test_same_seed_same_arm_and_strings():
    a, b = random_arm(7), random_arm(7)
    for field in ("link_lengths", "joint_axes", "link_offsets", "joint_limits", "link_radius"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.base_height == b.base_height
    assert arm_mjcf(a) == arm_mjcf(b)
    assert arm_urdf(a) == arm_urdf(b)


def test_different_seeds_different_arms(arms):
    mjcf = {arm_mjcf(spec) for spec in arms.values()}
    urdf = {arm_urdf(spec) for spec in arms.values()}
    assert len(mjcf) == len(urdf) == len(arms)
    offsets = np.array([spec.link_offsets for spec in arms.values()])
    assert np.min([np.abs(offsets[i] - offsets[j]).max() for i in range(len(arms)) for j in range(i)]) > 1e-3


def test_spec_arrays_are_read_only():
    spec = random_arm(0)
    with pytest.raises(ValueError):
        spec.joint_axes[0, 0] = 1.0


# ----------------------------------------------------------------------------- loading


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("n_joints", [3, 6, 7])
def test_loads_with_hinges_and_limits(fmt, n_joints):
    spec = random_arm(3, n_joints)
    model = load(fmt, spec)
    assert model.njnt == model.nq == n_joints
    ids = joint_ids(model, n_joints)
    assert np.all(model.jnt_type[ids] == mujoco.mjtJoint.mjJNT_HINGE)
    assert np.all(model.jnt_limited[ids])
    np.testing.assert_allclose(model.jnt_range[ids], spec.joint_limits, rtol=0, atol=1e-12)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("name", ["arm", "ur_like-2"])
def test_named_bodies_exist(fmt, name):
    spec = random_arm(1)
    model = load(fmt, spec, name)
    expected = [f"{name}_base", *(f"{name}_link{i + 1}" for i in range(spec.n_joints)), f"{name}_ee"]
    assert [model.body(b).name for b in range(1, model.nbody)] == expected
    base = model.body(f"{name}_base")
    assert base.parentid[0] == 0 and model.body_dofnum[base.id] == 0, "the base must be fixed to the world"
    assert np.all(model.body_mass[1:] > 0)


@pytest.mark.parametrize("fmt", FORMATS)
def test_collision_and_visual_geoms_for_every_link(fmt):
    spec = random_arm(2)
    model = load(fmt, spec)
    collides = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
    # MJCF puts visual geoms in group 2 and collision geoms in 3; MuJoCo's URDF import uses 1 and 0.
    visual_group, collision_group = (2, 3) if fmt == "mjcf" else (1, 0)
    for b in range(1, model.nbody):
        geoms = np.flatnonzero(model.geom_bodyid == b)
        name = model.body(b).name
        assert np.any(collides[geoms]), f"{name} has no collision geom"
        assert np.any(~collides[geoms]), f"{name} has no visual geom"
        assert np.all(model.geom_group[geoms[collides[geoms]]] == collision_group)
        assert np.all(model.geom_group[geoms[~collides[geoms]]] == visual_group)


@pytest.mark.parametrize("fmt", FORMATS)
def test_link_colours_distinct(fmt):
    spec = random_arm(4, 8)
    model = load(fmt, spec)
    colours = []
    for i in range(spec.n_joints):
        body = model.body(f"arm_link{i + 1}").id
        visual = [g for g in np.flatnonzero(model.geom_bodyid == body) if model.geom_contype[g] == 0]
        colours.append({tuple(np.round(model.geom_rgba[g], 3).tolist()) for g in visual})
    housing = set.intersection(*colours)  # the joint housings share one colour
    own = [c - housing for c in colours]
    assert all(len(c) == 1 for c in own), own
    assert len(set.union(*own)) == spec.n_joints


@pytest.mark.parametrize("seed", [0, 6])
def test_urdf_shafts_and_housings_match_mjcf(seed, arms):
    """URDF cylinders sit where the MJCF capsules and housings do, along the same axes (rpy is right)."""
    spec = arms[seed]
    mjcf, urdf = load("mjcf", spec), load("urdf", spec)
    for i in range(spec.n_joints):
        r = spec.link_radius[i]
        body = urdf.body(f"arm_link{i + 1}").id
        cylinders = {round(float(urdf.geom_size[g, 0]), 9): g for g in np.flatnonzero(urdf.geom_bodyid == body)
                     if urdf.geom_contype[g]}
        for part, radius in (("", r), ("_housing", 1.2 * r)):
            g_mjcf = mjcf.geom(f"arm_link{i + 1}{part}_collision").id
            g_urdf = cylinders[round(radius, 9)]
            np.testing.assert_allclose(urdf.geom_pos[g_urdf], mjcf.geom_pos[g_mjcf], atol=1e-12)
            z_mjcf, z_urdf = (np.zeros(3) for _ in range(2))
            mujoco.mju_rotVecQuat(z_mjcf, np.array([0.0, 0.0, 1.0]), mjcf.geom_quat[g_mjcf])
            mujoco.mju_rotVecQuat(z_urdf, np.array([0.0, 0.0, 1.0]), urdf.geom_quat[g_urdf])
            assert abs(z_mjcf @ z_urdf) > 1 - 1e-12


# ----------------------------------------------------------------------------- kinematics


def test_forward_axes_by_hand():
    """Two joints: z then x, at q = (pi/2, pi/2): hand-computed axes and anchors."""
    spec = ArmSpec(
        n_joints=2,
        link_lengths=np.array([0.3, 0.2]),
        joint_axes=np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
        link_offsets=np.array([[0.3, 0.0, 0.0], [0.0, 0.2, 0.0]]),
        joint_limits=np.array([[-2.0, 2.0], [-2.0, 2.0]]),
        link_radius=np.array([0.04, 0.03]),
        base_height=0.1,
    )
    axes, anchors = forward_axes(spec, np.array([np.pi / 2, np.pi / 2]))
    # Joint 1 at (0, 0, 0.1) about z; after +90 deg, link 1's x axis points along base y,
    # so joint 2 sits at (0, 0.3, 0.1) and its axis (link x) is base y.
    np.testing.assert_allclose(axes, [[0, 0, 1], [0, 1, 0]], atol=1e-15)
    np.testing.assert_allclose(anchors, [[0, 0, 0.1], [0, 0.3, 0.1]], atol=1e-15)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("seed", [0, 5, 11, 19])
def test_mujoco_kinematics_match_forward_axes(fmt, seed, arms):
    spec = arms[seed]
    model = load(fmt, spec)
    data = mujoco.MjData(model)
    ids = joint_ids(model, spec.n_joints)
    for q in random_qs(spec, 20, seed):
        set_q(model, data, ids, q)
        mujoco.mj_kinematics(model, data)
        axes_mj, anchors_mj = axes_in_base(model, data, ids)
        axes, anchors = forward_axes(spec, q)
        np.testing.assert_allclose(axes_mj, axes, rtol=0, atol=KINEMATICS_TOL)
        np.testing.assert_allclose(anchors_mj, anchors, rtol=0, atol=KINEMATICS_TOL)


@pytest.mark.parametrize("n_joints", [3, 7])
def test_kinematics_with_base_placed_elsewhere(n_joints):
    """Axes are compared in the base frame: move and turn the base in the world, they must not change."""
    spec = random_arm(9, n_joints)
    placed = '<body name="arm_base" pos="0.4 -0.2 0.7" euler="0.3 -0.5 1.1"'
    xml = arm_mjcf(spec).replace('<body name="arm_base"', placed)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    ids = joint_ids(model, n_joints)
    q = random_qs(spec, 1, 0)[0]
    set_q(model, data, ids, q)
    mujoco.mj_kinematics(model, data)
    assert np.linalg.norm(data.xpos[model.body("arm_base").id]) > 0.5
    axes_mj, anchors_mj = axes_in_base(model, data, ids)
    axes, anchors = forward_axes(spec, q)
    np.testing.assert_allclose(axes_mj, axes, rtol=0, atol=KINEMATICS_TOL)
    np.testing.assert_allclose(anchors_mj, anchors, rtol=0, atol=KINEMATICS_TOL)


@pytest.mark.parametrize("seed", [2, 13])
def test_mjcf_and_urdf_agree(seed, arms):
    """Every body's pose, base frame, from the two files (no forward_axes involved)."""
    spec = arms[seed]
    models = {fmt: load(fmt, spec) for fmt in FORMATS}
    datas = {fmt: mujoco.MjData(m) for fmt, m in models.items()}
    for q in random_qs(spec, 20, seed + 100):
        poses = {}
        for fmt, model in models.items():
            data = datas[fmt]
            set_q(model, data, joint_ids(model, spec.n_joints), q)
            mujoco.mj_kinematics(model, data)
            poses[fmt] = (data.xpos[1:].copy(), data.xmat[1:].copy())
        np.testing.assert_allclose(poses["mjcf"][0], poses["urdf"][0], rtol=0, atol=KINEMATICS_TOL)
        np.testing.assert_allclose(poses["mjcf"][1], poses["urdf"][1], rtol=0, atol=KINEMATICS_TOL)


def test_kinematics_check_can_fail():
    """A spec that differs from the one written by 1 mm in one offset is caught."""
    spec = random_arm(0)
    offsets = spec.link_offsets.copy()
    offsets[2, 0] += 1e-3
    wrong = ArmSpec(spec.n_joints, np.linalg.norm(offsets, axis=1), spec.joint_axes, offsets,
                    spec.joint_limits, spec.link_radius, spec.base_height)
    model = load("urdf", spec)
    data = mujoco.MjData(model)
    ids = joint_ids(model, spec.n_joints)
    mujoco.mj_kinematics(model, data)
    _, anchors_mj = axes_in_base(model, data, ids)
    assert np.abs(anchors_mj - forward_axes(wrong, np.zeros(spec.n_joints))[1]).max() > 1e3 * KINEMATICS_TOL


# ----------------------------------------------------------------------------- self-collision


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("seed", SEEDS)
def test_no_self_collision_at_zero(fmt, seed, arms):
    model = load(fmt, arms[seed])
    assert non_adjacent_contacts(model, mujoco.MjData(model)) == []


@pytest.mark.parametrize("fmt", FORMATS)
def test_self_collision_check_can_fail(fmt):
    model = load(fmt, folded_arm())
    pairs = non_adjacent_contacts(model, mujoco.MjData(model))
    assert ("arm_link1", "arm_link3") in pairs or ("arm_link3", "arm_link1") in pairs


# ----------------------------------------------------------------------------- errors


def test_spec_validation():
    good = folded_arm()
    fields = dict(vars(good))
    with pytest.raises(InvalidInputError, match="joint_axes must have shape"):
        ArmSpec(**{**fields, "joint_axes": good.joint_axes[:2]})
    with pytest.raises(InvalidInputError, match="unit vectors"):
        ArmSpec(**{**fields, "joint_axes": 2 * good.joint_axes})
    with pytest.raises(InvalidInputError, match="norms of link_offsets"):
        ArmSpec(**{**fields, "link_lengths": good.link_lengths + 0.01})
    with pytest.raises(InvalidInputError, match="lower < upper"):
        ArmSpec(**{**fields, "joint_limits": good.joint_limits[:, ::-1]})
    with pytest.raises(InvalidInputError, match="NaN"):
        ArmSpec(**{**fields, "link_radius": np.array([0.04, np.nan, 0.04])})
    with pytest.raises(InvalidInputError, match="base_height"):
        ArmSpec(**{**fields, "base_height": 0.0})


def test_argument_errors():
    spec = random_arm(0)
    with pytest.raises(InvalidInputError, match=r"q must have shape \(6,\)"):
        forward_axes(spec, np.zeros(5))
    with pytest.raises(InvalidInputError, match="n_joints must be an integer in 2..8"):
        random_arm(0, 1)
    with pytest.raises(InvalidInputError, match="seed"):
        random_arm(-1)
    with pytest.raises(InvalidInputError, match="name"):
        arm_mjcf(spec, "my arm")
