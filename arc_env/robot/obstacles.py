"""Known obstacles around a robot: boxes and spheres in its base frame, read from a YAML or JSON file.

``arc-calib plan --obstacles FILE`` keeps every start configuration, sweep and transit of a motion script
clear of them (``RobotModel.load(source, obstacles=...)`` adds them to the model as collision geometry).
The file is a list (YAML or JSON; JSON is YAML) of entries, each either a box or a sphere, in the robot's
base frame, metres::

    - {type: box, size: [0.6, 0.8, 0.02], pos: [0.5, 0.0, -0.01]}          # full edge lengths
    - {type: box, half_size: [0.05, 0.05, 0.4], pos: [0.4, 0.5, 0.4],
       quat: [0.0, 0.0, 0.3826834, 0.9238795]}                            # x, y, z, w (as ROS)
    - {type: sphere, radius: 0.1, pos: [0.3, -0.4, 0.6], name: lamp}

``type`` may be left out when the keys say it (``radius``: a sphere; ``size`` or ``half_size``: a box).
``quat`` (boxes only) is the box's orientation in the base frame, (x, y, z, w), normalised on reading;
``name`` is optional (letters, digits, ``_`` and ``-``). Anything else is refused with a message naming
the entry and the valid keys.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.errors import InvalidInputError

#: Prefix of the geoms ``add_obstacles`` adds (``arc_obstacle_<k>`` or ``arc_obstacle_<name>``).
OBSTACLE_PREFIX = "arc_obstacle_"
#: Geom group of the obstacles (collision-only: never drawn, by MuJoCo's convention for groups 3-5).
OBSTACLE_GROUP = 3
_KEYS = {"box": {"type", "name", "size", "half_size", "pos", "quat"}, "sphere": {"type", "name", "radius", "pos"}}
_NAME = re.compile(r"[A-Za-z0-9_-]{1,64}")


@dataclass(frozen=True)
class Obstacle:
    """A static box or sphere in the robot's base frame.

    Attributes:
        kind: "box" or "sphere".
        pos: (3,) metres, the centre in the base frame.
        half_size: (3,) metres, a box's half extents along its own axes; (r, r, r) for a sphere.
        quat_xyzw: (4,) the orientation in the base frame, (x, y, z, w), unit; (0, 0, 0, 1) for a sphere.
        name: a label for messages (the geom is named ``OBSTACLE_PREFIX + name``).
    """

    kind: str
    pos: tuple[float, float, float]
    half_size: tuple[float, float, float]
    quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    name: str = ""


def _vector(entry: dict, key: str, n: int, where: str, positive: bool = False) -> tuple[float, ...]:
    value = entry[key]
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{where}: {key} must be {n} numbers, got {value!r}") from exc
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{where}: {key} must be {n} finite numbers, got {value!r}")
    if positive and not np.all(arr > 0):
        raise InvalidInputError(f"{where}: {key} must be > 0 metres, got {value!r}")
    return tuple(float(v) for v in arr)


def obstacle_from_entry(entry: Any, where: str) -> Obstacle:
    """One entry of an obstacles file -> Obstacle; InvalidInputError naming ``where`` and the valid keys."""
    if not isinstance(entry, dict):
        raise InvalidInputError(f"{where}: must be a mapping such as {{type: box, size: [x, y, z], pos: [x, y, z]}} "
                                f"or {{type: sphere, radius: r, pos: [x, y, z]}}, got {entry!r}")
    kind = entry.get("type")
    if kind is None:
        kind = "sphere" if "radius" in entry else "box" if {"size", "half_size"} & set(entry) else None
    if kind not in _KEYS:
        raise InvalidInputError(f"{where}: type must be one of {sorted(_KEYS)} (or leave it out and give radius, "
                                f"size or half_size), got {entry.get('type')!r}")
    unknown = sorted(str(k) for k in entry if k not in _KEYS[kind])
    if unknown:
        raise InvalidInputError(f"{where}: unknown key(s) {unknown} for a {kind}; valid keys: {sorted(_KEYS[kind])}")
    if "pos" not in entry:
        raise InvalidInputError(f"{where}: a {kind} needs pos: [x, y, z] (metres, base frame)")
    name = entry.get("name", "")
    if name != "" and not (isinstance(name, str) and _NAME.fullmatch(name)):
        raise InvalidInputError(f"{where}: name {name!r} must be 1 to 64 letters, digits, '_' or '-'")
    pos = _vector(entry, "pos", 3, where)
    if kind == "sphere":
        if "radius" not in entry:
            raise InvalidInputError(f"{where}: a sphere needs radius (metres)")
        radius = entry["radius"]
        if isinstance(radius, bool) or not isinstance(radius, int | float) or not math.isfinite(radius) or radius <= 0:
            raise InvalidInputError(f"{where}: radius must be a number > 0 metres, got {radius!r}")
        r = float(radius)
        return Obstacle("sphere", pos, (r, r, r), name=name)
    if ("size" in entry) == ("half_size" in entry):
        raise InvalidInputError(f"{where}: a box needs exactly one of size (full edge lengths) or half_size, metres")
    key = "size" if "size" in entry else "half_size"
    half = np.asarray(_vector(entry, key, 3, where, positive=True)) * (0.5 if key == "size" else 1.0)
    quat = (0.0, 0.0, 0.0, 1.0)
    if "quat" in entry:
        q = np.asarray(_vector(entry, "quat", 4, where))
        if np.linalg.norm(q) < 1e-6:
            raise InvalidInputError(f"{where}: quat (x, y, z, w) must not be zero")
        quat = tuple(float(v) for v in q / np.linalg.norm(q))
    return Obstacle("box", pos, (float(half[0]), float(half[1]), float(half[2])), quat, name)  # type: ignore[arg-type]


def read_obstacles(path: str | Path) -> tuple[Obstacle, ...]:
    """The obstacles of a YAML or JSON file (the module docstring gives the format).

    Raises:
        InvalidInputError: the file is unreadable, not YAML/JSON, not a list, or an entry is invalid
            (the message names the file and the entry's index).
    """
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InvalidInputError(f"--obstacles {path}: not a readable YAML or JSON file: {exc}") from exc
    if data is None:
        return ()
    if not isinstance(data, list):
        raise InvalidInputError(f"--obstacles {path}: must be a list of boxes and spheres, got a {type(data).__name__}")
    obstacles = tuple(obstacle_from_entry(e, f"--obstacles {path}: entry {k}") for k, e in enumerate(data))
    names = [o.name for o in obstacles if o.name]
    if len(set(names)) != len(names):
        raise InvalidInputError(f"--obstacles {path}: names must be unique, got {names}")
    return obstacles


def geom_name(obstacle: Obstacle, index: int) -> str:
    """The MuJoCo geom name of obstacle ``index``: ``arc_obstacle_<name>`` or ``arc_obstacle_<index>``."""
    return OBSTACLE_PREFIX + (obstacle.name or str(index))


def add_obstacles(spec: mujoco.MjSpec, obstacles: Sequence[Obstacle], T_world_base: FloatArray) -> None:
    """Add the obstacles to the world body of ``spec`` as collision geoms (group ``OBSTACLE_GROUP``).

    Args:
        spec: the model spec (its world body gets one geom per obstacle).
        obstacles: boxes and spheres in the base frame.
        T_world_base: (4, 4) float64, metres: the robot base's pose in the world frame.
    """
    for k, o in enumerate(obstacles):
        R_base_geom = Rotation.from_quat(o.quat_xyzw).as_matrix()
        R_world_geom = T_world_base[:3, :3] @ R_base_geom
        p_world = T_world_base[:3, :3] @ np.asarray(o.pos) + T_world_base[:3, 3]
        x, y, z, w = Rotation.from_matrix(R_world_geom).as_quat()
        kind = mujoco.mjtGeom.mjGEOM_BOX if o.kind == "box" else mujoco.mjtGeom.mjGEOM_SPHERE
        spec.worldbody.add_geom(name=geom_name(o, k), type=kind, size=list(o.half_size), pos=p_world.tolist(),
                                quat=[w, x, y, z], group=OBSTACLE_GROUP)


__all__ = ["OBSTACLE_GROUP", "OBSTACLE_PREFIX", "Obstacle", "add_obstacles", "geom_name", "obstacle_from_entry",
           "read_obstacles"]
