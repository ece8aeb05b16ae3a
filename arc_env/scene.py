"""The simulated world: a robot from an MJCF or URDF file on a floor, a camera on a tripod, lights.

``Scene`` compiles the robot into a scene of its own and answers what the environment needs:
the arm's joints and limits, its kinematics Gamma(Q, J) in the base frame (the function the
solver takes), the camera pose, rendering (RGB and a robot mask) and the moving links' surface
points (for the oracle keypoints).

Surface texture. A flat-shaded mesh has few corners, while real arms have seams, screws, logos and
scuffs. Every rendered geom of the robot gets one material: a MuJoCo built-in cube texture with
random dark marks on a light ground (``mark="random"``), mapped from each geom's local
coordinates, i.e. a uniform speckle "paint". This is fair: the marks are random texels, not
fiducials; nothing downstream knows where they are or that they exist, the tracker finds corners
in the rendered pixels exactly as it would on a real arm, and the solver only ever sees tracks.

Frames: the world frame is MuJoCo's; the robot's base frame is its base body's frame;
``T_camera_base`` (OpenCV optical frame, ``solver.frames``) is what the calibration recovers.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray

from arc_env.camera import fovy_from_intrinsics, mujoco_camera_from_optical
from arc_env.marker_board import MarkerBoard, add_marker_board, restore_board_material
from solver.camera import in_image, pixels_from_camera_points
from solver.errors import InvalidInputError
from solver.frames import check_transform, transform_from_rt
from solver.observations import CameraIntrinsics

FloatArray = NDArray[np.float64]

#: Name of the camera the scene adds; its pose is set by ``Scene.set_camera``.
CAMERA_NAME = "arc_camera"
#: Name of the body carrying the camera housing and tripod (collision geometry for the planners).
MOUNT_BODY = "arc_camera_mount"
_SPECKLE = "arc_speckle"

#: A typical Panda start configuration (rad) for the gymnasium-robotics model.
PANDA_HOME = (0.0, -0.5, 0.0, -2.0, 0.0, 1.5, 0.0)


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


@dataclass(frozen=True)
class Obstacle:
    """A static box in the scene (rendered and collision-checked).

    Attributes:
        name: geom name.
        pos: (3,) metres, the box centre in the world frame.
        half_size: (3,) metres, half extents along world x, y, z.
    """

    name: str
    pos: tuple[float, float, float]
    half_size: tuple[float, float, float]


@dataclass(frozen=True)
class SceneConfig:
    """How the scene is built and rendered.

    Attributes:
        robot: the robot.
        width: image width, px.
        height: image height, px.
        fx: focal length in pixels at ``width`` (fx = fy; a RealSense D415 colour stream has about
            1380 at 1920x1080); None scales 1380 with the width.
        shadows: render shadows (off by default: about 8x cheaper at 1080p).
        reflections: render floor reflections (off by default).
        multisamples: MSAA samples per pixel (MuJoCo's ``offsamples``). 0 (default) renders a 1080p
            frame about 2.2x cheaper than MuJoCo's 4 on llvmpipe (82 vs 186 ms, one thread); only
            geometry edges differ (texture marks are filtered either way), and ``blur_px`` softens
            their aliasing.
        blur_px: standard deviation of a Gaussian point-spread function applied to every
            full-resolution frame, px (a real lens and sensor never give one-pixel staircases;
            0 turns it off). Measured on the 960x540 recording round trip
            (tests/arc_env/test_round_trip.py): aliased frames 9.7 mrad / 8.6 mm, with the 0.7 px
            blur 5.0 mrad / 3.7 mm, with 4x MSAA and no blur 3.0 mrad / 3.3 mm; costs 3.6 ms at 1080p.
        speckle: give the robot's rendered geoms the random-speckle texture (see the module doc).
        speckle_texels: texels per cube face of the speckle texture (fewer: larger marks).
        speckle_density: fraction of texels that are dark marks.
        obstacles: static boxes.
        camera_mount: add a camera housing and tripod pole as collision geometry.
        marker_board: a ChArUco board fixed to the robot (the marker baseline's scene,
            ``arc_env.marker_board``); None (default) for the markerless scene.
    """

    robot: RobotSource = field(default_factory=RobotSource)
    width: int = 1920
    height: int = 1080
    fx: float | None = None
    shadows: bool = False
    reflections: bool = False
    multisamples: int = 0
    blur_px: float = 0.7
    speckle: bool = True
    speckle_texels: int = 96
    speckle_density: float = 0.06
    obstacles: tuple[Obstacle, ...] = ()
    camera_mount: bool = True
    marker_board: MarkerBoard | None = None

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise InvalidInputError(f"image size {self.width}x{self.height} is too small")
        if self.fx is not None and not self.fx > 0:
            raise InvalidInputError(f"fx must be > 0, got {self.fx}")
        if not 0 <= self.multisamples <= 16:
            raise InvalidInputError(f"multisamples must be in 0..16, got {self.multisamples}")
        if not 0.0 <= self.blur_px <= 5.0:
            raise InvalidInputError(f"blur_px must be in [0, 5], got {self.blur_px}")
        if not 0.0 < self.speckle_density < 1.0:
            raise InvalidInputError("speckle_density must be in (0, 1)")

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """The rendered camera: fx = fy, principal point at the image centre, no distortion."""
        fx = self.fx if self.fx is not None else 1380.0 * self.width / 1920.0
        return CameraIntrinsics.from_fov(fx, self.width, self.height)


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


def _robot_spec(source: RobotSource) -> mujoco.MjSpec:
    if source.path is None:
        return _panda_spec()
    path = Path(source.path)
    if not path.is_file():
        raise InvalidInputError(f"robot file {path} does not exist")
    try:
        return mujoco.MjSpec.from_file(str(path))
    except Exception as exc:  # MuJoCo raises ValueError with the parser's message
        raise InvalidInputError(f"robot file {path} could not be loaded: {exc}") from exc


def robot_spec(source: RobotSource) -> mujoco.MjSpec:
    """The robot's model as a MuJoCo spec (file paths of meshes made absolute for the default Panda).

    Raises:
        InvalidInputError: the file is missing or does not load (the message names it).
    """
    return _robot_spec(source)


def _world_xml(config: SceneConfig) -> str:
    c = config
    reflect = 0.2 if c.reflections else 0.0
    obstacles = "".join(
        f'<geom name="{o.name}" type="box" pos="{" ".join(map(str, o.pos))}" '
        f'size="{" ".join(map(str, o.half_size))}" rgba=".55 .45 .35 1"/>' for o in c.obstacles)
    # The housing sits behind the optical centre (a MuJoCo camera looks along its -z).
    housing = ('<geom name="arc_camera_housing" type="box" size="0.05 0.015 0.015" pos="0 0 0.02" '
               'rgba=".15 .15 .15 1"/>') if c.camera_mount else ""
    mount = (f'<body name="{MOUNT_BODY}"><camera name="{CAMERA_NAME}" '
             f'fovy="{fovy_from_intrinsics(c.intrinsics)}"/>{housing}</body>')
    return f"""<mujoco model="arc_scene">
  <visual><global offwidth="{c.width}" offheight="{c.height}"/>
    <quality shadowsize="4096" offsamples="{c.multisamples}"/>
    <headlight ambient=".35 .35 .35" diffuse=".4 .4 .4" specular="0 0 0"/></visual>
  <asset>
    <texture name="arc_floor" type="2d" builtin="checker" rgb1=".32 .33 .35" rgb2=".26 .27 .29"
      width="512" height="512"/>
    <material name="arc_floor" texture="arc_floor" texrepeat="6 6" reflectance="{reflect}"/>
    <texture name="{_SPECKLE}" type="cube" builtin="flat" mark="random" random="{c.speckle_density}"
      rgb1=".88 .88 .85" markrgb=".08 .08 .08" width="{c.speckle_texels}" height="{c.speckle_texels}"/>
    <material name="{_SPECKLE}" texture="{_SPECKLE}" specular=".2" shininess=".2"/>
  </asset>
  <worldbody>
    <light name="arc_key" pos="1.5 1.0 3.0" dir="-0.5 -0.3 -1" directional="true" diffuse=".55 .55 .55"
      castshadow="{str(c.shadows).lower()}"/>
    <light name="arc_fill" pos="-1.5 -1.0 2.5" dir="0.5 0.3 -1" directional="true" diffuse=".25 .25 .25"
      castshadow="false"/>
    <geom name="arc_floor" type="plane" size="4 4 0.1" material="arc_floor"/>
    {obstacles}
    {mount}
  </worldbody>
</mujoco>"""


def _primitive_surface(kind: int, size: FloatArray, rng: np.random.Generator, n: int = 300) -> FloatArray | None:
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


def _subtree(model: mujoco.MjModel, root: int) -> list[int]:
    return [b for b in range(model.nbody) if _is_descendant(model, b, root)]


def _is_descendant(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return root == 0


class Scene:
    """A compiled MuJoCo scene with one robot and one camera.

    Args:
        config: how to build it.

    Raises:
        InvalidInputError: the robot file is missing or does not load (the message names it), the
            base body or a joint does not exist (the message lists the valid names), or the arm
            has no hinge joints.
    """

    def __init__(self, config: SceneConfig | None = None):
        self.config = config or SceneConfig()
        source = self.config.robot
        where = source.path or "the gymnasium-robotics Panda"
        robot = _robot_spec(source)
        bodies = [b.name for b in robot.bodies if b.name]
        base = robot.body(source.base_body)
        if base is None:
            raise InvalidInputError(f"{where}: no body named {source.base_body!r}; bodies: {bodies}")
        spec = mujoco.MjSpec.from_string(_world_xml(self.config))
        for attr in ("nuser_actuator", "nuser_body", "nuser_geom", "nuser_jnt", "nuser_site", "nuser_sensor",
                     "nuser_tendon", "nuser_cam"):
            setattr(spec, attr, getattr(robot, attr))  # avoid MuJoCo's attach-conflict warnings
        frame = spec.worldbody.add_frame()
        frame.attach_body(base, "", "")  # keep the robot's own names
        if self.config.marker_board is not None:
            add_marker_board(spec, self.config.marker_board)
        try:
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Attaching a spec with an empty prefix")
                self.model = spec.compile()
        except Exception as exc:
            raise InvalidInputError(f"{where}: the scene does not compile: {exc}") from exc
        m = self.model
        self.base_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, source.base_body)
        self.robot_bodies = _subtree(m, self.base_body)
        self._set_up_robot_geoms()
        if self.config.marker_board is not None:
            restore_board_material(m)  # the speckle paint is for the robot, not the board
        self.arm_joints = self._arm_joints(source, where)
        self.n_joints = len(self.arm_joints)
        self.qpos_adr = np.array([m.jnt_qposadr[j] for j in self.arm_joints])
        limited = np.array([bool(m.jnt_limited[j]) for j in self.arm_joints])
        rng = np.array([m.jnt_range[j] for j in self.arm_joints], dtype=np.float64)
        self.lower = np.where(limited, rng[:, 0], -np.pi)
        self.upper = np.where(limited, rng[:, 1], np.pi)
        if source.home:
            home = np.asarray(source.home, dtype=np.float64)
            if home.shape != (self.n_joints,):
                raise InvalidInputError(f"{where}: home has {home.size} values for {self.n_joints} joints")
        else:
            home = np.zeros(self.n_joints)
        self.home = np.clip(home, self.lower, self.upper)
        self.camera_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME)
        self.mount_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, MOUNT_BODY)
        self.data = mujoco.MjData(m)
        self._kin = mujoco.MjData(m)
        mujoco.mj_kinematics(m, self._kin)
        self.T_world_base = transform_from_rt(self._kin.xmat[self.base_body].reshape(3, 3).copy(),
                                              self._kin.xpos[self.base_body].copy())
        self.T_camera_base = np.eye(4)
        self._surface: dict[int, tuple[NDArray[np.int64], FloatArray]] = {}
        self._renderers: dict[int, mujoco.Renderer] = {}  # by downscale factor
        self._scene_option = mujoco.MjvOption()
        for g in range(3, 6):  # collision geoms live in group 3 by convention
            self._scene_option.geomgroup[g] = 0
        self.set_q(self.home)

    # -- robot ---------------------------------------------------------------------------------
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

    def _set_up_robot_geoms(self) -> None:
        """Render what the robot file meant to be seen, and give it the speckle texture.

        When the robot has visual-only geoms (contype = conaffinity = 0), its collision geoms are
        moved to group 3 so they are not drawn over them (URDF imports put collision geoms in
        group 0); otherwise its collision geoms are what renders.
        """
        m = self.model
        robot = np.isin(m.geom_bodyid, self.robot_bodies)
        visual = robot & (m.geom_contype == 0) & (m.geom_conaffinity == 0)
        if visual.any():
            m.geom_group[robot & ~visual & (m.geom_group <= 2)] = 3
        rendered = robot & (m.geom_group <= 2)
        if self.config.speckle:
            m.geom_matid[rendered] = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MATERIAL, _SPECKLE)

    @property
    def joint_names(self) -> list[str]:
        """Names of the arm joints, in order."""
        return [self.model.joint(j).name for j in self.arm_joints]

    def check_q(self, q: FloatArray) -> FloatArray:
        """Validate an arm configuration q: (n_joints,) rad; returns it as float64."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n_joints,):
            raise InvalidInputError(f"q must have shape ({self.n_joints},), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise InvalidInputError("q contains NaN or infinite values")
        return q

    def set_q(self, q: FloatArray) -> None:
        """Put the arm at q: (n_joints,) rad in the rendering state (no dynamics)."""
        self.data.qpos[self.qpos_adr] = q
        self._forward(self.data)

    def set_swept(self, q: FloatArray, joint: int, delta: float) -> None:
        """Put the arm at q: (n_joints,) rad with joint ``joint`` turned further by ``delta`` rad."""
        q = q.copy()
        q[joint] += delta
        self.set_q(q)

    def _forward(self, data: mujoco.MjData) -> None:
        mujoco.mj_kinematics(self.model, data)
        mujoco.mj_camlight(self.model, data)  # cameras are placed here, not by mj_kinematics

    @property
    def q(self) -> FloatArray:
        """The arm's current configuration, (n_joints,) rad."""
        return self.data.qpos[self.qpos_adr].copy()

    def axis_and_point(self, q: FloatArray, joint: int) -> tuple[FloatArray, FloatArray]:
        """Gamma(Q, J): joint ``joint``'s axis (3,) unit and a point on it (3,) m, base frame, at q.

        This is the ``AxisFunction`` the solver takes; it reads MuJoCo's own kinematics.
        """
        q = self.check_q(q)
        if not 0 <= joint < self.n_joints:
            raise InvalidInputError(f"joint must be in [0, {self.n_joints}), got {joint}")
        self._kin.qpos[self.qpos_adr] = q
        mujoco.mj_kinematics(self.model, self._kin)
        j = self.arm_joints[joint]
        R_wb, p_wb = self.T_world_base[:3, :3], self.T_world_base[:3, 3]
        axis = R_wb.T @ self._kin.xaxis[j]
        point = R_wb.T @ (self._kin.xanchor[j] - p_wb)
        return axis / np.linalg.norm(axis), point

    def moving_bodies(self, joint: int) -> list[int]:
        """Bodies that joint ``joint`` moves (its body's subtree)."""
        return _subtree(self.model, int(self.model.jnt_bodyid[self.arm_joints[joint]]))

    # -- camera --------------------------------------------------------------------------------
    @functools.cached_property
    def intrinsics(self) -> CameraIntrinsics:
        """The rendered camera's intrinsics (built once: the config is frozen)."""
        return self.config.intrinsics

    def set_camera(self, T_camera_base: FloatArray) -> None:
        """Place the camera (and its mount) so that ``p_camera = T_camera_base @ p_base``."""
        T_camera_base = check_transform(T_camera_base, "T_camera_base")
        self._place_mount(T_camera_base)
        self.T_camera_base = T_camera_base.copy()
        mujoco.mj_kinematics(self.model, self._kin)

    def _place_mount(self, T_camera_base: FloatArray) -> None:
        """Move the camera mount body to where ``T_camera_base`` puts the camera; update ``data``."""
        T_world_camera = self.T_world_base @ np.linalg.inv(T_camera_base)
        self.model.body_pos[self.mount_body], self.model.body_quat[self.mount_body] = \
            mujoco_camera_from_optical(T_world_camera)
        self._forward(self.data)

    # -- rendering -----------------------------------------------------------------------------
    @property
    def renderer(self) -> mujoco.Renderer:
        """The full-resolution offscreen renderer (created on first use)."""
        return self._renderer(1)

    def _renderer(self, downscale: int) -> mujoco.Renderer:
        if downscale not in self._renderers:
            h, w = max(1, self.config.height // downscale), max(1, self.config.width // downscale)
            try:
                self._renderers[downscale] = mujoco.Renderer(self.model, h, w)
            except Exception as exc:
                raise RuntimeError(
                    f"offscreen rendering failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: {exc}. "
                    "Install Mesa's EGL (apt libegl1) or OSMesa (libosmesa6) and set MUJOCO_GL."
                ) from exc
        return self._renderers[downscale]

    def _update(self, T_camera_base: FloatArray | None, downscale: int = 1) -> mujoco.Renderer:
        if int(downscale) != downscale or downscale < 1:
            raise InvalidInputError(f"downscale must be a positive integer, got {downscale!r}")
        r = self._renderer(int(downscale))
        if T_camera_base is None:
            r.update_scene(self.data, CAMERA_NAME, scene_option=self._scene_option)
        else:
            cam = mujoco.MjvCamera()
            cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            cam.fixedcamid = self.camera_id
            m = self.model
            saved = m.body_pos[self.mount_body].copy(), m.body_quat[self.mount_body].copy()
            self._place_mount(check_transform(T_camera_base, "T_camera_base"))
            r.update_scene(self.data, cam, scene_option=self._scene_option)
            m.body_pos[self.mount_body], m.body_quat[self.mount_body] = saved
            self._forward(self.data)
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = int(self.config.shadows)
        r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = int(self.config.reflections)
        return r

    def render(self, downscale: int = 1) -> NDArray[np.uint8]:
        """The camera's RGB image of the current state, (H // downscale, W // downscale, 3) uint8.

        A ``downscale`` above 1 is a thumbnail of the same view (same field of view, fewer pixels),
        for cheap image tests; the tracker always gets full resolution. Full-resolution frames get
        the config's point-spread function (``blur_px``); thumbnails, whose pixels are larger than
        it, do not.
        """
        r = self._update(None, downscale)
        r.disable_segmentation_rendering()
        image = r.render().copy()
        if downscale == 1 and self.config.blur_px > 0:
            image = cv2.GaussianBlur(image, (0, 0), self.config.blur_px)
        return image

    def depth(self, T_camera_base: FloatArray | None = None, downscale: int = 1) -> NDArray[np.float32]:
        """Depth along the optical axis of every pixel, (H // downscale, W // downscale) float32, metres.

        Seen by the true camera or one at ``T_camera_base`` (e.g. an estimate, to predict what it
        would see); the far clipping distance where nothing is hit.
        """
        r = self._update(T_camera_base, downscale)
        r.enable_depth_rendering()
        try:
            return r.render().copy()
        finally:
            r.disable_depth_rendering()

    def robot_mask(self, T_camera_base: FloatArray | None = None) -> NDArray[np.bool_]:
        """Pixels showing the robot, (H, W) bool, seen by the true camera or one at ``T_camera_base``."""
        r = self._update(T_camera_base)
        r.enable_segmentation_rendering()
        try:
            seg = r.render()
        finally:
            r.disable_segmentation_rendering()
        geom_ids = seg[..., 0]
        is_geom = seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
        robot_geom = np.zeros(self.model.ngeom + 1, dtype=bool)
        robot_geom[:-1] = np.isin(self.model.geom_bodyid, self.robot_bodies)
        return is_geom & robot_geom[np.where(geom_ids >= 0, geom_ids, self.model.ngeom)]

    def close(self) -> None:
        """Free the renderers' GL contexts."""
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()

    # -- surface points (oracle keypoints) -------------------------------------------------------
    def surface_points(self, joint: int) -> tuple[NDArray[np.int64], FloatArray]:
        """Vertices of the rendered geoms that joint ``joint`` moves.

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
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
                mid = m.geom_dataid[g]
                verts = m.mesh_vert[m.mesh_vertadr[mid]:m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
            else:
                verts = _primitive_surface(int(m.geom_type[g]), m.geom_size[g], np.random.default_rng(g))
                if verts is None:
                    continue
            R = m.geom_quat[g]
            rot = np.empty(9)
            mujoco.mju_quat2Mat(rot, R)
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

    def points_base(self, body: NDArray[np.int64], local: FloatArray) -> FloatArray:
        """Body-fixed points at the current state in the base frame: (P,), (P, 3) -> (P, 3) metres."""
        R = self.data.xmat[body].reshape(-1, 3, 3)
        world = np.einsum("pij,pj->pi", R, local) + self.data.xpos[body]
        R_wb, p_wb = self.T_world_base[:3, :3], self.T_world_base[:3, 3]
        return (world - p_wb) @ R_wb

    def project_points(self, body: NDArray[np.int64], local: FloatArray, T_camera_base: FloatArray,
                       min_depth: float, margin_px: float = 0.0) -> tuple[FloatArray, NDArray[np.bool_]]:
        """Body-fixed points at the current state seen through a camera at ``T_camera_base``.

        Args:
            body: (P,) body ids.
            local: (P, 3) metres, the points in those bodies' frames.
            T_camera_base: (4, 4) float64, the camera to project with (true or estimated).
            min_depth: m; points nearer (or behind the camera) are not visible.
            margin_px: px; points closer to the image border are not visible.

        Returns:
            pixels (P, 2) float64 (meaningless where not visible) and visible (P,) bool.
        """
        pc = self.points_base(body, local) @ T_camera_base[:3, :3].T + T_camera_base[:3, 3]
        front = pc[:, 2] > min_depth
        pc[~front, 2] = 1.0  # keep the projection finite; these points are reported not visible
        uv = pixels_from_camera_points(pc, self.intrinsics)
        return uv, front & in_image(uv, self.intrinsics, margin_px)
