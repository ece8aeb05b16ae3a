"""The robot as ARC-Calib needs it: a MuJoCo-compiled MJCF or URDF, used as kinematics and geometry only.

``RobotModel`` answers what the solver, the planners and the overlays ask of a robot: its arm joints and
limits, Gamma(Q, J) -> (axis, point) in the base frame (the function the solver takes), body poses,
the moving links' surface points, and the collision and visual geometry (``model``, for the planners'
collision checker and IK and for overlays). MuJoCo compiles the file and computes forward kinematics;
nothing here renders, so nothing here creates a GL context or needs the simulator.

``RobotModel.load`` compiles the robot on its own, with one collision-only ground plane at the world's
z = 0 (where the robot stands) so that planners never sweep the arm through its support: no rendered
floor, no texture, no camera. The simulator's ``arc_env.sim.scene.Scene`` compiles the same robot into
a rendered world and wraps that model in a ``RobotModel`` of its own.

Frames: the world frame is MuJoCo's; the robot's base frame is its base body's frame; every point and
axis this module returns is in the base frame (metres, radians).
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import threading
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from arc_env.robot.obstacles import Obstacle, add_obstacles
from solver.arrays import FloatArray, IndexArray, MaskArray
from solver.camera import in_image, pixels_from_camera_points
from solver.errors import InvalidInputError
from solver.frames import transform_from_rt
from solver.observations import CameraIntrinsics

#: A typical Panda start configuration (rad) for the gymnasium-robotics model.
PANDA_HOME = (0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.0)
#: Name of the collision-only ground plane ``RobotModel.load`` adds.
GROUND_GEOM = "arc_ground"
#: Geom group of collision-only geometry (never drawn, by MuJoCo's convention for groups 3-5).
COLLISION_GROUP = 3
#: MuJoCo compiler settings a URDF gets when its own ``<mujoco><compiler>`` element does not set them
#: (``urdf_spec``): keep every link as a body (the base body a result is expressed in must not be fused
#: into the world), draw the <visual> meshes (what the robot looks like; the <collision> geometry is
#: kept for the planners, ``RobotModel`` stops drawing it), keep the meshes' folders, and accept the
#: inertias as written (only kinematics are used here, never dynamics).
URDF_COMPILER = {"fusestatic": "false", "discardvisual": "false", "strippath": "false",
                 "balanceinertia": "true"}
#: Mesh files MuJoCo reads; a URDF whose <visual> meshes are of another kind (e.g. COLLADA .dae) keeps
#: MuJoCo's default of discarding its visuals, and its collision geometry is drawn instead.
MESH_SUFFIXES = (".stl", ".obj", ".msh")


@dataclass(frozen=True)
class RobotSource:
    """Where a robot comes from.

    Attributes:
        path: an MJCF (.xml) or URDF (.urdf) file; None means the Franka Panda that the
            gymnasium-robotics package ships.
        base_body: the body whose frame is the robot's base frame (``T_camera_base``'s "base").
        joints: names of the arm joints in order; empty means every hinge joint in the base
            body's subtree, in tree order.
        home: start configuration (rad), one value per arm joint; empty means zeros clipped to the
            joint limits.
    """

    path: str | None = None
    base_body: str = "panda0_link0"
    joints: tuple[str, ...] = ()
    home: tuple[float, ...] = PANDA_HOME

    @property
    def label(self) -> str:
        """How messages name the robot: its file, or the default Panda."""
        return self.path or "the gymnasium-robotics Panda"


def panda_mjcf_dir() -> Path:
    """The directory of the Franka Panda MJCF in the installed gymnasium-robotics package."""
    spec = importlib.util.find_spec("gymnasium_robotics")  # located, not imported (it is noisy)
    if spec is None or not spec.submodule_search_locations:
        raise InvalidInputError("the default robot needs the gymnasium-robotics package "
                                "(pip install gymnasium-robotics)")
    d = Path(spec.submodule_search_locations[0]) / "envs" / "assets" / "kitchen_franka" / "franka_assets"
    if not (d / "chain.xml").is_file():
        raise InvalidInputError(f"gymnasium-robotics has no Franka model at {d}")
    return d


def _panda_spec() -> mujoco.MjSpec:
    d = panda_mjcf_dir()
    xml = (f'<mujoco model="panda"><include file="{d / "assets.xml"}"/>'
           f'<worldbody><include file="{d / "chain.xml"}"/></worldbody></mujoco>')
    spec = mujoco.MjSpec.from_string(xml)
    for mesh in spec.meshes:  # assets.xml gives meshdir relative to its parent directory
        rel = os.path.relpath(mesh.file, d)
        mesh.file = str(d / "meshes" / rel)
    return spec


def _urdf_mesh_file(urdf: Path, filename: str) -> Path:
    """Where a URDF's mesh ``filename`` is.

    ``package://NAME/rest`` is looked up in the URDF's folder and its ancestors (a folder named NAME, or
    holding one); ``file://`` URIs and relative names start from the URDF's folder.
    """
    if filename.startswith("file://"):
        filename = filename[len("file://"):]
    if not filename.startswith("package://"):
        return Path(filename) if Path(filename).is_absolute() else urdf.parent / filename
    package, _, rest = filename[len("package://"):].partition("/")
    for folder in urdf.resolve().parents:
        for candidate in (folder, folder / package):
            if candidate.name == package and candidate.is_dir():
                return candidate / rest
    raise InvalidInputError(f"robot file {urdf}: no folder {package!r} beside it or above it for {filename}")


def urdf_spec(path: Path) -> mujoco.MjSpec:
    """A URDF file as a MuJoCo spec, made loadable in memory (the file is never changed).

    Mesh file names become absolute paths (``package://`` URIs resolved as ``_urdf_mesh_file`` says),
    since MuJoCo's URDF importer knows no packages and by default strips folders from file names; the
    compiler settings of ``URDF_COMPILER`` are added where the file's own ``<mujoco><compiler>`` element
    does not give them (visuals stay discarded when a visual mesh is not in ``MESH_SUFFIXES``).

    Raises:
        InvalidInputError: the file is not XML, a package folder is missing, or MuJoCo refuses it.
    """
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise InvalidInputError(f"robot file {path} could not be read: {exc}") from exc
    extension = root.find("mujoco")
    if extension is None:
        extension = ET.SubElement(root, "mujoco")
    compiler = extension.find("compiler")
    if compiler is None:
        compiler = ET.SubElement(extension, "compiler")
    own_paths = any(k in compiler.attrib for k in ("meshdir", "assetdir", "strippath"))
    if not own_paths:  # the file does not say where its meshes are: find them as ROS tools do
        for mesh in root.iter("mesh"):
            if mesh.get("filename"):
                mesh.set("filename", str(_urdf_mesh_file(path, mesh.get("filename", "")).resolve()))
    visual_meshes = [m.get("filename", "") for v in root.iter("visual") for m in v.iter("mesh")]
    defaults = dict(URDF_COMPILER)
    if any(not f.lower().endswith(MESH_SUFFIXES) for f in visual_meshes):
        defaults["discardvisual"] = "true"
    if own_paths:
        del defaults["strippath"]
    for key, value in defaults.items():
        compiler.attrib.setdefault(key, value)
    try:
        spec = mujoco.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    except Exception as exc:  # MuJoCo raises ValueError with the parser's message
        raise InvalidInputError(f"robot file {path} could not be loaded: {exc}") from exc
    spec.modelfiledir = str(path.parent.resolve())  # what the file's own relative paths start from
    return spec


def robot_spec(source: RobotSource) -> mujoco.MjSpec:
    """The robot's model as a MuJoCo spec (mesh paths made absolute for the default Panda and URDFs).

    An MJCF file is read as it is; a URDF (``.urdf``) through ``urdf_spec``.

    Raises:
        InvalidInputError: the file is missing or does not load (the message names it).
    """
    if source.path is None:
        return _panda_spec()
    path = Path(source.path)
    if not path.is_file():
        raise InvalidInputError(f"robot file {path} does not exist")
    if path.suffix.lower() == ".urdf":
        return urdf_spec(path)
    try:
        return mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # MuJoCo raises ValueError with the parser's message
        raise InvalidInputError(f"robot file {path} could not be loaded: {exc}") from exc


@contextlib.contextmanager
def quiet_attach() -> Iterator[None]:
    """Silence MuJoCo's "Attaching a spec with an empty prefix" warning (and only it) inside the block.

    Attaching the robot's bodies under their own names needs an empty prefix; MuJoCo warns that such a
    model may not save to XML, through its C warning hook (stderr and ``MUJOCO_LOG.TXT``) when attaching
    and as a Python ``UserWarning`` when compiling, on every command. Other warnings go on as before.
    """
    previous = mujoco.get_mju_user_warning()

    def hook(message: str) -> None:
        if "empty prefix" in message:
            return
        if previous is not None:
            previous(message)
        else:
            warnings.warn(f"MuJoCo: {message}", stacklevel=2)

    mujoco.set_mju_user_warning(hook)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Attaching a spec with an empty prefix")
            yield
    finally:
        mujoco.set_mju_user_warning(previous)


def attach_robot(world: mujoco.MjSpec, robot: mujoco.MjSpec, source: RobotSource) -> None:
    """Attach the robot's base body (and its subtree) to ``world``'s world body under its own names.

    Raises:
        InvalidInputError: the base body does not exist (the message lists the bodies).
    """
    base = robot.body(source.base_body)
    if base is None:
        bodies = [b.name for b in robot.bodies if b.name]
        raise InvalidInputError(f"{source.label}: no body named {source.base_body!r}; bodies: {bodies}")
    for attr in ("nuser_actuator", "nuser_body", "nuser_geom", "nuser_jnt", "nuser_site", "nuser_sensor",
                 "nuser_tendon", "nuser_cam"):
        setattr(world, attr, getattr(robot, attr))  # avoid MuJoCo's attach-conflict warnings
    with quiet_attach():
        world.worldbody.add_frame().attach_body(base, "", "")  # keep the robot's own names


def compile_spec(spec: mujoco.MjSpec, source: RobotSource) -> mujoco.MjModel:
    """Compile a spec holding the robot; InvalidInputError naming the robot when MuJoCo refuses."""
    try:
        with quiet_attach():
            return spec.compile()
    except Exception as exc:
        raise InvalidInputError(f"{source.label}: the model does not compile: {exc}") from exc


def primitive_surface(kind: int, size: FloatArray, rng: np.random.Generator, n: int = 300) -> FloatArray | None:
    """Points on a primitive geom's surface in its own frame, (n, 3) metres; None for other types."""
    G = mujoco.mjtGeom
    if kind in (G.mjGEOM_CAPSULE, G.mjGEOM_CYLINDER):
        a = rng.uniform(0, 2 * np.pi, n)
        return np.column_stack([size[0] * np.cos(a), size[0] * np.sin(a), rng.uniform(-size[1], size[1], n)])
    if kind in (G.mjGEOM_SPHERE, G.mjGEOM_ELLIPSOID):
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        return u * (size[:3] if kind == G.mjGEOM_ELLIPSOID else size[0])
    if kind == G.mjGEOM_BOX:
        p = rng.uniform(-1, 1, (n, 3))
        axis = rng.integers(0, 3, n)
        p[np.arange(n), axis] = rng.choice([-1.0, 1.0], n)
        return p * size[:3]
    return None



def geom_vertices(model: mujoco.MjModel, geom: int) -> FloatArray | None:
    """A geom's points in its own frame, (P, 3) metres; None for a type without any.

    A mesh's vertices, or a primitive's surface samples (seeded by the geom id: the same every call).
    """
    if model.geom_type[geom] == mujoco.mjtGeom.mjGEOM_MESH:
        mid = model.geom_dataid[geom]
        return model.mesh_vert[model.mesh_vertadr[mid]:model.mesh_vertadr[mid] + model.mesh_vertnum[mid]].astype(
            np.float64)
    return primitive_surface(int(model.geom_type[geom]), model.geom_size[geom], np.random.default_rng(geom))

def subtree(model: mujoco.MjModel, root: int) -> list[int]:
    """Body ids of ``root`` and all its descendants (every body when root is the world, 0)."""
    return [b for b in range(model.nbody) if _is_descendant(model, b, root)]


def _is_descendant(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return root == 0


class RobotModel:
    """One robot inside a compiled MuJoCo model: joints, limits, kinematics, geometry.

    Built by ``RobotModel.load`` (the robot alone) or by the simulator around its scene's model.
    ``data`` holds the arm's current state (``set_q``); ``axis_and_point`` uses a private state of its
    own, so it never disturbs ``data``, behind a lock, so threads may call it at once (an overlapped
    session's worker calibrates while the main thread plans and checks motions).

    Args:
        model: a compiled model that contains the robot.
        source: the robot (its base body, joints and home configuration).
        data: the state to keep the arm's configuration in (None: a new one).

    Raises:
        InvalidInputError: the base body or a joint does not exist (the message lists the valid
            names), a joint is not a hinge, the arm has no hinge joints, or ``home`` has the wrong length.
    """

    def __init__(self, model: mujoco.MjModel, source: RobotSource, data: mujoco.MjData | None = None):
        self.model = model
        self.source = source
        m = model
        where = source.label
        self.base_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, source.base_body)
        if self.base_body < 0:
            bodies = [m.body(b).name for b in range(1, m.nbody) if m.body(b).name]
            raise InvalidInputError(f"{where}: no body named {source.base_body!r}; bodies: {bodies}")
        self.robot_bodies = subtree(m, self.base_body)
        self._separate_visual_geoms()
        self.arm_joints = self._arm_joints(source, where)
        self.n_joints = len(self.arm_joints)
        self.qpos_adr = np.array([m.jnt_qposadr[j] for j in self.arm_joints])
        limited = np.array([bool(m.jnt_limited[j]) for j in self.arm_joints])
        rng = np.array([m.jnt_range[j] for j in self.arm_joints], dtype=np.float64)
        self.lower: FloatArray = np.where(limited, rng[:, 0], -np.pi)
        self.upper: FloatArray = np.where(limited, rng[:, 1], np.pi)
        if source.home:
            home = np.asarray(source.home, dtype=np.float64)
            if home.shape != (self.n_joints,):
                raise InvalidInputError(f"{where}: home has {home.size} values for {self.n_joints} joints")
        else:
            home = np.zeros(self.n_joints)
        self.home: FloatArray = np.clip(home, self.lower, self.upper)
        self.data = data if data is not None else mujoco.MjData(m)
        self._kin = mujoco.MjData(m)
        self._kin_lock = threading.Lock()
        mujoco.mj_kinematics(m, self._kin)
        self.T_world_base = transform_from_rt(self._kin.xmat[self.base_body].reshape(3, 3).copy(),
                                              self._kin.xpos[self.base_body].copy())
        self._surface: dict[int, tuple[IndexArray, FloatArray]] = {}

    @classmethod
    def load(cls, source: RobotSource, ground: bool = True, obstacles: Sequence[Obstacle] = ()) -> RobotModel:
        """Compile the robot on its own (no floor, texture or camera), at its home configuration.

        Args:
            source: the robot.
            ground: add a collision-only plane at the world's z = 0 (``GROUND_GEOM``, never drawn).
            obstacles: boxes and spheres in the base frame (``arc_env.robot.obstacles``), added as
                collision-only geoms of the world (the base's pose comes from a first compilation).

        Raises:
            InvalidInputError: the file is missing or does not load, or see the constructor.
        """
        robot = robot_spec(source)
        world = mujoco.MjSpec()
        world.modelname = "arc_robot"
        if ground:
            world.worldbody.add_geom(name=GROUND_GEOM, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[4.0, 4.0, 0.1],
                                     group=COLLISION_GROUP)
        attach_robot(world, robot, source)
        model = cls(compile_spec(world, source), source)
        if obstacles:
            add_obstacles(world, obstacles, model.T_world_base)
            model = cls(compile_spec(world, source), source)
        model.set_q(model.home)
        return model

    def _separate_visual_geoms(self) -> None:
        """Make what the robot file meant to be seen the drawn geometry.

        When the robot has visual-only geoms (contype = conaffinity = 0) in a drawn group (0-2), its
        collision geoms are moved to ``COLLISION_GROUP`` so they are not drawn over them (URDF imports
        put collision geoms in group 0); otherwise its collision geoms are what is drawn. Visual-only
        geoms in hidden groups (3-5, e.g. a simulator's decorations) do not count.
        """
        m = self.model
        robot = np.isin(m.geom_bodyid, self.robot_bodies)
        visual = robot & (m.geom_contype == 0) & (m.geom_conaffinity == 0) & (m.geom_group <= 2)
        if visual.any():
            m.geom_group[robot & ~visual & (m.geom_group <= 2)] = COLLISION_GROUP

    # -- joints --------------------------------------------------------------------------------
    def _arm_joints(self, source: RobotSource, where: str) -> list[int]:
        m = self.model
        names = [m.joint(j).name for j in range(m.njnt)]
        if source.joints:
            ids = []
            for name in source.joints:
                j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
                if j < 0:
                    raise InvalidInputError(f"{where}: no joint named {name!r}; joints: {names}")
                if m.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
                    raise InvalidInputError(f"{where}: joint {name!r} is not a hinge (revolute) joint")
                ids.append(j)
            return ids
        ids = [j for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
               and m.jnt_bodyid[j] in self.robot_bodies]
        if not ids:
            raise InvalidInputError(f"{where}: no hinge joint under body {source.base_body!r}")
        return ids

    @property
    def joint_names(self) -> list[str]:
        """Names of the arm joints, in order."""
        return [self.model.joint(j).name for j in self.arm_joints]

    @property
    def default_q(self) -> FloatArray:
        """The model's own reference configuration of the arm joints (``qpos0``), (n_joints,) rad."""
        return self.model.qpos0[self.qpos_adr].astype(np.float64)

    def check_q(self, q: FloatArray) -> FloatArray:
        """Validate an arm configuration q: (n_joints,) rad; returns it as float64."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n_joints,):
            raise InvalidInputError(f"q must have shape ({self.n_joints},), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise InvalidInputError("q contains NaN or infinite values")
        return q

    # -- state ---------------------------------------------------------------------------------
    def set_q(self, q: FloatArray) -> None:
        """Put the arm at q: (n_joints,) rad in ``data`` (no dynamics)."""
        self.data.qpos[self.qpos_adr] = q
        self.forward()

    def set_swept(self, q: FloatArray, joint: int, delta: float) -> None:
        """Put the arm at q: (n_joints,) rad with joint ``joint`` turned further by ``delta`` rad."""
        q = q.copy()
        q[joint] += delta
        self.set_q(q)

    def forward(self) -> None:
        """Recompute body, camera and light poses in ``data`` from its qpos and the model."""
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)  # cameras are placed here, not by mj_kinematics

    @property
    def q(self) -> FloatArray:
        """The arm's current configuration, (n_joints,) rad."""
        return self.data.qpos[self.qpos_adr].copy()

    # -- kinematics ----------------------------------------------------------------------------
    def axis_and_point(self, q: FloatArray, joint: int) -> tuple[FloatArray, FloatArray]:
        """Gamma(Q, J): joint ``joint``'s axis (3,) unit and a point on it (3,) m, base frame, at q.

        This is the ``AxisFunction`` the solver takes; it reads MuJoCo's own kinematics.
        """
        q = self.check_q(q)
        if not 0 <= joint < self.n_joints:
            raise InvalidInputError(f"joint must be in [0, {self.n_joints}), got {joint}")
        j = self.arm_joints[joint]
        with self._kin_lock:
            self._kin.qpos[self.qpos_adr] = q
            mujoco.mj_kinematics(self.model, self._kin)
            axis_world, anchor_world = self._kin.xaxis[j].copy(), self._kin.xanchor[j].copy()
        R_world_base, p_world_base = self.T_world_base[:3, :3], self.T_world_base[:3, 3]
        axis = R_world_base.T @ axis_world
        point = R_world_base.T @ (anchor_world - p_world_base)
        return axis / np.linalg.norm(axis), point

    def moving_bodies(self, joint: int) -> list[int]:
        """Bodies that joint ``joint`` moves (its body's subtree)."""
        return subtree(self.model, int(self.model.jnt_bodyid[self.arm_joints[joint]]))

    def joint_body(self, joint: int) -> int:
        """The body arm joint ``joint`` turns."""
        return int(self.model.jnt_bodyid[self.arm_joints[joint]])

    def is_visual(self, geom: int) -> bool:
        """Whether geom ``geom`` is drawn (groups 0-2), i.e. what a camera sees of the robot."""
        return bool(self.model.geom_group[geom] <= 2)

    def rendered_geoms(self) -> list[int]:
        """The robot's drawn geoms (see ``is_visual``), in id order."""
        m = self.model
        robot = np.isin(m.geom_bodyid, self.robot_bodies) & (m.geom_group <= 2)
        return [int(g) for g in np.nonzero(robot)[0]]

    def surface_points(self, joint: int) -> tuple[IndexArray, FloatArray]:
        """Vertices of the drawn geoms that joint ``joint`` moves.

        Returns:
            body: (P,) int, the body each point is fixed to; local: (P, 3) metres in that body's frame.
        """
        if joint in self._surface:
            return self._surface[joint]
        m = self.model
        moving = set(self.moving_bodies(joint))
        bodies, points = [], []
        for g in range(m.ngeom):
            if m.geom_bodyid[g] not in moving or m.geom_group[g] > 2:
                continue
            verts = geom_vertices(m, g)
            if verts is None:
                continue
            rot = np.empty(9)
            mujoco.mju_quat2Mat(rot, m.geom_quat[g])
            local = verts @ rot.reshape(3, 3).T + m.geom_pos[g]
            bodies.append(np.full(len(local), m.geom_bodyid[g]))
            points.append(local)
        if points:
            out = np.concatenate(bodies).astype(np.int64), np.concatenate(points)
        else:
            out = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        for a in out:
            a.flags.writeable = False
        self._surface[joint] = out  # the model's geometry is fixed: compute once per joint
        return out

    def points_base(self, body: IndexArray, local: FloatArray) -> FloatArray:
        """Body-fixed points at the current state in the base frame: (P,), (P, 3) -> (P, 3) metres."""
        R_world_body = self.data.xmat[body].reshape(-1, 3, 3)
        world = np.einsum("pij,pj->pi", R_world_body, local) + self.data.xpos[body]
        R_world_base, p_world_base = self.T_world_base[:3, :3], self.T_world_base[:3, 3]
        return (world - p_world_base) @ R_world_base

    def project_points(self, body: IndexArray, local: FloatArray, T_camera_base: FloatArray,
                       intrinsics: CameraIntrinsics, min_depth: float, margin_px: float = 0.0
                       ) -> tuple[FloatArray, MaskArray]:
        """Body-fixed points at the current state seen through a camera at ``T_camera_base``.

        Args:
            body: (P,) body ids.
            local: (P, 3) metres, the points in those bodies' frames.
            T_camera_base: (4, 4) float64, the camera pose to project with (an estimate, or the truth
                in simulation).
            intrinsics: the camera.
            min_depth: m; points nearer (or behind the camera) are not visible.
            margin_px: px; points closer to the image border are not visible.

        Returns:
            pixels (P, 2) float64 (meaningless where not visible) and visible (P,) bool.
        """
        points_camera = self.points_base(body, local) @ T_camera_base[:3, :3].T + T_camera_base[:3, 3]
        front = points_camera[:, 2] > min_depth
        points_camera[~front, 2] = 1.0  # keep the projection finite; these points are reported not visible
        uv = pixels_from_camera_points(points_camera, intrinsics)
        return uv, front & in_image(uv, intrinsics, margin_px)


__all__ = [
    "COLLISION_GROUP",
    "GROUND_GEOM",
    "MESH_SUFFIXES",
    "PANDA_HOME",
    "URDF_COMPILER",
    "RobotModel",
    "RobotSource",
    "attach_robot",
    "compile_spec",
    "geom_vertices",
    "panda_mjcf_dir",
    "primitive_surface",
    "quiet_attach",
    "robot_spec",
    "subtree",
    "urdf_spec",
]
