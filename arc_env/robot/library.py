"""Named robots for tests and benchmarks: arm models that install from the package index, as shipped.

``library_robot(name)`` turns a name into a ``RobotSource`` (the model file, base body, arm joints and a
home configuration); ``ROBOT_NAMES`` lists the names. Every model is read in place from the package
that ships it, with its own meshes and colours (nothing painted, nothing written into the package;
``arc_env.robot.model.urdf_spec`` makes a URDF loadable in memory):

* ``panda``: the Franka Emika Panda of gymnasium-robotics (``kitchen_franka``), the default robot
  (``RobotSource()``): 7 joints, white and dark grey links.
* ``iiwa``: the KUKA LBR iiwa (rtkg's lbr_iiwa description) of pybullet's data package
  (``pybullet_data/kuka_iiwa/model.urdf``): 7 joints, links in the file's own grey, blue and orange.
* ``xarm6``: the UFACTORY xArm 6 of pybullet's data package (``pybullet_data/xarm/xarm6_robot_white.urdf``,
  the white version of the file): 6 joints, white links and a silver flange.

The two pybullet arms need the ``pybullet`` package (``pip install pybullet``, a dependency of
ARC-Calib); only its data files are read, pybullet itself is never imported.

Home configurations are upright, bent "ready" poses like the Panda's: the arm leans over the front of
its base (+x), every joint at least 0.4 rad inside its limits, no link touching another or the floor.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from arc_env.robot.model import RobotSource
from solver.errors import InvalidInputError

#: The robots ``library_robot`` knows, the default Panda first.
ROBOT_NAMES = ("panda", "iiwa", "xarm6")
#: The library's default robot (``RobotSource()``).
DEFAULT_ROBOT = "panda"

#: rad: the iiwa leaning forward at the shoulder, elbow bent back, the flange pointing down and forward.
IIWA_HOME = (0.0, 0.6, 0.0, -1.4, 0.0, 1.0, 0.0)
#: rad: the xArm 6 with its shoulder forward, elbow bent and the wrist pointing down and forward.
XARM6_HOME = (0.0, -0.5, -0.9, 0.0, 1.2, 0.0)


def pybullet_data_dir() -> Path:
    """The ``pybullet_data`` folder of the installed pybullet package (located, never imported).

    Raises:
        InvalidInputError: pybullet is not installed (the message says how to install it).
    """
    spec = importlib.util.find_spec("pybullet_data")
    if spec is None or not spec.submodule_search_locations:
        raise InvalidInputError("the library's iiwa and xarm6 robots need the pybullet package, whose "
                                "pybullet_data folder ships their models (pip install pybullet)")
    return Path(spec.submodule_search_locations[0])


def _pybullet_file(relative: str) -> str:
    path = pybullet_data_dir() / relative
    if not path.is_file():
        raise InvalidInputError(f"the installed pybullet package has no {relative} (at {path}); "
                                "pip install 'pybullet>=3.2.7,<3.3'")
    return str(path)


def library_robot(name: str) -> RobotSource:
    """The robot named ``name`` (one of ``ROBOT_NAMES``) as a ``RobotSource``.

    Raises:
        InvalidInputError: the name is unknown (the message lists the valid names), or the package that
            ships the model is not installed (the message names it).
    """
    if name == "panda":
        return RobotSource()
    if name == "iiwa":
        return RobotSource(path=_pybullet_file("kuka_iiwa/model.urdf"), base_body="lbr_iiwa_link_0",
                           joints=tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8)), home=IIWA_HOME)
    if name == "xarm6":
        return RobotSource(path=_pybullet_file("xarm/xarm6_robot_white.urdf"), base_body="link_base",
                           joints=tuple(f"joint{i}" for i in range(1, 7)), home=XARM6_HOME)
    raise InvalidInputError(f"unknown robot {name!r}; valid: {', '.join(ROBOT_NAMES)}")


def robot_from_arguments(robot: str | None, base_body: str | None) -> RobotSource:
    """The robot a command line names: a library name (``ROBOT_NAMES``), a model file, or the default.

    Args:
        robot: None (the default Panda), a name of ``ROBOT_NAMES`` (when no such file exists and no base
            body is given), or an MJCF/URDF file path, which needs ``base_body``.
        base_body: the body whose frame is the robot's base, for a model file.

    Raises:
        InvalidInputError: a model file without a base body, or a base body with a library name.
    """
    if robot is None:
        if base_body:
            raise InvalidInputError("--base-body needs --robot (a model file)")
        return RobotSource()
    if robot in ROBOT_NAMES and not Path(robot).exists():
        if base_body:
            raise InvalidInputError(f"--base-body is for a model file; the library's {robot!r} knows its own base")
        return library_robot(robot)
    if not base_body:
        raise InvalidInputError(f"--robot {robot!r} is not one of the library's robots ({', '.join(ROBOT_NAMES)}), "
                                "so it is a model file and needs --base-body (the body whose frame is the robot's "
                                "base)")
    return RobotSource(path=robot, base_body=base_body, home=())


def parse_robot_names(text: str) -> tuple[str, ...]:
    """A comma-separated list of robot names (e.g. a ``--robots`` argument), checked, in order, no repeats.

    Raises:
        InvalidInputError: the list is empty or names an unknown robot (the message lists the valid names).
    """
    names = tuple(dict.fromkeys(n.strip() for n in text.split(",") if n.strip()))
    if not names:
        raise InvalidInputError(f"no robot named in {text!r}; valid: {', '.join(ROBOT_NAMES)}")
    for n in names:
        if n not in ROBOT_NAMES:
            raise InvalidInputError(f"unknown robot {n!r}; valid: {', '.join(ROBOT_NAMES)}")
    return names


__all__ = ["DEFAULT_ROBOT", "IIWA_HOME", "ROBOT_NAMES", "XARM6_HOME", "library_robot", "parse_robot_names",
           "pybullet_data_dir"]
