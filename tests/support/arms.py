"""Procedurally generated serial arms, written as MJCF and as URDF, to test robots other than the Panda.

An arm is a chain ``base -> link1 -> ... -> linkN -> ee``. Every body frame has the same orientation
as its parent's at q = 0 (no fixed rotations), so at q = 0 all frames are parallel to the base frame:

* link 1's origin is ``(0, 0, base_height)`` in the base frame; link i+1's origin (or the
  end-effector's, for the last link) is ``link_offsets[i]`` in link i's frame;
* joint i turns link i about ``joint_axes[i]`` (a unit vector, the same in link i's frame and its
  parent's, since the rotation leaves it fixed) through link i's origin.

Geometry derived from the spec (the same in MJCF and URDF):

* each link has a shaft from its origin to its child's origin, radius ``link_radius[i]`` (capsule in
  MJCF, cylinder in URDF, which has no capsule), and a joint housing: a cylinder centred on the
  joint, along the joint axis, radius ``HOUSING_RADIUS_SCALE * r``, half-length ``HOUSING_HALF_LENGTH_SCALE * r``;
* the base is a pedestal cylinder from z = 0 to ``base_height``, radius ``BASE_RADIUS_SCALE * r_1``;
* the end-effector body carries a sphere of radius ``EE_RADIUS_SCALE * r_N``.

``random_arm`` redraws links until, at q = 0, no two non-adjacent bodies' collision geoms come within
``CLEARANCE`` of each other and every moving geom is ``FLOOR_CLEARANCE`` above the plane z = 0 (where
a scene puts its floor). The check bounds every geom by a capsule, so it holds for both formats.
Joint names are 1-based (``{name}_joint1``); array rows are 0-based (row 0 is joint 1).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np

from solver.arrays import FloatArray
from solver.errors import ArcCalibError, InvalidInputError

#: Joint housing radius and half-length, as multiples of the link radius.
HOUSING_RADIUS_SCALE = 1.2
HOUSING_HALF_LENGTH_SCALE = 1.0
#: Base pedestal radius as a multiple of the first link's radius.
BASE_RADIUS_SCALE = 1.6
#: End-effector sphere radius as a multiple of the last link's radius.
EE_RADIUS_SCALE = 0.8
#: Density of every link, kg/m^3 (a hollow aluminium arm averages about this).
DENSITY = 1000.0
#: End-effector mass, kg.
EE_MASS = 0.05
#: Smallest gap, m, between collision geoms of non-adjacent bodies at q = 0 in ``random_arm``.
CLEARANCE = 0.01
#: Smallest height, m, of every moving collision geom above z = 0 at q = 0 in ``random_arm``.
FLOOR_CLEARANCE = 0.005

_LINK_LENGTH_RANGE = (0.1, 0.35)  # m
_REACH_RANGE = (0.8, 1.2)  # m, sum of link lengths
_LIMIT_RANGE = (1.5, 2.8)  # rad, symmetric limits +-U(...)
_MIN_AXIS_ANGLE = np.deg2rad(30.0)  # between consecutive joint axes
_FIRST_RADIUS_RANGE = (0.04, 0.055)  # m
_LAST_RADIUS_RANGE = (0.025, 0.035)  # m
_BASE_HEIGHT_RANGE = (0.13, 0.18)  # m
_MAX_ATTEMPTS = 100  # whole-arm draws
_TRIES_PER_LINK = 100  # draws of one link's axis and direction
_UNIT_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class ArmSpec:
    """A serial arm of N revolute joints (see the module docstring for the frame conventions).

    Arrays are converted to read-only float64. Equality is identity; compare fields with numpy.

    Attributes:
        n_joints: N >= 1.
        link_lengths: (N,) float64, m: length of each link, the norm of ``link_offsets[i]``.
        joint_axes: (N, 3) float64: unit axis of joint i in its parent link's frame (equal to link
            i's own frame, since every frame is parallel to its parent at q = 0).
        link_offsets: (N, 3) float64, m: origin of link i's child (link i+1, or the end-effector
            body for the last link) in link i's frame.
        joint_limits: (N, 2) float64, rad: (lower, upper) of each joint, lower < upper.
        link_radius: (N,) float64, m: radius of each link's shaft.
        base_height: m: height of joint 1 (link 1's origin) above the base frame's origin.
    """

    n_joints: int
    link_lengths: FloatArray
    joint_axes: FloatArray
    link_offsets: FloatArray
    joint_limits: FloatArray
    link_radius: FloatArray
    base_height: float

    def __post_init__(self) -> None:
        if isinstance(self.n_joints, bool) or not isinstance(self.n_joints, int | np.integer) or self.n_joints < 1:
            raise InvalidInputError(f"n_joints must be a positive integer, got {self.n_joints!r}")
        n = int(self.n_joints)
        object.__setattr__(self, "n_joints", n)
        shapes = {
            "link_lengths": (n,),
            "joint_axes": (n, 3),
            "link_offsets": (n, 3),
            "joint_limits": (n, 2),
            "link_radius": (n,),
        }
        for field, shape in shapes.items():
            value = np.array(getattr(self, field), dtype=np.float64)
            if value.shape != shape:
                raise InvalidInputError(f"{field} must have shape {shape}, got {value.shape}")
            if not np.all(np.isfinite(value)):
                raise InvalidInputError(f"{field} contains NaN or infinite values")
            value.setflags(write=False)
            object.__setattr__(self, field, value)
        base_height = float(self.base_height)
        if not np.isfinite(base_height) or base_height <= 0:
            raise InvalidInputError(f"base_height must be a positive number of metres, got {self.base_height!r}")
        object.__setattr__(self, "base_height", base_height)
        if np.any(self.link_lengths <= 0) or np.any(self.link_radius <= 0):
            raise InvalidInputError("link_lengths and link_radius must be positive")
        if not np.allclose(np.linalg.norm(self.joint_axes, axis=1), 1.0, rtol=0, atol=_UNIT_TOL):
            raise InvalidInputError("joint_axes must be unit vectors")
        if not np.allclose(np.linalg.norm(self.link_offsets, axis=1), self.link_lengths, rtol=0, atol=_UNIT_TOL):
            raise InvalidInputError("link_lengths must equal the norms of link_offsets")
        if np.any(self.joint_limits[:, 0] >= self.joint_limits[:, 1]):
            raise InvalidInputError("every joint needs joint_limits lower < upper")

    def joint_origins(self) -> FloatArray:
        """Each body's origin in its parent's frame: (N + 1, 3) float64, m; links 1..N, then the end-effector."""
        return np.vstack([[0.0, 0.0, self.base_height], self.link_offsets])


def _rotation(axis: FloatArray, angle: float) -> FloatArray:
    """Rodrigues: rotation by angle (rad) about a unit axis (3,) -> (3, 3)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def forward_axes(spec: ArmSpec, q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Joint axes and anchors in the base frame at configuration q (pure numpy, no MuJoCo).

    Args:
        spec: the arm.
        q: (N,) float64, rad: joint angles (not checked against the limits).

    Returns:
        axes: (N, 3) float64: unit axis of each joint in the base frame.
        anchors: (N, 3) float64, m: each joint's anchor (its link's origin) in the base frame.

    Raises:
        InvalidInputError: q has the wrong shape or non-finite values.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (spec.n_joints,):
        raise InvalidInputError(f"q must have shape ({spec.n_joints},), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise InvalidInputError("q contains NaN or infinite values")
    origins = spec.joint_origins()
    axes = np.empty((spec.n_joints, 3))
    anchors = np.empty((spec.n_joints, 3))
    R_base_link = np.eye(3)  # the parent of joint i, in the base frame
    p_base = np.zeros(3)
    for i in range(spec.n_joints):
        p_base = p_base + R_base_link @ origins[i]
        axes[i] = R_base_link @ spec.joint_axes[i]
        anchors[i] = p_base
        R_base_link = R_base_link @ _rotation(spec.joint_axes[i], q[i])
    return axes, anchors


# ---------------------------------------------------------------------------------------------
# Random generation


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v)


def _link_lengths(rng: np.random.Generator, n: int) -> FloatArray:
    """N lengths in _LINK_LENGTH_RANGE whose sum is close to a target drawn from _REACH_RANGE."""
    lo, hi = _LINK_LENGTH_RANGE
    target = float(np.clip(rng.uniform(*_REACH_RANGE), n * lo, n * hi))
    lengths = rng.uniform(lo, hi, size=n)
    for _ in range(50):  # alternate projections onto {sum = target} and the box [lo, hi]^N
        lengths = np.clip(lengths * target / lengths.sum(), lo, hi)
    return lengths


def _random_axis(rng: np.random.Generator, previous: FloatArray | None) -> FloatArray:
    """A random unit axis at least _MIN_AXIS_ANGLE from ``previous`` (either sign), if given."""
    while True:
        a = _unit(rng.normal(size=3))
        if previous is None or abs(a @ previous) <= np.cos(_MIN_AXIS_ANGLE):
            return a


def _random_direction(rng: np.random.Generator, previous: FloatArray | None) -> FloatArray:
    """A link direction: a step of a random walk on the sphere that starts roughly upward."""
    if previous is None:
        return _unit(np.array([0.0, 0.0, 1.0]) + 0.4 * rng.normal(size=3))
    return _unit(previous + 0.8 * rng.normal(size=3))


def _segment_distance(p0: FloatArray, p1: FloatArray, q0: FloatArray, q1: FloatArray) -> float:
    """Distance, m, between segments p0-p1 and q0-q1 (Ericson, Real-Time Collision Detection, 5.1.9)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    eps = 1e-15
    if a <= eps and e <= eps:
        return float(np.linalg.norm(r))
    if a <= eps:
        s, t = 0.0, float(np.clip(f / e, 0.0, 1.0))
    else:
        c = d1 @ r
        if e <= eps:
            s, t = float(np.clip(-c / a, 0.0, 1.0)), 0.0
        else:
            b = d1 @ d2
            denom = a * e - b * b
            s = float(np.clip((b * f - c * e) / denom, 0.0, 1.0)) if denom > eps else 0.0
            t = (b * s + f) / e
            if t < 0.0:
                s, t = float(np.clip(-c / a, 0.0, 1.0)), 0.0
            elif t > 1.0:
                s, t = float(np.clip((b - c) / a, 0.0, 1.0)), 1.0
    return float(np.linalg.norm(p0 + s * d1 - (q0 + t * d2)))


Capsule = tuple[FloatArray, FloatArray, float]  # (end (3,) m, end (3,) m, radius m)


def _base_capsules(base_height: float, first_radius: float) -> list[Capsule]:
    return [(np.zeros(3), np.array([0.0, 0.0, base_height]), BASE_RADIUS_SCALE * first_radius)]


def _link_capsules(origin: FloatArray, axis: FloatArray, offset: FloatArray, radius: float) -> list[Capsule]:
    """Shaft and housing of a link whose origin is at ``origin`` (3,) m, at q = 0 (frames parallel)."""
    h = HOUSING_HALF_LENGTH_SCALE * radius * axis
    return [(origin, origin + offset, radius), (origin - h, origin + h, HOUSING_RADIUS_SCALE * radius)]


def _ee_capsules(origin: FloatArray, last_radius: float) -> list[Capsule]:
    return [(origin, origin, EE_RADIUS_SCALE * last_radius)]


def _above_floor(body: list[Capsule]) -> bool:
    return all(min(p[2], q[2]) - r >= FLOOR_CLEARANCE for p, q, r in body)


def _apart(a: list[Capsule], b: list[Capsule]) -> bool:
    """Whether every capsule of a is at least CLEARANCE from every capsule of b."""
    return all(
        _segment_distance(p0, p1, q0, q1) >= ri + rj + CLEARANCE for p0, p1, ri in a for q0, q1, rj in b
    )


def _fits(body: list[Capsule], chain: list[list[Capsule]]) -> bool:
    """Whether a body appended to ``chain`` (its parent last) is above the floor and clear of non-parents."""
    return _above_floor(body) and all(_apart(body, other) for other in chain[:-1])


def _bounding_capsules(spec: ArmSpec) -> list[list[Capsule]]:
    """Per body (base, links 1..N, ee), capsules bounding its collision geoms at q = 0, base frame."""
    origins = np.cumsum(spec.joint_origins(), axis=0)  # (N + 1, 3) body origins in the base frame
    bodies = [_base_capsules(spec.base_height, spec.link_radius[0])]
    for i in range(spec.n_joints):
        bodies.append(_link_capsules(origins[i], spec.joint_axes[i], spec.link_offsets[i], spec.link_radius[i]))
    bodies.append(_ee_capsules(origins[-1], spec.link_radius[-1]))
    return bodies


def _is_clear(spec: ArmSpec) -> bool:
    """No non-adjacent bodies within CLEARANCE at q = 0, every moving geom FLOOR_CLEARANCE above z = 0."""
    bodies = _bounding_capsules(spec)
    return all(_fits(bodies[k], bodies[:k]) for k in range(1, len(bodies)))


def _grow_chain(
    rng: np.random.Generator, lengths: FloatArray, radii: FloatArray, base_height: float
) -> tuple[FloatArray, FloatArray] | None:
    """Joint axes (N, 3) and link offsets (N, 3) of a clear chain, one link at a time; None if stuck."""
    n = lengths.shape[0]
    axes, offsets = np.empty((n, 3)), np.empty((n, 3))
    chain = [_base_capsules(base_height, radii[0])]
    origin = np.array([0.0, 0.0, base_height])
    for i in range(n):
        for _ in range(_TRIES_PER_LINK):
            axis = _random_axis(rng, axes[i - 1] if i else None)
            offset = lengths[i] * _random_direction(rng, offsets[i - 1] / lengths[i - 1] if i else None)
            body = _link_capsules(origin, axis, offset, radii[i])
            if not _fits(body, chain):
                continue
            if i == n - 1 and not _fits(_ee_capsules(origin + offset, radii[i]), [*chain, body]):
                continue
            break
        else:
            return None
        axes[i], offsets[i] = axis, offset
        chain.append(body)
        origin = origin + offset
    return axes, offsets


def random_arm(seed: int, n_joints: int = 6) -> ArmSpec:
    """A random serial arm, the same for the same seed, free of self-collision at q = 0.

    Link lengths are 0.1-0.35 m with a total reach of about 0.8-1.2 m (clipped into what N links
    can reach); joint axes are random unit vectors, consecutive ones at least 30 degrees apart;
    link directions at q = 0 follow a random walk that starts upward; limits are symmetric,
    +-1.5 to +-2.8 rad; the link radius tapers from 4-5.5 cm to 2.5-3.5 cm. The chain is grown one
    link at a time, each link redrawn until it is clear of the links before it (see the module
    docstring), and the finished arm is checked again as a whole.

    Args:
        seed: non-negative integer seed of ``numpy.random.default_rng``.
        n_joints: N, 2..8 (beyond 8 links, short links with their joint housings rarely fit).

    Returns:
        The arm.

    Raises:
        InvalidInputError: seed negative or n_joints out of range.
        ArcCalibError: no clear arm found in ``_MAX_ATTEMPTS`` draws (not seen in practice).
    """
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r}")
    if isinstance(n_joints, bool) or not isinstance(n_joints, int | np.integer) or not 2 <= n_joints <= 8:
        raise InvalidInputError(f"n_joints must be an integer in 2..8, got {n_joints!r}")
    n = int(n_joints)
    rng = np.random.default_rng(seed)
    for _ in range(_MAX_ATTEMPTS):
        lengths = _link_lengths(rng, n)
        radii = np.linspace(rng.uniform(*_FIRST_RADIUS_RANGE), rng.uniform(*_LAST_RADIUS_RANGE), n)
        base_height = rng.uniform(*_BASE_HEIGHT_RANGE)
        limits = rng.uniform(*_LIMIT_RANGE, size=n)
        grown = _grow_chain(rng, lengths, radii, base_height)
        if grown is None:
            continue
        axes, offsets = grown
        spec = ArmSpec(
            n_joints=n,
            link_lengths=np.linalg.norm(offsets, axis=1),  # equal to lengths up to rounding
            joint_axes=axes,
            link_offsets=offsets,
            joint_limits=np.column_stack([-limits, limits]),
            link_radius=radii,
            base_height=base_height,
        )
        if _is_clear(spec):
            return spec
    raise ArcCalibError(f"no self-collision-free arm with {n} joints found in {_MAX_ATTEMPTS} draws (seed {seed})")


# ---------------------------------------------------------------------------------------------
# Shared geometry and inertia


def _fmt(values: FloatArray | float) -> str:
    """Space-separated shortest round-trip decimal form of each value."""
    return " ".join(repr(float(v)) for v in np.atleast_1d(np.asarray(values, dtype=np.float64)))


def _link_colors(n: int) -> list[tuple[float, float, float]]:
    """N clearly distinct RGB colours (evenly spaced hues)."""
    return [colorsys.hsv_to_rgb(k / n, 0.65, 0.9) for k in range(n)]


_HOUSING_RGB = (0.25, 0.25, 0.28)
_BASE_RGB = (0.15, 0.15, 0.17)
_EE_RGB = (0.85, 0.85, 0.85)


def _cylinder_inertia(mass: float, radius: float, length: float, axis: FloatArray) -> FloatArray:
    """Inertia (3, 3), kg m^2, of a solid cylinder about its centre; axis (3,) unit."""
    along = 0.5 * mass * radius**2
    across = mass * (3.0 * radius**2 + length**2) / 12.0
    P = np.outer(axis, axis)
    return across * (np.eye(3) - P) + along * P


def _link_inertial(spec: ArmSpec, i: int) -> tuple[float, FloatArray, FloatArray]:
    """Mass (kg), centre of mass (3,) m and inertia (3, 3) kg m^2 about it, in link i's frame."""
    r, length = spec.link_radius[i], spec.link_lengths[i]
    R, half = HOUSING_RADIUS_SCALE * r, HOUSING_HALF_LENGTH_SCALE * r
    parts = [  # (mass, centre, axis, radius, length) of the shaft and the housing, both solid cylinders
        (DENSITY * np.pi * r**2 * length, 0.5 * spec.link_offsets[i], spec.link_offsets[i] / length, r, length),
        (DENSITY * np.pi * R**2 * 2 * half, np.zeros(3), spec.joint_axes[i], R, 2 * half),
    ]
    mass = sum(p[0] for p in parts)
    com = sum(p[0] * p[1] for p in parts) / mass
    inertia = np.zeros((3, 3))
    for m, c, axis, radius, cyl_length in parts:
        d = c - com
        inertia += _cylinder_inertia(m, radius, cyl_length, axis) + m * ((d @ d) * np.eye(3) - np.outer(d, d))
    return float(mass), com, inertia


def _base_inertial(spec: ArmSpec) -> tuple[float, FloatArray, FloatArray]:
    r = BASE_RADIUS_SCALE * spec.link_radius[0]
    mass = DENSITY * np.pi * r**2 * spec.base_height
    inertia = _cylinder_inertia(mass, r, spec.base_height, np.array([0.0, 0.0, 1.0]))
    return float(mass), np.array([0.0, 0.0, 0.5 * spec.base_height]), inertia


def _ee_inertial(spec: ArmSpec) -> tuple[float, FloatArray, FloatArray]:
    r = EE_RADIUS_SCALE * spec.link_radius[-1]
    return EE_MASS, np.zeros(3), 0.4 * EE_MASS * r**2 * np.eye(3)


# ---------------------------------------------------------------------------------------------
# MJCF


def _mjcf_inertial(mass: float, com: FloatArray, inertia: FloatArray) -> str:
    full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    return f'<inertial pos="{_fmt(com)}" mass="{_fmt(mass)}" fullinertia="{_fmt(np.array(full))}"/>'


def arm_mjcf(spec: ArmSpec, name: str = "arm") -> str:
    """The arm as a complete, standalone MJCF model (no floor, lights or cameras).

    Bodies ``{name}_base`` (fixed, child of the world body), ``{name}_link1`` .. ``{name}_linkN``
    (hinge joints ``{name}_joint1`` .. ``{name}_jointN`` with the spec's limits) and ``{name}_ee``.
    Every body has an explicit inertial (solid cylinders of density ``DENSITY``). Visual geoms are in
    class ``{name}_visual`` (group 2, contype = conaffinity = 0), collision geoms in class
    ``{name}_collision`` (group 3, contype = conaffinity = 1); each link has a capsule shaft and a
    cylinder joint housing of both kinds, and each link's shaft has its own colour. The compiler is
    set to radians. Names are prefixed with ``name`` so that several arms can share a scene.

    Args:
        spec: the arm.
        name: prefix of every name in the model, and the model's name.

    Returns:
        The MJCF XML document.
    """
    _check_name(name)
    vis, col = f"{name}_visual", f"{name}_collision"
    colors = _link_colors(spec.n_joints)
    lines = [
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" autolimits="true"/>',
        "  <default>",
        f'    <default class="{name}">',
        '      <joint type="hinge" limited="true" damping="1" armature="0.01"/>',
        f'      <default class="{vis}"><geom group="2" contype="0" conaffinity="0" density="0"/></default>',
        f'      <default class="{col}"><geom group="3" contype="1" conaffinity="1" density="0"'
        ' rgba="0.5 0.5 0.5 0.3"/></default>',
        "    </default>",
        "  </default>",
        "  <worldbody>",
    ]
    r0 = BASE_RADIUS_SCALE * spec.link_radius[0]
    base_fromto = _fmt(np.array([0.0, 0.0, 0.0, 0.0, 0.0, spec.base_height]))
    lines += [
        f'    <body name="{name}_base" childclass="{name}">',
        "      " + _mjcf_inertial(*_base_inertial(spec)),
        f'      <geom name="{name}_base_visual" class="{vis}" type="cylinder" fromto="{base_fromto}"'
        f' size="{_fmt(r0)}" rgba="{_fmt(np.array(_BASE_RGB))} 1"/>',
        f'      <geom name="{name}_base_collision" class="{col}" type="cylinder" fromto="{base_fromto}"'
        f' size="{_fmt(r0)}"/>',
    ]
    origins = spec.joint_origins()
    indent = "      "
    for i in range(spec.n_joints):
        link = f"{name}_link{i + 1}"
        r = spec.link_radius[i]
        h = HOUSING_HALF_LENGTH_SCALE * r * spec.joint_axes[i]
        shaft = _fmt(np.concatenate([np.zeros(3), spec.link_offsets[i]]))
        housing = _fmt(np.concatenate([-h, h]))
        lo, hi = spec.joint_limits[i]
        lines += [
            f'{indent}<body name="{link}" pos="{_fmt(origins[i])}">',
            f'{indent}  <joint name="{name}_joint{i + 1}" axis="{_fmt(spec.joint_axes[i])}"'
            f' range="{_fmt(np.array([lo, hi]))}"/>',
            f"{indent}  " + _mjcf_inertial(*_link_inertial(spec, i)),
            f'{indent}  <geom name="{link}_visual" class="{vis}" type="capsule" fromto="{shaft}" size="{_fmt(r)}"'
            f' rgba="{_fmt(np.array(colors[i]))} 1"/>',
            f'{indent}  <geom name="{link}_housing_visual" class="{vis}" type="cylinder" fromto="{housing}"'
            f' size="{_fmt(HOUSING_RADIUS_SCALE * r)}" rgba="{_fmt(np.array(_HOUSING_RGB))} 1"/>',
            f'{indent}  <geom name="{link}_collision" class="{col}" type="capsule" fromto="{shaft}"'
            f' size="{_fmt(r)}"/>',
            f'{indent}  <geom name="{link}_housing_collision" class="{col}" type="cylinder" fromto="{housing}"'
            f' size="{_fmt(HOUSING_RADIUS_SCALE * r)}"/>',
        ]
        indent += "  "
    r_ee = _fmt(EE_RADIUS_SCALE * spec.link_radius[-1])
    lines += [
        f'{indent}<body name="{name}_ee" pos="{_fmt(spec.link_offsets[-1])}">',
        f"{indent}  " + _mjcf_inertial(*_ee_inertial(spec)),
        f'{indent}  <geom name="{name}_ee_visual" class="{vis}" type="sphere" size="{r_ee}"'
        f' rgba="{_fmt(np.array(_EE_RGB))} 1"/>',
        f'{indent}  <geom name="{name}_ee_collision" class="{col}" type="sphere" size="{r_ee}"/>',
        f"{indent}</body>",
    ]
    for _ in range(spec.n_joints):
        indent = indent[:-2]
        lines.append(f"{indent}</body>")
    lines += ["    </body>", "  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)


def _check_name(name: str) -> None:
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "_-" for c in name):
        raise InvalidInputError(f"name must be a non-empty string of letters, digits, '_' or '-', got {name!r}")


# ---------------------------------------------------------------------------------------------
# URDF


def _rpy_z_to(direction: FloatArray) -> FloatArray:
    """URDF roll-pitch-yaw (rad) of a frame whose z axis points along the unit direction (3,)."""
    x, y, z = direction
    # R = Rz(yaw) Ry(pitch) with roll 0 maps z to (cos yaw sin pitch, sin yaw sin pitch, cos pitch).
    pitch = np.arccos(np.clip(z, -1.0, 1.0))
    yaw = np.arctan2(y, x) if np.hypot(x, y) > 1e-12 else 0.0
    return np.array([0.0, pitch, yaw])


def _urdf_inertial(mass: float, com: FloatArray, inertia: FloatArray) -> str:
    I = inertia  # noqa: E741
    return (
        f'<inertial><origin xyz="{_fmt(com)}" rpy="0 0 0"/><mass value="{_fmt(mass)}"/>'
        f'<inertia ixx="{_fmt(I[0, 0])}" ixy="{_fmt(I[0, 1])}" ixz="{_fmt(I[0, 2])}"'
        f' iyy="{_fmt(I[1, 1])}" iyz="{_fmt(I[1, 2])}" izz="{_fmt(I[2, 2])}"/></inertial>'
    )


def _urdf_shape(kind: str, xyz: FloatArray, rpy: FloatArray, geometry: str, material: str | None = None) -> str:
    mat = f'<material name="{material}"/>' if material else ""
    return f'<{kind}><origin xyz="{_fmt(xyz)}" rpy="{_fmt(rpy)}"/><geometry>{geometry}</geometry>{mat}</{kind}>'


def arm_urdf(spec: ArmSpec, name: str = "arm") -> str:
    """The same arm as URDF, with primitives only (cylinders and a sphere; URDF has no capsule).

    Links ``{name}_base``, ``{name}_link1`` .. ``{name}_linkN``, ``{name}_ee``; revolute joints
    ``{name}_joint1`` .. ``{name}_jointN`` (origin xyz = the link offset, rpy = 0, axis, limits) and a
    fixed joint ``{name}_ee_joint``. Each link has a cylinder shaft and a cylinder joint housing,
    each as <visual> (coloured) and <collision>.

    MuJoCo's URDF importer needs two settings, given in a ``<mujoco><compiler .../></mujoco>``
    element inside <robot> (other URDF tools ignore unknown elements):

    * ``fusestatic="false"``: by default MuJoCo fuses bodies without joints into their parents,
      which would merge ``{name}_base`` into the world body and ``{name}_ee`` into the last link,
      losing both names.
    * ``discardvisual="false"``: by default MuJoCo drops <visual> elements. Kept, they become
      geoms with contype = conaffinity = 0 in group 1, while <collision> geoms get
      contype = conaffinity = 1 in group 0 (URDF cannot set groups; the MJCF uses 2 and 3).

    Args:
        spec: the arm.
        name: prefix of every link, joint and material name, and the robot's name.

    Returns:
        The URDF XML document.
    """
    _check_name(name)
    colors = _link_colors(spec.n_joints)
    lines = [
        '<?xml version="1.0"?>',
        f'<robot name="{name}">',
        "  <mujoco>",
        '    <compiler fusestatic="false" discardvisual="false"/>',
        "  </mujoco>",
        f'  <material name="{name}_base_color"><color rgba="{_fmt(np.array(_BASE_RGB))} 1"/></material>',
        f'  <material name="{name}_housing_color"><color rgba="{_fmt(np.array(_HOUSING_RGB))} 1"/></material>',
        f'  <material name="{name}_ee_color"><color rgba="{_fmt(np.array(_EE_RGB))} 1"/></material>',
    ]
    lines += [
        f'  <material name="{name}_link{i + 1}_color"><color rgba="{_fmt(np.array(c))} 1"/></material>'
        for i, c in enumerate(colors)
    ]
    zero = np.zeros(3)
    base_radius = BASE_RADIUS_SCALE * spec.link_radius[0]
    base_geom = f'<cylinder radius="{_fmt(base_radius)}" length="{_fmt(spec.base_height)}"/>'
    base_xyz = np.array([0.0, 0.0, 0.5 * spec.base_height])
    lines += [
        f'  <link name="{name}_base">',
        "    " + _urdf_inertial(*_base_inertial(spec)),
        "    " + _urdf_shape("visual", base_xyz, zero, base_geom, f"{name}_base_color"),
        "    " + _urdf_shape("collision", base_xyz, zero, base_geom),
        "  </link>",
    ]
    origins = spec.joint_origins()
    parent = f"{name}_base"
    for i in range(spec.n_joints):
        link = f"{name}_link{i + 1}"
        r = spec.link_radius[i]
        shaft = f'<cylinder radius="{_fmt(r)}" length="{_fmt(spec.link_lengths[i])}"/>'
        shaft_xyz = 0.5 * spec.link_offsets[i]
        shaft_rpy = _rpy_z_to(spec.link_offsets[i] / spec.link_lengths[i])
        housing = (
            f'<cylinder radius="{_fmt(HOUSING_RADIUS_SCALE * r)}" length="{_fmt(2 * HOUSING_HALF_LENGTH_SCALE * r)}"/>'
        )
        housing_rpy = _rpy_z_to(spec.joint_axes[i])
        lo, hi = spec.joint_limits[i]
        lines += [
            f'  <link name="{link}">',
            "    " + _urdf_inertial(*_link_inertial(spec, i)),
            "    " + _urdf_shape("visual", shaft_xyz, shaft_rpy, shaft, f"{link}_color"),
            "    " + _urdf_shape("visual", zero, housing_rpy, housing, f"{name}_housing_color"),
            "    " + _urdf_shape("collision", shaft_xyz, shaft_rpy, shaft),
            "    " + _urdf_shape("collision", zero, housing_rpy, housing),
            "  </link>",
            f'  <joint name="{name}_joint{i + 1}" type="revolute">',
            f'    <parent link="{parent}"/><child link="{link}"/>',
            f'    <origin xyz="{_fmt(origins[i])}" rpy="0 0 0"/>',
            f'    <axis xyz="{_fmt(spec.joint_axes[i])}"/>',
            f'    <limit lower="{_fmt(lo)}" upper="{_fmt(hi)}" effort="50" velocity="2"/>',
            '    <dynamics damping="1"/>',
            "  </joint>",
        ]
        parent = link
    ee_geom = f'<sphere radius="{_fmt(EE_RADIUS_SCALE * spec.link_radius[-1])}"/>'
    lines += [
        f'  <link name="{name}_ee">',
        "    " + _urdf_inertial(*_ee_inertial(spec)),
        "    " + _urdf_shape("visual", zero, zero, ee_geom, f"{name}_ee_color"),
        "    " + _urdf_shape("collision", zero, zero, ee_geom),
        "  </link>",
        f'  <joint name="{name}_ee_joint" type="fixed">',
        f'    <parent link="{parent}"/><child link="{name}_ee"/>',
        f'    <origin xyz="{_fmt(spec.link_offsets[-1])}" rpy="0 0 0"/>',
        "  </joint>",
        "</robot>",
        "",
    ]
    return "\n".join(lines)
