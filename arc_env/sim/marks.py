"""What real arms carry, for the ``realistic`` appearance: seams and screw heads, labels and cables.

``plan_marks`` decides, from a seeded generator and the robot's drawn geometry at its home
configuration, which links carry what; ``add_marks`` adds the labels and cables to the scene's spec
and the seam and screw materials the geoms will wear; ``dress`` puts those materials on once the spec
is compiled again. Every mark is the simulator's secret: nothing downstream is told where a mark is or
that it exists.

* Seams and screws (per drawn geom, a third each, a third plain): a cube texture of panel lines
  (``mark="edge"``) or sparse dark specks, mapped from the geom's local coordinates, multiplied by the
  geom's own colour (its ``rgba``, or its material's when the geom keeps MuJoCo's default ``rgba``),
  so that a black link stays black and a white one white. A geom whose own material has a texture keeps
  it.
* Labels (each link with probability ``LABEL_PROBABILITY``): a printed rectangle of
  ``LABEL_WIDTH_M`` wide, a light ground (white, silver or warning yellow) with dark lines of
  "words", often a logo and a frame; a thin box fixed to the link, its face on the link's surface.
  The surface point and normal come from ``mujoco.mj_ray`` cast from outside toward the link at the
  home configuration; a place is kept only where the surface under the label's corners, edges and
  centre stays within ``LABEL_GAP_M`` of its face (nearly flat, not hidden by another link).
* Cables (each link with probability ``CABLE_PROBABILITY`` and at least ``CABLE_MIN_LENGTH_M`` long
  along its principal axis): a dark cable of ``CABLE_RADIUS_M`` radius (5-10 mm thick) along the
  link, a chain of capsules resting on the link's surface: rays cast every ``CABLE_STEP_M`` along the
  axis from one side give the surface's profile; the cable follows its upper envelope (a running
  maximum over neighbouring samples) in as few straight segments as keep its underside between the
  envelope and ``CABLE_SLACK_M`` above it (so it never dips into the surface at a sample).

Labels and cables are geoms of their link's body, after its own geoms: visual only (``contype =
conaffinity = 0``), massless (density 0: the body's mass, centre of mass and inertia are unchanged) and
in geom group ``MARK_GROUP``. The scene draws that group, while ``RobotModel`` counts only groups 0-2
as the robot's drawn geometry, so the marks never enter the collision checker, the oracle's surface
points or the overlay's projected model; they do enter ``Scene.robot_mask`` (they are part of the
robot's image). Body ids are those of the unmarked model; geom ids of later bodies move up by the
marks added before them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from arc_env.robot.model import RobotModel, geom_vertices
from arc_env.sim.marker_board import BOARD_BODY
from solver.arrays import FloatArray, ImageArray

#: Geom group of the labels and cables: drawn by the scene, outside the robot's drawn groups 0-2.
MARK_GROUP = 5
#: Names of the seam and screw cube textures (and of their materials for geoms coloured by ``rgba``).
SEAMS = "arc_seams"
SCREWS = "arc_screws"

#: Chance that a link carries a label.
LABEL_PROBABILITY = 0.4
#: Label width range, m (a rating plate or warning label: a few cm); its height is width / aspect.
LABEL_WIDTH_M = (0.03, 0.06)
LABEL_ASPECT = (1.4, 2.4)
#: How far the surface under a label may fall below (or rise to) its printed face, m.
LABEL_GAP_M = 0.003
#: The printed face stands this far above the surface point, m; the box reaches this deep below it.
LABEL_LIFT_M = 0.0008
LABEL_DEPTH_M = 0.0035
#: Ray casts tried per label before the link goes without one.
LABEL_TRIES = 40
#: Label texture size, texels (width, height).
LABEL_TEXELS = (160, 80)

#: Chance that a link carries a cable, and the shortest link (along its principal axis) that does, m.
CABLE_PROBABILITY = 0.6
CABLE_MIN_LENGTH_M = 0.08
#: Cable radius range, m (5-10 mm thick), and sampling step along the link, m.
CABLE_RADIUS_M = (0.0025, 0.005)
CABLE_STEP_M = 0.005
#: The cable's centre line runs this far above the envelope plus its radius, m; a straight segment may cut
#: as far below that, so its underside never goes below the envelope at a sample.
CABLE_CLEARANCE_M = 0.001
#: Largest height of a cable's underside above the envelope it spans before a segment is split, m.
CABLE_SLACK_M = 0.004
#: Sides of the link tried per cable.
CABLE_TRIES = 8

_DRAWN_GROUPS = np.array([1, 1, 1, 0, 0, 0], np.uint8)
_FAR_M = 0.3  # rays start this far outside the surface
_SEEN_FROM_M = 0.05  # a label's face must be visible from this far along its normal above the floor
_DEFAULT_RGBA = np.array([0.5, 0.5, 0.5, 1.0], np.float32)  # MuJoCo's default geom rgba


@dataclass(frozen=True)
class Label:
    """A printed label fixed to a link.

    Attributes:
        body: the link's body id.
        pos: (3,) m, the label box's centre in the link body's frame.
        quat: (4,) w, x, y, z: the box's orientation in the link body's frame (its z is the surface normal).
        half_size: (3,) m, the box's half extents (face half-width, half-height, half-thickness).
        design: (H, W, 3) uint8 RGB, the printed image (rows top-down).
    """

    body: int
    pos: FloatArray
    quat: FloatArray
    half_size: FloatArray
    design: ImageArray = field(repr=False)


@dataclass(frozen=True)
class Cable:
    """A cable fixed to a link: capsules between consecutive points.

    Attributes:
        body: the link's body id.
        points: (K, 3) m, the cable's centre line in the link body's frame, K >= 2.
        radius: m.
        rgba: (4,) its colour.
    """

    body: int
    points: FloatArray
    radius: float
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class Marks:
    """What the realistic appearance adds to one robot.

    Attributes:
        patterns: drawn geom id (in the unmarked model) -> ``SEAMS`` or ``SCREWS`` (geoms not listed stay plain).
        labels: the labels.
        cables: the cables.
        materials: drawn geom id (in the unmarked model) -> name of the material it wears (filled by
            ``add_marks``).
    """

    patterns: dict[int, str]
    labels: tuple[Label, ...]
    cables: tuple[Cable, ...]
    materials: dict[int, str] = field(default_factory=dict)


def plan_marks(robot: RobotModel, seed: int) -> Marks:
    """Choose and place the marks of ``robot`` (posed at its home configuration here), seeded by ``seed``.

    The seams/screws choice is the generator's first draw (one integer per drawn geom), so it does not
    depend on the labels and cables that follow. A marker board (``arc_env.sim.marker_board``) gets no
    label or cable (and the scene gives it its own material back).
    """
    rng = np.random.default_rng(seed)
    geoms = robot.rendered_geoms()
    choice = rng.integers(0, 3, len(geoms))
    patterns = {g: (SEAMS if c == 1 else SCREWS) for g, c in zip(geoms, choice, strict=True) if c}
    robot.set_q(robot.home)
    m, d = robot.model, robot.data
    board = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, BOARD_BODY)
    links = sorted({int(m.geom_bodyid[g]) for g in geoms} - {board})
    labels, cables = [], []
    for body in links:
        wants_label, wants_cable = rng.random(2) < (LABEL_PROBABILITY, CABLE_PROBABILITY)
        link_geoms = [g for g in geoms if m.geom_bodyid[g] == body]
        points = np.concatenate([_geom_points(m, d, g) for g in link_geoms])
        if not m.body(body).name or len(points) < 4:
            continue
        centre = points.mean(axis=0)
        axes = np.linalg.svd(points - centre, full_matrices=False)[2]  # rows: principal directions
        if wants_label:
            label = _place_label(m, d, body, link_geoms, axes[0], rng)
            if label is not None:
                labels.append(label)
        if wants_cable:
            cable = _place_cable(m, d, body, points, centre, axes, rng)
            if cable is not None:
                cables.append(cable)
    return Marks(patterns, tuple(labels), tuple(cables))


def add_marks(spec: mujoco.MjSpec, model: mujoco.MjModel, marks: Marks) -> None:
    """Add ``marks``' labels, cables and seam/screw materials to ``spec``, the spec ``model`` was compiled from.

    Fills ``marks.materials``; ``dress`` puts them on once the spec is compiled again.
    """
    for g, pattern in sorted(marks.patterns.items()):
        name = _pattern_material(spec, model, g, pattern)
        if name is not None:
            marks.materials[g] = name

    # from the spec's root default, not the link's class (which may colour or weigh its geoms), and
    # everything that matters set here
    visual = {"default": spec.default, "contype": 0, "conaffinity": 0, "mass": 0.0, "density": 0.0,
              "group": MARK_GROUP}
    for k, label in enumerate(marks.labels):
        name = f"arc_label_{k}"
        h, w = label.design.shape[:2]
        texture = spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, width=w, height=h, nchannel=3)
        texture.data = np.ascontiguousarray(np.flipud(label.design)).tobytes()  # MuJoCo rows run bottom-up
        material = spec.add_material(name=name)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name
        material.specular, material.shininess = 0.3, 0.4
        link = spec.body(model.body(label.body).name)
        link.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, pos=label.pos, quat=label.quat, size=label.half_size,
                      material=name, rgba=[1.0, 1.0, 1.0, 1.0], **visual)
    for k, cable in enumerate(marks.cables):
        material = spec.add_material(name=f"arc_cable_{k}", rgba=list(cable.rgba))
        material.specular, material.shininess = 0.4, 0.5
        link = spec.body(model.body(cable.body).name)
        for i, (a, b) in enumerate(zip(cable.points[:-1], cable.points[1:], strict=True)):
            link.add_geom(name=f"arc_cable_{k}_{i}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=np.concatenate([a, b]),
                          size=[cable.radius, 0, 0], material=f"arc_cable_{k}", rgba=list(cable.rgba), **visual)


def dress(marked: mujoco.MjModel, unmarked: mujoco.MjModel, marks: Marks) -> None:
    """Give the geoms of ``marked`` (the spec compiled with the marks) their seam or screw materials.

    ``marks.materials`` names geoms by their ids in ``unmarked``; a body's own geoms keep their order and
    come before its marks, so a geom's id moves by as much as its body's first geom id.
    """
    for g, name in marks.materials.items():
        body = unmarked.geom_bodyid[g]
        moved = int(marked.body_geomadr[body] - unmarked.body_geomadr[body])
        marked.geom_matid[g + moved] = mujoco.mj_name2id(marked, mujoco.mjtObj.mjOBJ_MATERIAL, name)


def _pattern_material(spec: mujoco.MjSpec, model: mujoco.MjModel, geom: int, pattern: str) -> str | None:
    """The material geom ``geom`` wears with seams or screws: its own colour times the pattern (None: keep its own).

    MuJoCo draws a geom in its ``rgba`` unless that is the default and the geom has a material, whose
    ``rgba`` it then takes; the pattern texture multiplies that colour.
    """
    own = int(model.geom_matid[geom])
    coloured = not np.array_equal(model.geom_rgba[geom], _DEFAULT_RGBA)
    if own < 0 and coloured:
        return pattern  # coloured by its rgba alone: the shared material (rgba 1) keeps that colour
    if own >= 0 and np.any(model.mat_texid[own] >= 0):
        return None  # a textured material of its own: keep it
    name = f"{pattern}_{geom}"
    rgba = model.mat_rgba[own] if own >= 0 else _DEFAULT_RGBA
    material = spec.add_material(name=name, rgba=[float(c) for c in rgba])
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = pattern
    if own < 0:
        material.specular, material.shininess = 0.3, 0.3  # as the shared pattern materials
    else:
        material.specular, material.shininess = float(model.mat_specular[own]), float(model.mat_shininess[own])
        material.reflectance = float(model.mat_reflectance[own])
    return name


def _geom_points(m: mujoco.MjModel, d: mujoco.MjData, geom: int) -> FloatArray:
    """A drawn geom's vertices (mesh) or surface samples (primitive) in the world frame, (P, 3) m."""
    local = geom_vertices(m, geom)
    if local is None:
        return np.zeros((0, 3))
    return local @ d.geom_xmat[geom].reshape(3, 3).T + d.geom_xpos[geom]


def _ray(m: mujoco.MjModel, d: mujoco.MjData, origin: FloatArray, direction: FloatArray
         ) -> tuple[float, int, FloatArray]:
    """Distance (m, -1: nothing), body hit and the surface normal (facing the ray) along a unit ray."""
    geom = np.full(1, -1, np.int32)
    normal = np.zeros(3)
    dist = mujoco.mj_ray(m, d, origin, direction, _DRAWN_GROUPS, 1, -1, geom, normal)
    if dist < 0 or geom[0] < 0:
        return -1.0, -1, normal
    if normal @ direction > 0:
        normal = -normal
    return float(dist), int(m.geom_bodyid[geom[0]]), normal


def _body_frame(d: mujoco.MjData, body: int) -> tuple[FloatArray, FloatArray]:
    return d.xmat[body].reshape(3, 3).copy(), d.xpos[body].copy()


def _place_label(m: mujoco.MjModel, d: mujoco.MjData, body: int, geoms: list[int], axis: FloatArray,
                 rng: np.random.Generator) -> Label | None:
    """A label on the link's surface, found by rays from random outside directions; None when none fits."""
    width = rng.uniform(*LABEL_WIDTH_M)
    height = width / rng.uniform(*LABEL_ASPECT)
    design = label_design(rng)
    for _ in range(LABEL_TRIES):
        g = geoms[rng.integers(len(geoms))]
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        reach = float(m.geom_rbound[g]) + _FAR_M
        dist, hit_body, normal = _ray(m, d, d.geom_xpos[g] + reach * u, -u)
        if hit_body != body:
            continue
        point = d.geom_xpos[g] + (reach - dist) * u
        if (point + _SEEN_FROM_M * normal)[2] < 0.0:
            continue  # faces the floor (the world's z = 0) from just above it: no camera would see it
        along = axis - (axis @ normal) * normal
        if np.linalg.norm(along) < 1e-6:
            continue
        along /= np.linalg.norm(along)
        if rng.random() < 0.5:  # labels run along the link or across it
            along = np.cross(normal, along)
        across = np.cross(normal, along)
        if not _flat_under(m, d, body, point, normal, along * width / 2, across * height / 2):
            continue
        R_world_label = np.column_stack([along, across, normal])
        depth = LABEL_DEPTH_M
        centre = point + normal * (LABEL_LIFT_M - depth) / 2
        R_world_body, p_world_body = _body_frame(d, body)
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, (R_world_body.T @ R_world_label).ravel())
        return Label(body, R_world_body.T @ (centre - p_world_body), quat,
                     np.array([width / 2, height / 2, (LABEL_LIFT_M + depth) / 2]), design)
    return None


def _flat_under(m: mujoco.MjModel, d: mujoco.MjData, body: int, point: FloatArray, normal: FloatArray,
                half_along: FloatArray, half_across: FloatArray) -> bool:
    """Whether the link's surface under a label's 3 x 3 grid of face points lies within ``LABEL_GAP_M`` of it."""
    for i in (-1.0, 0.0, 1.0):
        for j in (-1.0, 0.0, 1.0):
            face = point + i * half_along + j * half_across
            dist, hit_body, _ = _ray(m, d, face + _FAR_M * normal, -normal)
            if hit_body != body:
                return False
            rise = _FAR_M - dist  # surface height above the tangent plane at the label's centre
            if not -LABEL_GAP_M <= rise <= LABEL_LIFT_M / 2:
                return False
    return True


def _place_cable(m: mujoco.MjModel, d: mujoco.MjData, body: int, points: FloatArray, centre: FloatArray,
                 axes: FloatArray, rng: np.random.Generator) -> Cable | None:
    """A cable along the link's principal axis on one side, resting on the surface; None when it does not fit."""
    axis = axes[0]
    t = (points - centre) @ axis
    length = float(np.ptp(t))
    radius = rng.uniform(*CABLE_RADIUS_M)
    grey = rng.uniform(0.04, 0.12)
    rgba = (grey, grey, grey * 1.05, 1.0)
    if length < CABLE_MIN_LENGTH_M:
        return None
    span = np.arange(t.min() + 0.1 * length, t.max() - 0.1 * length, CABLE_STEP_M)
    radial = points - centre - np.outer(t, axis)
    reach = float(np.max(np.linalg.norm(radial, axis=1))) + _FAR_M
    for _ in range(CABLE_TRIES):
        phi = rng.uniform(0, 2 * np.pi)
        side = np.cos(phi) * axes[1] + np.sin(phi) * axes[2]
        heights = np.full(len(span), np.nan)
        for k, s in enumerate(span):
            dist, hit_body, _ = _ray(m, d, centre + s * axis + reach * side, -side)
            if hit_body == body:
                heights[k] = reach - dist
        run = _longest_run(np.isfinite(heights))
        if (run.stop - run.start) * CABLE_STEP_M < 0.75 * CABLE_MIN_LENGTH_M:
            continue
        s, h = span[run], heights[run]
        # upper envelope: each sample at least as high as its neighbours, so no segment dips into the surface
        envelope = np.maximum(h, np.maximum(np.r_[h[0], h[:-1]], np.r_[h[1:], h[-1]]))
        keep = _simplify_above(s, envelope, CABLE_SLACK_M, CABLE_CLEARANCE_M)
        lift = envelope[keep] + radius + CABLE_CLEARANCE_M
        world = centre + np.outer(s[keep], axis) + np.outer(lift, side)
        R_world_body, p_world_body = _body_frame(d, body)
        return Cable(body, (world - p_world_body) @ R_world_body, float(radius), rgba)
    return None


def _longest_run(ok: np.ndarray) -> slice:
    """The longest run of True in a boolean vector, as a slice (empty when there is none)."""
    best, start = slice(0, 0), None
    for k, value in enumerate([*ok, False]):
        if value and start is None:
            start = k
        elif not value and start is not None:
            if k - start > best.stop - best.start:
                best = slice(start, k)
            start = None
    return best


def _simplify_above(s: FloatArray, h: FloatArray, slack: float, sink: float) -> list[int]:
    """Indices of a polyline through (s, h) samples whose straight segments stay within [h - sink, h + slack]."""
    keep = [0]
    i = 0
    while i < len(s) - 1:
        j = i + 1
        while j + 1 < len(s):
            line = np.interp(s[i:j + 2], [s[i], s[j + 1]], [h[i], h[j + 1]])
            if np.any(line < h[i:j + 2] - sink) or np.any(line > h[i:j + 2] + slack):
                break
            j += 1
        keep.append(j)
        i = j
    return keep


def label_design(rng: np.random.Generator) -> ImageArray:
    """A label's printed image, (H, W, 3) uint8 RGB (``LABEL_TEXELS``): a light ground, dark "text", a logo."""
    w, h = LABEL_TEXELS
    grounds = ((238, 238, 232), (200, 203, 208), (236, 196, 44))
    ground = np.array(grounds[rng.integers(len(grounds))], np.uint8)
    ink = np.array([25, 25, 28], np.uint8)
    image = np.empty((h, w, 3), np.uint8)
    image[:] = ground
    margin = 8
    if rng.random() < 0.5:  # a printed frame
        image[3:5, 3:w - 3] = ink
        image[h - 5:h - 3, 3:w - 3] = ink
        image[3:h - 3, 3:5] = ink
        image[3:h - 3, w - 5:w - 3] = ink
        margin = 10
    left = margin
    if rng.random() < 0.6:  # a logo: a disc, a square or a triangle
        size = int(rng.integers(h // 3, h // 2 + 1))
        y0 = (h - size) // 2
        yy, xx = np.mgrid[0:size, 0:size]
        kind = rng.integers(3)
        if kind == 0:
            shape = (yy - size / 2 + 0.5) ** 2 + (xx - size / 2 + 0.5) ** 2 <= (size / 2) ** 2
        elif kind == 1:
            shape = np.ones((size, size), bool)
        else:
            shape = np.abs(xx - size / 2 + 0.5) <= yy / 2
        image[y0:y0 + size, left:left + size][shape] = ink
        left += size + 6
    lines = int(rng.integers(2, 5))
    pitch = (h - 2 * margin) // lines
    for k in range(lines):
        y = margin + k * pitch + (pitch - 6) // 2
        thick = int(rng.integers(4, 7)) if k == 0 else int(rng.integers(3, 5))  # a heading, then small print
        x = left
        while True:
            word = int(rng.integers(5, 22))
            if x + word > w - margin:
                break
            image[y:y + thick, x:x + word] = ink
            x += word + int(rng.integers(3, 6))
    return image


__all__ = ["MARK_GROUP", "Cable", "Label", "Marks", "add_marks", "dress", "label_design", "plan_marks"]
