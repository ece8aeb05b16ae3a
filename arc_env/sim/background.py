"""What stands behind a robot in a lab, for ``SceneConfig.background = "lab"``: cabinets, shelves, posters, boxes.

The default background (``"floor"``) is a dim checkered floor: behind the robot's outline the image is nearly
flat, which flatters anything that reads the robot's outline against its background (``solver.outlines``). A real
lab has cabinets, shelving, posters and boxes there, with edges as strong as the robot's own.

``plan_clutter`` draws, from a seeded generator, ``CLUTTER_ITEMS`` boxes of furniture sizes, each with a pattern of
its own (blocks of colour and dark lines: the fronts of shelves, posters, labelled boxes) and a place given
relative to the camera: an azimuth about the robot's base within ``BEHIND_DEG`` of the direction pointing away from
the camera, and a distance from the base in ``DISTANCE_M``, beyond the arm's reach and never between the camera and
the robot. ``add_clutter`` adds them to the scene's spec (a body each, visual only: ``contype = conaffinity = 0``,
so the planners' collision checker never sees them; drawn in geom group 0); ``place_clutter`` moves them behind
the robot whenever the camera moves (``Scene.set_camera``). The clutter is static during a sweep, as a lab is.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError

#: ``SceneConfig.background`` values: today's floor alone, or a lab behind the robot.
BACKGROUNDS = ("floor", "lab")
#: Items of clutter in the lab.
CLUTTER_ITEMS = 9
#: Their azimuths about the base: within this many degrees of the direction pointing away from the camera.
BEHIND_DEG = 80.0
#: Their distances from the base, m (a Panda reaches 0.86 m; the benchmark cameras stand 1.5-2.5 m away).
DISTANCE_M = (1.3, 3.2)
#: Half extents (x, y, z) ranges, m: from a box on the floor to a tall cabinet.
HALF_SIZE_M = ((0.15, 0.6), (0.15, 0.35), (0.15, 1.0))
#: Side of each item's pattern texture, texels.
PATTERN_TEXELS = 128
#: Name prefix of the clutter's bodies, geoms, textures and materials.
PREFIX = "arc_clutter_"


@dataclass(frozen=True)
class ClutterItem:
    """One item of the lab's clutter.

    Attributes:
        half_size: (3,) m, its box's half extents.
        azimuth: rad, its place about the base, relative to the direction pointing away from the camera.
        distance: m, from the base, on the floor plane.
        yaw: rad, its turn about the vertical.
        pattern: (PATTERN_TEXELS, PATTERN_TEXELS, 3) uint8, its surface.
    """

    half_size: tuple[float, float, float]
    azimuth: float
    distance: float
    yaw: float
    pattern: ImageArray


def plan_clutter(seed: int, n: int = CLUTTER_ITEMS) -> tuple[ClutterItem, ...]:
    """``n`` items of clutter drawn from ``seed`` (the same seed, the same lab)."""
    if n < 0:
        raise InvalidInputError(f"need n >= 0 clutter items, got {n}")
    rng = np.random.default_rng(seed)
    return tuple(ClutterItem(half_size=tuple(float(rng.uniform(*r)) for r in HALF_SIZE_M),
                             azimuth=float(np.radians(rng.uniform(-BEHIND_DEG, BEHIND_DEG))),
                             distance=float(rng.uniform(*DISTANCE_M)), yaw=float(rng.uniform(0.0, np.pi)),
                             pattern=_pattern(rng)) for _ in range(n))


def _pattern(rng: np.random.Generator) -> ImageArray:
    """A surface with edges: a ground colour, blocks of other colours, dark lines (shelf edges, print, tape)."""
    s = PATTERN_TEXELS
    image = np.empty((s, s, 3), np.uint8)
    image[:] = rng.integers(40, 230, 3)
    for _ in range(int(rng.integers(2, 7))):
        x0, y0 = rng.integers(0, s - 8, 2)
        w, h = rng.integers(8, s // 2, 2)
        image[y0:y0 + h, x0:x0 + w] = rng.integers(0, 256, 3)
    for _ in range(int(rng.integers(1, 5))):
        y = int(rng.integers(0, s - 2))
        image[y:y + int(rng.integers(1, 4))] = rng.integers(0, 60, 3)
    return image


def add_clutter(spec: mujoco.MjSpec, items: tuple[ClutterItem, ...]) -> None:
    """Add ``items`` to the scene's spec: a body each (placed by ``place_clutter``), visual only, drawn."""
    for k, item in enumerate(items):
        name = f"{PREFIX}{k}"
        texture = spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, width=PATTERN_TEXELS,
                                   height=PATTERN_TEXELS, nchannel=3)
        texture.data = np.ascontiguousarray(item.pattern).tobytes()
        material = spec.add_material(name=name)
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name
        material.specular, material.shininess = 0.1, 0.1
        body = spec.worldbody.add_body(name=name)
        body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=list(item.half_size), material=name,
                      rgba=[1.0, 1.0, 1.0, 1.0], contype=0, conaffinity=0, group=0)


def clutter_bodies(model: mujoco.MjModel, n: int) -> list[int]:
    """The ids of the ``n`` clutter bodies ``add_clutter`` added to ``model``."""
    return [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"{PREFIX}{k}") for k in range(n)]


def place_clutter(model: mujoco.MjModel, bodies: list[int], items: tuple[ClutterItem, ...], base_xy: FloatArray,
                  camera_xy: FloatArray) -> None:
    """Stand each item on the floor behind the robot as the camera at ``camera_xy`` (2,) m sees it.

    ``base_xy`` (2,) m: the robot's base on the floor (world frame). Sets the bodies' ``body_pos`` and
    ``body_quat``; the caller runs the kinematics.
    """
    away = np.asarray(base_xy, dtype=np.float64) - np.asarray(camera_xy, dtype=np.float64)
    heading = float(np.arctan2(away[1], away[0])) if np.linalg.norm(away) > 1e-9 else 0.0
    for body, item in zip(bodies, items, strict=True):
        angle = heading + item.azimuth
        xy = np.asarray(base_xy, dtype=np.float64) + item.distance * np.array([np.cos(angle), np.sin(angle)])
        model.body_pos[body] = [xy[0], xy[1], item.half_size[2]]
        half = 0.5 * (angle + item.yaw)
        model.body_quat[body] = [np.cos(half), 0.0, 0.0, np.sin(half)]
