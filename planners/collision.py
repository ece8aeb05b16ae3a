"""Collision checking of arm configurations against a MuJoCo scene, with python-fcl.

``CollisionChecker`` reads a MuJoCo model's collision geometry once, places it with MuJoCo's own
forward kinematics (``mj_kinematics`` on a private ``MjData``) and asks fcl whether any checked
pair of geoms intersects. Three queries:

* ``in_collision(q)``: one arm configuration;
* ``sweep_free(q, joint, delta)``: one joint turning by ``delta``, the exploratory motion of ARC-Calib;
* ``path_free(q_from, q_to)``: a straight joint-space segment, the motion validator of a planner.

Geometry (MuJoCo geom type -> fcl shape):

* sphere, capsule, cylinder, box, ellipsoid -> the exact fcl primitive (MuJoCo sizes are radii and
  half-lengths, fcl takes full lengths);
* mesh -> ``fcl.Convex`` of the mesh's convex hull. MuJoCo collides every mesh as its convex hull,
  so the hull reproduces MuJoCo's contacts; a BVH of the triangles would instead find only surface
  crossings and miss a primitive wholly inside a mesh;
* plane -> ``fcl.Halfspace`` (the solid below the plane; MuJoCo planes are infinite for collision);
* hfield and sdf geoms, and geoms with a zero size or a degenerate mesh, are skipped and listed in
  ``CollisionChecker.skipped_geoms``.

Which pairs are checked (MuJoCo's rules, with the differences marked):

* both geoms collide in MuJoCo's sense (``contype`` or ``conaffinity`` nonzero) and pass its bit rule
  ``(contype1 & conaffinity2) or (contype2 & conaffinity1)``; explicit ``<pair>`` entries pass
  whatever their bits, as in MuJoCo, but (unlike MuJoCo) still go through the filters below;
* not excluded by ``<exclude>`` (``model.exclude_signature``) nor by ``ignore_pairs``;
* not adjacent links: bodies whose weld groups (bodies welded together by having no joint) are
  parent and child. MuJoCo never treats the world group as a parent; we do not either (the floor
  and fixed obstacles stay checked against the first link) except that a moving link's own parent
  body is always filtered, so a robot base welded to the world is not reported against link 1
  (MuJoCo would check that pair);
* the pair's relative pose can change with the arm: geoms moved by the same set of arm joints are
  rigid with respect to each other (same body, both static, both on the hand...), so their contact
  cannot depend on q and the pair is dropped. Pairs of this kind that touch at ``qpos_ref`` are
  listed in ``CollisionChecker.constant_contacts`` for information.

``margin`` > 0 also reports pairs closer than ``margin``: planes become a halfspace raised by the
margin and other pairs use ``fcl.distance`` (python-fcl's distance with a halfspace crashes, so it
is never called on one). MuJoCo's own per-geom ``geom_margin`` is not used.

Speed: every query runs ``mj_kinematics``, prunes the precomputed pair list with a vectorised
bounding-sphere test (a height test for planes) and calls ``fcl.collide`` on the survivors only,
placing those geoms lazily. On a Panda (47 geoms, 243 checked pairs) that is 45-80 us per
configuration; an fcl ``DynamicAABBTreeCollisionManager`` took about 300 us for the tree update and
its Python callbacks alone, before any narrow phase. One checker owns one ``MjData``: it is not
thread-safe; give each thread its own checker.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import fcl
import mujoco
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull, QhullError

from solver.arrays import FloatArray
from solver.errors import InvalidInputError

__all__ = ["CollisionChecker"]

_MOVABLE_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
_G = mujoco.mjtGeom


@dataclass(frozen=True)
class _Geom:
    """One collision geom as fcl sees it."""

    geom_id: int
    obj: fcl.CollisionObject
    rbound: float  # metres: bounding-sphere radius about the geom origin (inf for planes)
    is_plane: bool
    label: str


def _fractions(n_steps: int) -> FloatArray:
    """Path fractions 0 .. 1 of n_steps equal steps, both ends included (just the ends when 0)."""
    return np.linspace(0.0, 1.0, max(n_steps, 1) + 1)


def _name(model: mujoco.MjModel, obj: mujoco.mjtObj, idx: int) -> str:
    return mujoco.mj_id2name(model, obj, idx) or f"#{idx}"


def _geom_label(model: mujoco.MjModel, geom_id: int) -> str:
    body = int(model.geom_bodyid[geom_id])
    geom = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom_id)
    geom_text = f"geom '{geom}'" if geom else f"geom #{geom_id}"
    return f"body '{_name(model, mujoco.mjtObj.mjOBJ_BODY, body)}' ({geom_text})"


def _convex_from_mesh(model: mujoco.MjModel, mesh_id: int) -> tuple[fcl.Convex, float, list] | str:
    """The convex hull of a mesh as fcl.Convex, its bounding radius, and the arrays fcl points into."""
    adr, num = int(model.mesh_vertadr[mesh_id]), int(model.mesh_vertnum[mesh_id])
    verts = np.asarray(model.mesh_vert[adr : adr + num], dtype=np.float64)
    if num < 4:
        return f"mesh has {num} vertices"
    try:
        hull = ConvexHull(verts)
    except QhullError:
        try:  # flat or otherwise degenerate: joggle to a thin hull
            hull = ConvexHull(verts, qhull_options="QJ")
        except QhullError as err:
            return f"no convex hull ({err.__class__.__name__})"
    used = np.unique(hull.simplices)
    remap = np.full(num, -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    hull_verts = np.ascontiguousarray(verts[used])
    tris = remap[hull.simplices]
    # Orient every triangle outwards (qhull's order is arbitrary); fcl derives face normals from it.
    centroid = hull_verts.mean(axis=0)
    a, b, c = hull_verts[tris[:, 0]], hull_verts[tris[:, 1]], hull_verts[tris[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a - centroid) < 0
    tris[inward] = tris[inward][:, [0, 2, 1]]
    faces = np.ascontiguousarray(np.hstack([np.full((len(tris), 1), 3), tris]).ravel(), dtype=np.int64)
    rbound = float(np.linalg.norm(hull_verts, axis=1).max())
    # python-fcl keeps pointers into these arrays: the caller must keep them alive.
    return fcl.Convex(hull_verts, len(tris), faces), rbound, [hull_verts, faces]


def _shape(model: mujoco.MjModel, geom_id: int, margin: float) -> tuple[object, float, list] | str:
    """The fcl shape, bounding radius and kept-alive arrays of one geom, or the reason it is skipped."""
    gtype = int(model.geom_type[geom_id])
    size = np.asarray(model.geom_size[geom_id], dtype=np.float64)
    if gtype == int(_G.mjGEOM_PLANE):
        return fcl.Halfspace(np.array([0.0, 0.0, 1.0]), margin), math.inf, []
    if gtype == int(_G.mjGEOM_MESH):
        mesh_id = int(model.geom_dataid[geom_id])
        if mesh_id < 0:
            return "mesh geom without a mesh"
        return _convex_from_mesh(model, mesh_id)
    used = {int(_G.mjGEOM_SPHERE): 1, int(_G.mjGEOM_CAPSULE): 2, int(_G.mjGEOM_CYLINDER): 2}
    used |= {int(_G.mjGEOM_ELLIPSOID): 3, int(_G.mjGEOM_BOX): 3}
    if gtype not in used:
        return f"geom type {mujoco.mjtGeom(gtype).name} is not supported"
    if np.any(size[: used[gtype]] <= 0.0):
        return f"zero size {size[: used[gtype]].tolist()}"
    r, h = size[0], size[1]
    if gtype == int(_G.mjGEOM_SPHERE):
        return fcl.Sphere(r), r, []
    if gtype == int(_G.mjGEOM_CAPSULE):
        return fcl.Capsule(r, 2.0 * h), r + h, []
    if gtype == int(_G.mjGEOM_CYLINDER):
        return fcl.Cylinder(r, 2.0 * h), math.hypot(r, h), []
    if gtype == int(_G.mjGEOM_ELLIPSOID):
        return fcl.Ellipsoid(*size), float(size.max()), []
    return fcl.Box(*(2.0 * size)), float(np.linalg.norm(size)), []


class CollisionChecker:
    """Collision queries of an arm in a MuJoCo scene (see the module docstring for the rules).

    Attributes:
        model: the MuJoCo model (not modified).
        arm_joints: (n_arm,) MuJoCo joint ids; q vectors follow this order.
        qpos_ref: (nq,) float64: the full qpos every non-arm joint keeps.
        margin: metres; pairs closer than this count as colliding.
        pairs: (P, 2) int: the geom id pairs that are checked.
        skipped_geoms: geom label -> why it has no fcl shape.
        constant_contacts: labels of dropped rigid pairs that touch at ``qpos_ref``.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        arm_joints: Sequence[int],
        *,
        qpos_ref: FloatArray | None = None,
        margin: float = 0.0,
        ignore_pairs: Sequence[tuple[str, str]] = (),
    ) -> None:
        """Build the fcl geometry and the list of checked pairs.

        Args:
            model: a compiled MuJoCo model.
            arm_joints: MuJoCo ids of the arm's hinge or slide joints, in the order of q.
            qpos_ref: (nq,) float64: full qpos for all other joints; ``model.qpos0`` when None.
            margin: metres, >= 0: clearance below which a pair counts as colliding.
            ignore_pairs: (body name, body name) pairs never to check.

        Raises:
            InvalidInputError: a joint id is out of range, repeated or not a hinge/slide joint, a
                body name is unknown, or qpos_ref / margin is malformed.
        """
        self.model = model
        self.arm_joints = self._check_joints(model, arm_joints)
        self.qpos_ref = self._check_qpos_ref(model, qpos_ref)
        margin = float(margin)
        if not math.isfinite(margin) or margin < 0.0:
            raise InvalidInputError(f"margin must be a finite number >= 0 metres, got {margin}")
        self.margin = margin
        self._data = mujoco.MjData(model)
        self._request = fcl.CollisionRequest()
        self._qadr = model.jnt_qposadr[self.arm_joints].astype(np.int64)
        self._is_slide = model.jnt_type[self.arm_joints] == int(mujoco.mjtJoint.mjJNT_SLIDE)
        n_arm = len(self.arm_joints)

        # Which arm joints move each body: moves[b, a] is True when arm joint a is an ancestor of b.
        joint_body = model.jnt_bodyid[self.arm_joints]
        moves = np.zeros((model.nbody, n_arm), dtype=bool)
        for b in range(1, model.nbody):
            moves[b] = moves[model.body_parentid[b]] | (joint_body == b)
        self._body_moves = moves

        self.skipped_geoms: dict[str, str] = {}
        self._geoms: dict[int, _Geom] = {}
        self._keepalive: list = []
        for g in range(model.ngeom):
            if model.geom_contype[g] == 0 and model.geom_conaffinity[g] == 0:
                continue
            built = _shape(model, g, margin)
            if isinstance(built, str):
                self.skipped_geoms[_geom_label(model, g)] = built
                continue
            shape, rbound, arrays = built
            is_plane = int(model.geom_type[g]) == int(_G.mjGEOM_PLANE)
            if is_plane and moves[model.geom_bodyid[g]].any():
                self.skipped_geoms[_geom_label(model, g)] = "plane moved by the arm (infinite extent)"
                continue
            self._keepalive.extend([shape, *arrays])
            self._geoms[g] = _Geom(
                g, fcl.CollisionObject(shape, fcl.Transform()), rbound, is_plane, _geom_label(model, g)
            )
        if self.skipped_geoms:
            notes = "; ".join(f"{k}: {v}" for k, v in self.skipped_geoms.items())
            warnings.warn(f"CollisionChecker skips {len(self.skipped_geoms)} geom(s): {notes}", stacklevel=2)

        ignored = self._check_ignore_pairs(model, ignore_pairs)
        pairs, constant = self._select_pairs(model, ignored)
        self.pairs = np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)
        self._split_pairs()
        self._geom_moves = {g: moves[model.geom_bodyid[g]] for g in self._geoms}
        self._build_reach()

        self._set_qpos(self.qpos_ref[self._qadr])
        self.constant_contacts = [
            f"{self._geoms[a].label} and {self._geoms[b].label}"
            for a, b in sorted(constant)
            if self._near(a, b) and self._collide(a, b)
        ]

    # ----------------------------------------------------------------------------------------------
    # construction helpers

    @staticmethod
    def _check_joints(model: mujoco.MjModel, arm_joints: Sequence[int]) -> NDArray[np.int64]:
        joints = np.asarray(arm_joints)
        if joints.ndim != 1 or joints.size == 0 or not np.issubdtype(joints.dtype, np.integer):
            raise InvalidInputError(f"arm_joints must be a non-empty sequence of joint ids, got {arm_joints!r}")
        joints = joints.astype(np.int64)
        if np.any((joints < 0) | (joints >= model.njnt)):
            raise InvalidInputError(f"arm_joints {joints.tolist()} out of range: the model has {model.njnt} joints")
        if len(set(joints.tolist())) != joints.size:
            raise InvalidInputError(f"arm_joints must not repeat a joint, got {joints.tolist()}")
        for j in joints:
            if int(model.jnt_type[j]) not in _MOVABLE_JOINTS:
                kind = mujoco.mjtJoint(int(model.jnt_type[j])).name
                name = _name(model, mujoco.mjtObj.mjOBJ_JOINT, int(j))
                raise InvalidInputError(
                    f"arm joint {int(j)} ('{name}') is {kind}; only hinge and slide joints are arm joints"
                )
        return joints

    @staticmethod
    def _check_qpos_ref(model: mujoco.MjModel, qpos_ref: FloatArray | None) -> FloatArray:
        if qpos_ref is None:
            return np.array(model.qpos0, dtype=np.float64)
        qpos = np.array(qpos_ref, dtype=np.float64)
        if qpos.shape != (model.nq,) or not np.all(np.isfinite(qpos)):
            raise InvalidInputError(f"qpos_ref must be a finite (nq,) = ({model.nq},) array, got shape {qpos.shape}")
        return qpos

    @staticmethod
    def _check_ignore_pairs(model: mujoco.MjModel, ignore_pairs: Sequence[tuple[str, str]]) -> set[tuple[int, int]]:
        names = [_name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(model.nbody)]
        ignored = set()
        for pair in ignore_pairs:
            if len(pair) != 2:
                raise InvalidInputError(f"ignore_pairs entries must be (body, body) name pairs, got {pair!r}")
            ids = []
            for body in pair:
                b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
                if b < 0:
                    raise InvalidInputError(f"ignore_pairs: unknown body {body!r}; bodies are {names}")
                ids.append(b)
            ignored.add((min(ids), max(ids)))
        return ignored

    def _select_pairs(
        self, model: mujoco.MjModel, ignored: set[tuple[int, int]]
    ) -> tuple[set[tuple[int, int]], set[tuple[int, int]]]:
        """Checked geom pairs, and the rigid pairs dropped because q cannot change them."""
        excluded = {int(s) for s in model.exclude_signature}
        weld, parent = model.body_weldid, model.body_parentid
        explicit = {(min(a, b), max(a, b)) for a, b in zip(model.pair_geom1, model.pair_geom2, strict=True)}
        ids = sorted(self._geoms)
        pairs, constant = set(), set()
        for i, g1 in enumerate(ids):
            for g2 in ids[i + 1 :]:
                b1, b2 = int(model.geom_bodyid[g1]), int(model.geom_bodyid[g2])
                bits = (model.geom_contype[g1] & model.geom_conaffinity[g2]) or (
                    model.geom_contype[g2] & model.geom_conaffinity[g1]
                )
                if not bits and (g1, g2) not in explicit:
                    continue
                if ((b1 << 16) + b2) in excluded or ((b2 << 16) + b1) in excluded:
                    continue
                if (min(b1, b2), max(b1, b2)) in ignored:
                    continue
                w1, w2 = int(weld[b1]), int(weld[b2])
                if (w1 and w1 == weld[parent[w2]]) or (w2 and w2 == weld[parent[w1]]):
                    continue  # adjacent links (MuJoCo's parent filter, world excepted)
                if (w2 and parent[w2] == b1 and b1) or (w1 and parent[w1] == b2 and b2):
                    continue  # a link and the body it hangs from, also when that one is static
                if np.array_equal(self._body_moves[b1], self._body_moves[b2]):
                    constant.add((g1, g2))
                    continue
                pairs.add((g1, g2))
        return pairs, constant

    def _split_pairs(self) -> None:
        """Arrays for the bounding-sphere prefilter: sphere-sphere pairs and plane-geom pairs."""
        planes = np.array([self._geoms[a].is_plane or self._geoms[b].is_plane for a, b in self.pairs], dtype=bool)
        solid = self.pairs[~planes]
        self._sp_a, self._sp_b = solid[:, 0], solid[:, 1]
        self._sp_reach = np.array(
            [self._geoms[a].rbound + self._geoms[b].rbound + self.margin for a, b in solid], dtype=np.float64
        )
        plane_pairs = [(a, b) if self._geoms[a].is_plane else (b, a) for a, b in self.pairs[planes]]
        pp = np.array(plane_pairs, dtype=np.int64).reshape(-1, 2)
        self._pl_plane, self._pl_geom = pp[:, 0], pp[:, 1]
        self._pl_reach = np.array([self._geoms[g].rbound + self.margin for g in self._pl_geom], dtype=np.float64)

    def _build_reach(self) -> None:
        """Configuration-free reach bounds of each arm joint for ``path_free``, at qpos_ref.

        For arm joint a and a geom g it moves, |p - anchor_a| for any point p of g is at most the
        sum of anchor-to-anchor distances along g's chain of arm joints, plus |x_g - anchor_last|
        plus g's bounding radius. Hinge motion keeps each of those distances; a slide joint k
        further down the chain adds at most |q_k - q_ref_k|, added per query.
        """
        n_arm = len(self.arm_joints)
        self._set_qpos(self.qpos_ref[self._qadr])
        anchor = np.array(self._data.xanchor[self.arm_joints])
        depth = np.array([self._body_depth(int(b)) for b in self.model.jnt_bodyid[self.arm_joints]])
        moving = [g for g, m in self._geom_moves.items() if m.any()]
        base = np.full((n_arm, len(moving)), -np.inf)
        slides_below = np.zeros((n_arm, len(moving), n_arm))
        for col, g in enumerate(moving):
            chain = sorted(np.flatnonzero(self._geom_moves[g]), key=lambda a: (depth[a], a))
            x_g = self._data.geom_xpos[g]
            for pos, a in enumerate(chain):
                below = chain[pos:]
                length = sum(np.linalg.norm(anchor[k2] - anchor[k1]) for k1, k2 in zip(below, below[1:], strict=False))
                base[a, col] = length + np.linalg.norm(x_g - anchor[below[-1]]) + self._geoms[g].rbound
                for k in below[1:]:
                    slides_below[a, col, k] = float(self._is_slide[k])
        self._reach_base, self._reach_slides = base, slides_below

    def _body_depth(self, body: int) -> int:
        depth = 0
        while body:
            body = int(self.model.body_parentid[body])
            depth += 1
        return depth

    # ----------------------------------------------------------------------------------------------
    # core

    def _set_qpos(self, q: FloatArray) -> None:
        self._data.qpos[:] = self.qpos_ref
        self._data.qpos[self._qadr] = q
        mujoco.mj_kinematics(self.model, self._data)

    def _place(self, g: int) -> fcl.CollisionObject:
        obj = self._geoms[g].obj
        obj.setTransform(fcl.Transform(self._data.geom_xmat[g].reshape(3, 3), self._data.geom_xpos[g]))
        return obj

    def _collide(self, a: int, b: int) -> bool:
        """Whether geoms a and b (placed from the current MjData) intersect or are within margin."""
        oa, ob = self._place(a), self._place(b)
        if fcl.collide(oa, ob, self._request, fcl.CollisionResult()) > 0:
            return True
        if self.margin == 0.0 or self._geoms[a].is_plane or self._geoms[b].is_plane:
            return False  # planes carry the margin in their halfspace offset
        return fcl.distance(oa, ob, fcl.DistanceRequest(), fcl.DistanceResult()) < self.margin

    def _near(self, a: int, b: int) -> bool:
        """Bounding-sphere (or plane height) test of one pair at the current MjData."""
        ga, gb = self._geoms[a], self._geoms[b]
        if ga.is_plane and gb.is_plane:
            return False
        if ga.is_plane or gb.is_plane:
            plane, other = (ga, gb) if ga.is_plane else (gb, ga)
            normal = self._data.geom_xmat[plane.geom_id][2::3]
            height = normal @ (self._data.geom_xpos[other.geom_id] - self._data.geom_xpos[plane.geom_id])
            return bool(height < other.rbound + self.margin)
        gap = np.linalg.norm(self._data.geom_xpos[a] - self._data.geom_xpos[b])
        return bool(gap < ga.rbound + gb.rbound + self.margin)

    def _first_collision(self) -> str:
        """Reason naming the first colliding pair at the current MjData, '' when none."""
        xpos = self._data.geom_xpos
        d = xpos[self._sp_a] - xpos[self._sp_b]
        near = np.einsum("ij,ij->i", d, d) < self._sp_reach**2
        for a, b in zip(self._sp_a[near], self._sp_b[near], strict=True):
            if self._collide(int(a), int(b)):
                return self._reason(int(a), int(b))
        if self._pl_plane.size:
            normal = self._data.geom_xmat[self._pl_plane][:, 2::3]  # plane z axis (column 2), world frame
            height = np.einsum("ij,ij->i", normal, xpos[self._pl_geom] - xpos[self._pl_plane])
            for p, g in zip(
                self._pl_plane[height < self._pl_reach], self._pl_geom[height < self._pl_reach], strict=True
            ):
                if self._collide(int(g), int(p)):
                    return self._reason(int(g), int(p))
        return ""

    def _reason(self, a: int, b: int) -> str:
        verb = "collides with" if self.margin == 0.0 else f"is within {self.margin:g} m of"
        return f"{self._geoms[a].label} {verb} {self._geoms[b].label}"

    def _check_q(self, q: FloatArray, name: str = "q") -> FloatArray:
        n_arm = len(self.arm_joints)
        arr = np.asarray(q, dtype=np.float64)
        if arr.shape != (n_arm,):
            raise InvalidInputError(f"{name} must have shape ({n_arm},) (one value per arm joint), got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InvalidInputError(f"{name} must be finite, got {arr.tolist()}")
        return arr

    @staticmethod
    def _check_step(max_step_m: float) -> float:
        step = float(max_step_m)
        if not math.isfinite(step) or step <= 0.0:
            raise InvalidInputError(f"max_step_m must be a finite number > 0 metres, got {max_step_m}")
        return step

    # ----------------------------------------------------------------------------------------------
    # public queries

    def in_collision(self, q: FloatArray) -> tuple[bool, str]:
        """Whether the arm collides at one configuration.

        Args:
            q: (n_arm,) float64, rad (metres for slide joints), in ``arm_joints`` order.

        Returns:
            (colliding, reason): reason names the two bodies and geoms of the first colliding pair
            found, '' when the configuration is free.

        Raises:
            InvalidInputError: q has the wrong shape or a non-finite value.
        """
        self._set_qpos(self._check_q(q))
        reason = self._first_collision()
        return bool(reason), reason

    def colliding_pairs(self, q: FloatArray) -> list[tuple[int, int]]:
        """Every checked pair that collides at one configuration (diagnostics; slower than in_collision).

        Args:
            q: (n_arm,) float64, rad (metres for slide joints), in ``arm_joints`` order.

        Returns:
            (geom id, geom id) pairs, each with the smaller id first, in increasing order.

        Raises:
            InvalidInputError: q has the wrong shape or a non-finite value.
        """
        self._set_qpos(self._check_q(q))
        return [(int(a), int(b)) for a, b in self.pairs if self._near(int(a), int(b)) and self._collide(int(a), int(b))]

    def sweep_samples(self, q: FloatArray, joint: int, delta: float, max_step_m: float = 0.005) -> FloatArray:
        """The configurations ``sweep_free`` checks, in order.

        Samples are spaced so that no point of a geom moved by the joint travels more than
        ``max_step_m`` between two of them: for a hinge the angular step is max_step_m divided by
        the largest distance of the moving geoms' bounding spheres from the joint axis (a distance
        the rotation itself keeps); for a slide joint the step is max_step_m. Both ends included.

        Args:
            q: (n_arm,) float64, rad: the start configuration.
            joint: 0-based index into ``arm_joints``.
            delta: rad (metres for a slide joint): signed motion of that joint.
            max_step_m: metres, > 0: largest travel of any moving point between samples.

        Returns:
            (K, n_arm) float64, rad: K >= 2 configurations from q to q + delta * e_joint.

        Raises:
            InvalidInputError: malformed q, joint index out of range, non-finite delta or step.
        """
        q0 = self._check_q(q)
        n_arm = len(self.arm_joints)
        if isinstance(joint, bool) or not isinstance(joint, int | np.integer) or not 0 <= joint < n_arm:
            raise InvalidInputError(f"joint must be an index in 0..{n_arm - 1} into arm_joints, got {joint!r}")
        delta = float(delta)
        if not math.isfinite(delta):
            raise InvalidInputError(f"delta must be finite, got {delta}")
        step_m = self._check_step(max_step_m)
        joint = int(joint)
        self._set_qpos(q0)
        reach = 1.0 if self._is_slide[joint] else self._axis_reach(joint)
        fractions = _fractions(math.ceil(abs(delta) * reach / step_m))
        samples = np.repeat(q0[None, :], len(fractions), axis=0)
        samples[:, joint] += fractions * delta
        return samples

    def sweep_free(self, q: FloatArray, joint: int, delta: float, max_step_m: float = 0.005) -> tuple[bool, str]:
        """Whether one joint can move from q[joint] to q[joint] + delta without collision.

        Checks the configurations of ``sweep_samples`` in order from the start, both ends included.

        Args:
            q: (n_arm,) float64, rad: the start configuration.
            joint: 0-based index into ``arm_joints``.
            delta: rad (metres for a slide joint): signed motion of that joint.
            max_step_m: metres, > 0: largest travel of any moving point between checks.

        Returns:
            (True, '') when free, else (False, reason) with the joint value and the colliding pair.

        Raises:
            InvalidInputError: malformed q, joint index out of range, non-finite delta or step.
        """
        samples = self.sweep_samples(q, joint, delta, max_step_m)
        unit = "m" if self._is_slide[int(joint)] else "rad"
        for i, qi in enumerate(samples):
            self._set_qpos(qi)
            reason = self._first_collision()
            if reason:
                where = f"joint {int(joint)} at {qi[int(joint)]:.4f} {unit} (sample {i}/{len(samples) - 1})"
                return False, f"{where}: {reason}"
        return True, ""

    def path_samples(self, q_from: FloatArray, q_to: FloatArray, max_step_m: float = 0.005) -> FloatArray:
        """The configurations ``path_free`` checks, in order.

        The segment is cut into N equal steps with sum_a |dq_a| * L_a <= max_step_m, where L_a
        bounds the distance from joint a's anchor of any point joint a moves, all along the
        segment (1 for slide joints; see ``_build_reach``), so no point moves further than
        max_step_m between two samples. Both ends included.

        Args:
            q_from: (n_arm,) float64, rad: start configuration.
            q_to: (n_arm,) float64, rad: end configuration.
            max_step_m: metres, > 0: largest travel of any moving point between samples.

        Returns:
            (K, n_arm) float64, rad: K >= 2 configurations from q_from to q_to.

        Raises:
            InvalidInputError: malformed q_from / q_to or step.
        """
        qa, qb = self._check_q(q_from, "q_from"), self._check_q(q_to, "q_to")
        step_m = self._check_step(max_step_m)
        fractions = _fractions(math.ceil(float(np.abs(qb - qa) @ self._reach(qa, qb)) / step_m))
        return qa + fractions[:, None] * (qb - qa)

    def path_free(self, q_from: FloatArray, q_to: FloatArray, max_step_m: float = 0.005) -> tuple[bool, str]:
        """Whether the straight joint-space segment q_from -> q_to is free, endpoints included.

        Checks the configurations of ``path_samples`` in order from q_from.

        Args:
            q_from: (n_arm,) float64, rad: start configuration.
            q_to: (n_arm,) float64, rad: end configuration.
            max_step_m: metres, > 0: largest travel of any moving point between checks.

        Returns:
            (True, '') when free, else (False, reason) with the path fraction, q and the pair.

        Raises:
            InvalidInputError: malformed q_from / q_to or step.
        """
        samples = self.path_samples(q_from, q_to, max_step_m)
        n_steps = len(samples) - 1
        for i, qi in enumerate(samples):
            self._set_qpos(qi)
            reason = self._first_collision()
            if reason:
                q_text = np.array2string(qi, precision=4, separator=", ")
                return False, f"at t={i / n_steps:.4f} (sample {i}/{n_steps}, q={q_text}): {reason}"
        return True, ""

    def _axis_reach(self, joint: int) -> float:
        """Largest distance of the joint's moving bounding spheres from its axis (current MjData)."""
        j = self.arm_joints[joint]
        axis, anchor = self._data.xaxis[j], self._data.xanchor[j]
        reach = 0.0
        for g, moves in self._geom_moves.items():
            if moves[joint]:
                r = self._data.geom_xpos[g] - anchor
                reach = max(reach, float(np.linalg.norm(r - (r @ axis) * axis)) + self._geoms[g].rbound)
        return reach

    def _reach(self, qa: FloatArray, qb: FloatArray) -> FloatArray:
        """(n_arm,) metres per unit of each joint along qa -> qb: L_a of ``path_free``."""
        slide_travel = np.where(
            self._is_slide,
            np.maximum(np.abs(qa - self.qpos_ref[self._qadr]), np.abs(qb - self.qpos_ref[self._qadr])),
            0.0,
        )
        if self._reach_base.shape[1] == 0:
            reach = np.zeros(len(self.arm_joints))
        else:
            reach = np.max(self._reach_base + self._reach_slides @ slide_travel, axis=1)
        reach = np.where(np.isfinite(reach), np.maximum(reach, 0.0), 0.0)
        return np.where(self._is_slide, 1.0, reach)
