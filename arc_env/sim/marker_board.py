"""A ChArUco board fixed to the robot's flange, for the marker-based hand-eye baseline.

``MarkerBoard`` says what the board is (OpenCV's ``cv2.aruco.CharucoBoard``: squares, sizes,
dictionary) and where it is mounted; ``add_marker_board`` adds it to a scene's ``MjSpec`` as a body
fixed to the mount body with two geoms: a thin box that renders the board image on its front face
(visual only) and the same box as collision geometry (so the planners' collision checker sees it).

Board frame: the frame of OpenCV's board object points (``CharucoBoard.getChessboardCorners``):
origin at the outer corner of the first square, x along the ``squares[0]`` columns, y along the
``squares[1]`` rows (image right and down in ``MarkerBoard.image()``), z = x cross y, into the
board. The printed face is the board's z = 0 plane and faces -z. The MuJoCo body
``BOARD_BODY`` has exactly this frame, so ``solvePnP`` on a rendered image returns the pose of
that body (``tests/arc_env/test_marker_baseline.py`` checks it).

The board body hangs under the robot's base body, so ``Scene.robot_mask`` counts it as robot and the
collision checker checks it against the other links, the floor and the camera mount (not against
the hand it is fixed to). Mask studies use the scene without the board.

Texture mapping (measured, MuJoCo 3.x/4.x): a 2-D texture on a box is projected along the box's
local z and spans the face once (``texrepeat = 1, 1``); MuJoCo's texture rows run bottom-up, so the
image is flipped vertically before it is handed over.

Default board, chosen by measured detection range rather than by habit: 4 x 6 squares of 40 mm
(0.16 x 0.24 m, an A4-sized board) with 30 mm DICT_4X4_50 markers. At 1920x1080 (fx = 1380 px) it
is detected at every tilt up to 50 degrees out to 2.1 m; a 5 x 7 board of 22 mm squares with
DICT_5X5 markers (a common desk board) was lost beyond 1.2 m, and the scene's cameras stand
1-2.5 m from the workspace. At 960x540 the default board is detected to about 1.2-1.5 m.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from solver.arrays import FloatArray
from solver.errors import InvalidInputError
from solver.frames import transform_from_rt

#: The board's body (its frame is OpenCV's board frame, see the module doc).
BOARD_BODY = "arc_marker_board"
#: The visual geom showing the board image.
BOARD_GEOM = "arc_marker_board"
#: The collision geom (same box, group 3).
BOARD_COLLISION_GEOM = "arc_marker_board_collision"
_BOARD_MATERIAL = "arc_marker_board"


@dataclass(frozen=True)
class MarkerBoard:
    """A ChArUco board and how it is fixed to the robot.

    Attributes:
        squares: (columns, rows) of chessboard squares.
        square_m: side of a square, m.
        marker_m: side of an ArUco marker, m (< square_m).
        dictionary: name of an OpenCV predefined dictionary, e.g. "DICT_4X4_50".
        mount_body: the body the board is fixed to (the Panda's flange and hand: "panda0_link7").
        standoff_m: m; the printed face lies this far along the mount body's +z, facing +z (for the
            Panda hand: just beyond the fingertips, as if the gripper held the board).
        thickness_m: board thickness, m.
        texels_per_square: texture resolution.
    """

    squares: tuple[int, int] = (4, 6)
    square_m: float = 0.04
    marker_m: float = 0.03
    dictionary: str = "DICT_4X4_50"
    mount_body: str = "panda0_link7"
    standoff_m: float = 0.29
    thickness_m: float = 0.004
    texels_per_square: int = 64

    def __post_init__(self) -> None:
        if min(self.squares) < 2:
            raise InvalidInputError(f"a ChArUco board needs at least 2 x 2 squares, got {self.squares}")
        if not 0 < self.marker_m < self.square_m:
            raise InvalidInputError(f"need 0 < marker_m < square_m, got {self.marker_m}, {self.square_m}")
        if not hasattr(cv2.aruco, self.dictionary) or not self.dictionary.startswith("DICT_"):
            names = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
            raise InvalidInputError(f"unknown ArUco dictionary {self.dictionary!r}; valid: {names}")
        if self.thickness_m <= 0 or self.texels_per_square < 8:
            raise InvalidInputError("thickness_m must be > 0 and texels_per_square >= 8")

    @property
    def size_m(self) -> tuple[float, float]:
        """Board width and height, m (along the board's x and y)."""
        return self.squares[0] * self.square_m, self.squares[1] * self.square_m

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board (a new object each call)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, dictionary)

    def image(self) -> NDArray[np.uint8]:
        """The printed board, (rows * texels, columns * texels) uint8 grey, no margin."""
        t = self.texels_per_square
        return self.cv_board().generateImage((self.squares[0] * t, self.squares[1] * t), marginSize=0)

    @property
    def T_mount_board(self) -> FloatArray:
        """The board frame in the mount body's frame, (4, 4): the face centred on the body's z axis.

        The board's z (into the board) is the mount's -z, so the printed face looks along the mount's
        +z; x is the mount's x and y is the mount's -y.
        """
        w, h = self.size_m
        R = np.diag([1.0, -1.0, -1.0])
        return transform_from_rt(R, np.array([-w / 2, h / 2, self.standoff_m]))


def add_marker_board(spec: mujoco.MjSpec, board: MarkerBoard) -> None:
    """Add the board (texture, material, body, visual and collision geoms) to a scene spec.

    Raises:
        InvalidInputError: the spec has no body named ``board.mount_body`` (the message lists them).
    """
    mount = spec.body(board.mount_body)
    if mount is None:
        names = [b.name for b in spec.bodies if b.name]
        raise InvalidInputError(f"marker board: no mount body {board.mount_body!r}; bodies: {names}")
    image = board.image()
    texture = spec.add_texture(name=_BOARD_MATERIAL, type=mujoco.mjtTexture.mjTEXTURE_2D,
                               width=image.shape[1], height=image.shape[0], nchannel=3)
    texture.data = np.repeat(np.flipud(image)[:, :, None], 3, axis=2).tobytes()  # MuJoCo rows run bottom-up
    material = spec.add_material(name=_BOARD_MATERIAL)
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = _BOARD_MATERIAL
    material.specular, material.shininess = 0.1, 0.1
    T_mount_board = board.T_mount_board
    x, y, z, w = Rotation.from_matrix(T_mount_board[:3, :3]).as_quat()
    body = mount.add_body(name=BOARD_BODY, pos=T_mount_board[:3, 3], quat=[w, x, y, z])
    half = [board.size_m[0] / 2, board.size_m[1] / 2, board.thickness_m / 2]
    centre = half  # the box spans [0, w] x [0, h] x [0, thickness] in the board frame
    body.add_geom(name=BOARD_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=centre,
                  material=_BOARD_MATERIAL, contype=0, conaffinity=0, group=0)
    body.add_geom(name=BOARD_COLLISION_GEOM, type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=centre,
                  contype=1, conaffinity=1, group=3)


def restore_board_material(model: mujoco.MjModel) -> None:
    """Give the board's visual geom its own material back (the scene paints every robot geom)."""
    geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, BOARD_GEOM)
    model.geom_matid[geom] = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, _BOARD_MATERIAL)
