"""The simulated world: a robot from an MJCF or URDF file on a floor, a camera on a tripod, lights.

``Scene`` compiles the robot into a scene of its own and answers what the environment needs:
the arm's joints and limits, its kinematics Gamma(Q, J) in the base frame (the function the
solver takes), the camera pose, rendering (RGB and a robot mask) and the moving links' surface
points (for the oracle keypoints).

Surface texture (``SceneConfig.appearance``, ``arc_env.sim.imaging``). A flat-shaded mesh has few corners,
while real arms have seams, screws, logos and scuffs. ``painted`` (the default) gives every rendered geom
of the robot one material: a MuJoCo built-in cube texture with random dark marks on a light ground
(``mark="random"``), mapped from each geom's local coordinates, i.e. a uniform speckle "paint" -- richer
than any real arm. ``as_shipped`` keeps the model's own materials; ``realistic`` keeps their colours and adds
what real arms carry (``arc_env.sim.marks``): sparse screw heads or panel seams on some links, a few printed
labels and a cable along some links (visual-only geoms fixed to the links). The marks are random, not
fiducials; nothing downstream knows where they are or that they exist, and the solver only ever sees tracks.
Camera effects (noise, motion blur, gain drift, lossy video) are applied to the frames of a sweep
(``Scene.render_sweep``).

The robot itself (joints, limits, kinematics, surface points) is an ``arc_env.robot.model.RobotModel``
around the scene's compiled model, ``Scene.robot``; it shares the scene's state, so posing the arm poses
what renders. The true camera pose lives here, in the simulator, and nowhere a planner reads.

Frames: the world frame is MuJoCo's; the robot's base frame is its base body's frame;
``T_camera_base`` (OpenCV optical frame, ``solver.frames``) is what the calibration recovers.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray

from arc_env.robot.model import RobotModel, RobotSource, attach_robot, compile_spec, robot_spec
from arc_env.robot.rendering import create_renderer
from arc_env.sim.background import BACKGROUNDS, add_clutter, clutter_bodies, place_clutter, plan_clutter
from arc_env.sim.camera import fovy_from_intrinsics, mujoco_camera_from_optical
from arc_env.sim.imaging import APPEARANCES, CameraEffects
from arc_env.sim.marker_board import MarkerBoard, add_marker_board, restore_board_material
from arc_env.sim.marks import MARK_GROUP, SCREWS, SEAMS, Marks, add_marks, dress, plan_marks
from solver.arrays import FloatArray, ImageArray, MaskArray
from solver.errors import InvalidInputError
from solver.frames import check_transform
from solver.observations import CameraIntrinsics

#: Name of the camera the scene adds; its pose is set by ``Scene.set_camera``.
CAMERA_NAME = "arc_camera"
#: Name of the body carrying the camera housing and tripod (collision geometry for the planners).
MOUNT_BODY = "arc_camera_mount"
#: Side of the key light's square shadow map, px (``SceneConfig.shadows``).
SHADOW_MAP_PX = 2048
_SPECKLE = "arc_speckle"


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
        shadows: render shadows (off by default: about 5x cheaper at 1080p). The key light's shadow map
            is ``SHADOW_MAP_PX`` square (a 1080p render with shadows: 54 ms at 2048, 70 ms at MuJoCo's
            usual 4096, 11 ms without; 2 llvmpipe threads).
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
        appearance: the robot's surface: "painted" (uniform speckle), "as_shipped" (the model's own
            materials) or "realistic" (as shipped plus sparse screws, seams, labels and cables); see
            ``arc_env.sim.imaging`` and ``arc_env.sim.marks``.
        appearance_seed: which links get which marks, and where, under "realistic".
        speckle_texels: texels per cube face of the speckle texture (fewer: larger marks).
        speckle_density: fraction of texels that are dark marks.
        effects: what the camera adds to the frames of a sweep (noise, motion blur, gain drift, video).
        obstacles: static boxes.
        camera_mount: add a camera housing and tripod pole as collision geometry.
        marker_board: a ChArUco board fixed to the robot (the marker baseline's scene,
            ``arc_env.marker_board``); None (default) for the markerless scene.
        background: what stands behind the robot: "floor" (the floor alone, the default) or "lab" (cabinets,
            shelves, posters and boxes behind the robot as the camera sees it: ``arc_env.sim.background``).
        background_seed: which lab, under "lab".
    """

    robot: RobotSource = field(default_factory=RobotSource)
    width: int = 1920
    height: int = 1080
    fx: float | None = None
    shadows: bool = False
    reflections: bool = False
    multisamples: int = 0
    blur_px: float = 0.7
    appearance: str = "painted"
    appearance_seed: int = 0
    speckle_texels: int = 96
    speckle_density: float = 0.06
    obstacles: tuple[Obstacle, ...] = ()
    camera_mount: bool = True
    marker_board: MarkerBoard | None = None
    effects: CameraEffects = field(default_factory=CameraEffects)
    background: str = "floor"
    background_seed: int = 0

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
        if self.appearance not in APPEARANCES:
            raise InvalidInputError(f"appearance must be one of {APPEARANCES}, got {self.appearance!r}")
        if self.background not in BACKGROUNDS:
            raise InvalidInputError(f"background must be one of {BACKGROUNDS}, got {self.background!r}")

    @property
    def intrinsics(self) -> CameraIntrinsics:
        """The rendered camera: fx = fy, principal point at the image centre, no distortion."""
        fx = self.fx if self.fx is not None else 1380.0 * self.width / 1920.0
        return CameraIntrinsics.from_fov(fx, self.width, self.height)


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
    <quality shadowsize="{SHADOW_MAP_PX}" offsamples="{c.multisamples}"/>
    <headlight ambient=".35 .35 .35" diffuse=".4 .4 .4" specular="0 0 0"/></visual>
  <asset>
    <texture name="arc_floor" type="2d" builtin="checker" rgb1=".32 .33 .35" rgb2=".26 .27 .29"
      width="512" height="512"/>
    <material name="arc_floor" texture="arc_floor" texrepeat="6 6" reflectance="{reflect}"/>
    <texture name="{_SPECKLE}" type="cube" builtin="flat" mark="random" random="{c.speckle_density}"
      rgb1=".88 .88 .85" markrgb=".08 .08 .08" width="{c.speckle_texels}" height="{c.speckle_texels}"/>
    <material name="{_SPECKLE}" texture="{_SPECKLE}" specular=".2" shininess=".2"/>
    <texture name="{SEAMS}" type="cube" builtin="flat" mark="edge" rgb1=".9 .9 .88" markrgb=".3 .3 .3"
      width="64" height="64"/>
    <material name="{SEAMS}" texture="{SEAMS}" specular=".3" shininess=".3"/>
    <texture name="{SCREWS}" type="cube" builtin="flat" mark="random" random="0.003" rgb1=".9 .9 .88"
      markrgb=".12 .12 .12" width="128" height="128"/>
    <material name="{SCREWS}" texture="{SCREWS}" specular=".3" shininess=".3"/>
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


class Scene:
    """A compiled MuJoCo scene with one robot and one camera.

    Attributes:
        config: how it was built.
        model: the compiled scene (robot, floor, camera mount, obstacles, lights; under the realistic
            appearance also the labels and cables, ``marks``).
        data: its state; ``robot`` poses the arm in it.
        robot: the robot in this scene (kinematics, limits, surface points), sharing ``data``.
        T_camera_base: (4, 4) the true camera pose (``set_camera``): simulation only.
        marks: what the realistic appearance added (None under the other appearances): simulation only.

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
        robot = robot_spec(source)
        for geom in robot.geoms:  # hidden either way; MARK_GROUP, which the scene draws, is for the marks
            if geom.group == MARK_GROUP:
                geom.group = MARK_GROUP - 1
        spec = mujoco.MjSpec.from_string(_world_xml(self.config))
        attach_robot(spec, robot, source)
        if self.config.marker_board is not None:
            add_marker_board(spec, self.config.marker_board)
        self._clutter = plan_clutter(self.config.background_seed) if self.config.background == "lab" else ()
        add_clutter(spec, self._clutter)
        self.model = compile_spec(spec, source)
        self.marks: Marks | None = None
        if self.config.appearance == "realistic":  # placed on the compiled robot, then compiled in
            unmarked = self.model
            self.marks = plan_marks(RobotModel(unmarked, source), self.config.appearance_seed)
            add_marks(spec, unmarked, self.marks)
            self.model = compile_spec(spec, source)
            dress(self.model, unmarked, self.marks)
        m = self.model
        self.data = mujoco.MjData(m)
        self.robot = RobotModel(m, source, self.data)
        self._set_up_robot_geoms()
        if self.config.marker_board is not None:
            restore_board_material(m)  # the speckle paint is for the robot, not the board
        self.camera_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME)
        self.mount_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, MOUNT_BODY)
        self._clutter_bodies = clutter_bodies(m, len(self._clutter))
        self.T_camera_base = np.eye(4)
        self._renderers: dict[int, mujoco.Renderer] = {}  # by downscale factor
        self._scene_option = mujoco.MjvOption()
        for g in range(3, 6):  # collision geoms live in group 3 by convention; the marks in MARK_GROUP
            self._scene_option.geomgroup[g] = int(g == MARK_GROUP)
        self.robot.set_q(self.robot.home)

    def _set_up_robot_geoms(self) -> None:
        """Paint the robot's drawn geoms (``RobotModel.rendered_geoms``) under the painted appearance.

        (The realistic appearance's seams and screws are put on by ``arc_env.sim.marks.dress``.)
        """
        m = self.model
        if self.config.appearance == "painted":
            m.geom_matid[self.robot.rendered_geoms()] = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_MATERIAL, _SPECKLE)

    # -- camera --------------------------------------------------------------------------------
    @functools.cached_property
    def intrinsics(self) -> CameraIntrinsics:
        """The rendered camera's intrinsics (built once: the config is frozen)."""
        return self.config.intrinsics

    def set_camera(self, T_camera_base: FloatArray) -> None:
        """Place the camera (and its mount) so that ``p_camera = T_camera_base @ p_base``."""
        T_camera_base = check_transform(T_camera_base, "T_camera_base")
        if self._clutter:  # behind the robot as this camera sees it
            T_world_camera = self.robot.T_world_base @ np.linalg.inv(T_camera_base)
            place_clutter(self.model, self._clutter_bodies, self._clutter, self.robot.T_world_base[:2, 3],
                          T_world_camera[:2, 3])
        self._place_mount(T_camera_base)
        self.T_camera_base = T_camera_base.copy()

    def _place_mount(self, T_camera_base: FloatArray) -> None:
        """Move the camera mount body to where ``T_camera_base`` puts the camera; update ``data``."""
        T_world_camera = self.robot.T_world_base @ np.linalg.inv(T_camera_base)
        self.model.body_pos[self.mount_body], self.model.body_quat[self.mount_body] = \
            mujoco_camera_from_optical(T_world_camera)
        self.robot.forward()

    def project_points(self, body: NDArray[np.int64], local: FloatArray, min_depth: float,
                       margin_px: float = 0.0) -> tuple[FloatArray, MaskArray]:
        """The robot's body-fixed points (P,), (P, 3) m at the current state, seen by the true camera.

        Returns pixels (P, 2) and visible (P,) as ``RobotModel.project_points``.
        """
        return self.robot.project_points(body, local, self.T_camera_base, self.intrinsics, min_depth, margin_px)

    def surface_point_at(self, pixel: FloatArray) -> tuple[int, FloatArray] | None:
        """What of the robot the true camera sees at ``pixel`` (2,) px in the current state (simulation's truth).

        Casts the pixel's ray (``mujoco.mj_ray``) against the geoms the camera draws, from the camera
        centre and past its mount. Returns (body id, (3,) m the hit point in that body's frame), or None
        when the ray meets no robot geom.
        """
        K_inv = np.linalg.inv(self.intrinsics.K)
        T_world_camera = self.robot.T_world_base @ np.linalg.inv(self.T_camera_base)
        ray = T_world_camera[:3, :3] @ (K_inv @ np.array([pixel[0], pixel[1], 1.0]))
        ray /= np.linalg.norm(ray)
        start = T_world_camera[:3, 3]
        groups = np.array(self._scene_option.geomgroup, dtype=np.uint8)  # the groups the camera draws
        geom = np.array([-1], dtype=np.int32)
        distance = mujoco.mj_ray(self.model, self.data, start, ray, groups, 1, self.mount_body, geom)
        if geom[0] < 0 or self.model.geom_bodyid[geom[0]] not in self.robot.robot_bodies:
            return None
        body = int(self.model.geom_bodyid[geom[0]])
        hit = start + distance * ray
        return body, self.data.xmat[body].reshape(3, 3).T @ (hit - self.data.xpos[body])

    # -- rendering -----------------------------------------------------------------------------
    @property
    def renderer(self) -> mujoco.Renderer:
        """The full-resolution offscreen renderer (created on first use)."""
        return self._renderer(1)

    def _renderer(self, downscale: int) -> mujoco.Renderer:
        if downscale not in self._renderers:
            h, w = max(1, self.config.height // downscale), max(1, self.config.width // downscale)
            self._renderers[downscale] = create_renderer(self.model, h, w)
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
            self.robot.forward()
        r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = int(self.config.shadows)
        r.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = int(self.config.reflections)
        return r

    def render(self, downscale: int = 1) -> ImageArray:
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

    def render_sweep(self, q: FloatArray, joint: int, deltas: FloatArray, joint_speed: float = 1.0,
                     rng: np.random.Generator | None = None) -> list[ImageArray]:
        """Frames of joint ``joint`` turned by each of deltas (F,) rad from q (n,) rad, through the camera.

        With ``config.effects``: each frame is the mean of renders over its exposure (the joint turning
        at ``joint_speed`` rad/s), then gain drift, noise and lossy video are applied with ``rng`` (needed
        when the effects draw random numbers). The arm is left at the last frame's configuration.
        """
        effects = self.config.effects
        offsets = effects.exposure_offsets(joint_speed) * (1.0 if deltas[-1] >= deltas[0] else -1.0)
        frames = []
        for d in deltas:
            if len(offsets) == 1:
                self.robot.set_swept(q, joint, d)
                frames.append(self.render())
                continue
            total = np.zeros((self.config.height, self.config.width, 3), np.float32)
            for offset in offsets:
                self.robot.set_swept(q, joint, d + offset)
                total += self.render()
            frames.append(np.clip(np.rint(total / len(offsets)), 0, 255).astype(np.uint8))
        self.robot.set_swept(q, joint, deltas[-1])
        if effects.active:
            if rng is None:
                raise InvalidInputError("camera effects need a random generator (render_sweep(..., rng=...))")
            frames = effects.apply(frames, rng)
        return frames

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

    def robot_mask(self, T_camera_base: FloatArray | None = None) -> MaskArray:
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
        robot_geom[:-1] = np.isin(self.model.geom_bodyid, self.robot.robot_bodies)
        return is_geom & robot_geom[np.where(geom_ids >= 0, geom_ids, self.model.ngeom)]

    def close(self) -> None:
        """Free the renderers' GL contexts."""
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()


class SceneRenderer:
    """What a planner may render of a scene (``planners.context.SceneRenderer``): images at a configuration.

    The true camera renders the image test's thumbnails, as a real robot's camera would take two
    snapshots; depth images are rendered from a given pose (an estimate). The scene itself, and with
    it the true camera pose, stays private.

    Args:
        scene: the scene to render.
    """

    def __init__(self, scene: Scene):
        self._scene = scene

    def _rendered(self) -> Scene:
        """The scene to render (a subclass may build it on demand)."""
        return self._scene

    def render_at(self, q: FloatArray, downscale: int = 1) -> ImageArray:
        """The camera's image with the arm at q (n,) rad; see ``Scene.render``. The arm stays at q."""
        scene = self._rendered()
        scene.robot.set_q(q)
        return scene.render(downscale)

    def depth_at(self, q: FloatArray, T_camera_base: FloatArray, downscale: int = 1) -> NDArray[np.float32]:
        """Depth image with the arm at q (n,) rad seen from ``T_camera_base``; see ``Scene.depth``."""
        scene = self._rendered()
        scene.robot.set_q(q)
        return scene.depth(T_camera_base, downscale)

    def prepare(self, downscale: int) -> None:
        """Create the renderer for ``downscale`` now (about 1 s of GL set-up), so no planning call pays for it."""
        self._rendered().render(downscale)
