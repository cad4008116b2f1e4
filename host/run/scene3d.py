"""A robot's 3D scene for Foxglove: primitives from its MJCF geoms, frame transforms from its joint angles.

Any robot (fixed or floating base): the model is the robot's own MJCF compiled with the run's scene
(:func:`robots.model.load_model`; ``RobotScene(robot, scene)``, default ``empty``: the robot alone), so
nothing here names a robot. A scene's objects (:mod:`robots.scenes`: the arm's table and its cubes,
coco's bottles) are bodies under ``world`` like the robot's, so they get frames and primitives the same
way. Their frames stay where the scene puts them: the board's SIM_STATE carries the robot's base, not
the objects' poses, so a cube the arm pushes is drawn where it started.

Frames: one per MuJoCo body, named after the body (``body<N>`` when unnamed); ``world`` is MuJoCo's
world body. :meth:`RobotScene.transforms` gives every body's pose in its parent body's frame (the
tree Foxglove's transform panel shows, as ROS's robot_state_publisher does for a URDF): forward
kinematics (``mj_kinematics``) of the recorded state, then ``p_rel = R_parentᵀ (p_child − p_parent)``,
``q_rel = q_parent* ⊗ q_child``. The root's pose is the board's ground truth (SIM_STATE) for a
floating base, or the MJCF's placement for a fixed one.

Geoms become :class:`foxglove.messages.SceneEntity` primitives in their body's frame
(:meth:`RobotScene.scene_update`): box -> cube (full extents = 2 x MuJoCo's half sizes), sphere,
ellipsoid -> sphere (diameters), cylinder -> cylinder (z axis, height = 2 x half length), capsule ->
cylinder + two end spheres, mesh -> a ``ModelPrimitive`` holding the compiled mesh as binary STL
(``media_type`` ``model/stl``, the vertices in the geom frame, m; colour overridden with the geom's).
Planes (the floor) and height fields are left out: Foxglove's 3D panel draws its own grid. Colour: the
geom's material colour, else its ``rgba``.

Cost: every mesh is converted once per :class:`RobotScene` (numpy: ``mesh_vert[mesh_face]`` into STL
records; a mesh used by several geoms once), and the entities are built once, at construction;
:meth:`RobotScene.scene_update` only restamps them (one ``SceneEntity`` per body around the same
primitive objects). Before, one ``Point3`` per vertex took ~0.3-1 s per scene for an arm with ~100 000
triangles of meshes, on the host's event loop. Caps: a mesh over :data:`MAX_MESH_TRIANGLES` triangles,
or one that would take the scene's STL past :data:`MAX_SCENE_MESH_BYTES`, is drawn as its bounding box
(a cube; :attr:`RobotScene.boxed_meshes` names them). The robot loader already refuses
mesh files over its own byte caps (:mod:`robots.loader`); these caps keep the one ``/scene`` message
bounded whatever MuJoCo made of the files.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np
from foxglove.messages import (
    Color,
    CubePrimitive,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    ModelPrimitive,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from robots.description import Robot
from robots.model import RobotModel, load_model

__all__ = ["MAX_MESH_TRIANGLES", "MAX_SCENE_MESH_BYTES", "STL_MEDIA_TYPE", "RobotScene", "stamp", "stl_bytes"]

#: a mesh with more triangles than this is drawn as its bounding box (1 000 000 triangles: 50 MB of STL)
MAX_MESH_TRIANGLES = 1_000_000
#: the scene's meshes together carry at most this many STL bytes; a mesh that would go past it is drawn
#: as its bounding box (the meshes are taken in geom order)
MAX_SCENE_MESH_BYTES = 64 * 1024 * 1024
#: the media type of the meshes' ``ModelPrimitive.data``
STL_MEDIA_TYPE = "model/stl"
WORLD = "world"

#: one binary STL record: normal, three vertices (float32 LE), attribute byte count (u16)
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])


def stl_bytes(vertices: np.ndarray, faces: np.ndarray, header: bytes = b"ghostshell mesh") -> bytes:
    """Binary STL of a triangle mesh: ``vertices`` (n, 3) float (m), ``faces`` (k, 3) vertex indices.

    80-byte header, u32 triangle count, then 50 bytes per triangle (unit normal from the winding, the
    three vertices, attribute 0): ``84 + 50 k`` bytes. numpy only, no per-vertex Python objects.
    Raises ``IndexError`` for a face index outside ``vertices``.
    """
    tri = np.asarray(vertices, dtype=np.float32)[np.asarray(faces, dtype=np.intp).reshape(-1, 3)]
    rec = np.zeros(len(tri), dtype=_STL_RECORD)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    rec["normal"] = n / np.where(norm > 0, norm, 1)
    rec["v"] = tri
    return header[:80].ljust(80, b"\0") + np.uint32(len(tri)).tobytes() + rec.tobytes()


def stamp(board_time_us: int) -> Timestamp:
    """A Foxglove timestamp on the board clock (seconds since the board started)."""
    return Timestamp(board_time_us // 1_000_000, (board_time_us % 1_000_000) * 1000)


def _pose(pos: Sequence[float] | np.ndarray, quat_wxyz: Sequence[float] | np.ndarray) -> Pose:
    w, x, y, z = (float(v) for v in quat_wxyz)
    return Pose(position=Vector3(x=float(pos[0]), y=float(pos[1]), z=float(pos[2])),
                orientation=Quaternion(x=x, y=y, z=z, w=w))


def _quat_conj_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``conj(a) ⊗ b`` row by row for (n, 4) arrays of (w, x, y, z) quaternions."""
    aw, ax, ay, az = -a[:, 0], a[:, 1], a[:, 2], a[:, 3]  # -conj(a) = (-w, x, y, z): same rotation
    bw, bx, by, bz = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    out = np.stack([aw * bw - ax * bx - ay * by - az * bz,
                    aw * bx + ax * bw + ay * bz - az * by,
                    aw * by - ax * bz + ay * bw + az * bx,
                    aw * bz + ax * by - ay * bx + az * bw], axis=1)
    return -out


@dataclass(frozen=True)
class _Geom:
    body: int
    kind: int
    size: tuple[float, float, float]
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    rgba: tuple[float, float, float, float]
    mesh: int


class RobotScene:
    """The robot's bodies as Foxglove frames and primitives (see the module docstring)."""

    def __init__(self, robot: Robot, scene: str = "empty") -> None:
        self.robot = robot
        self.scene = scene
        self.rm: RobotModel = load_model(robot, scene)
        m = self.rm.model
        self.model = m
        self.data = mujoco.MjData(m)
        self.rm.place_on_floor(self.data, robot.pose(robot.start_pose) if robot.start_pose else
                               [0.0] * robot.servo_count)
        self.names = [m.body(i).name or f"body{i}" for i in range(m.nbody)]
        self.names[0] = WORLD
        self.parent = np.asarray(m.body_parentid, dtype=int)
        self.bodies = np.arange(1, m.nbody)  # every body but the world
        self._pairs = [(self.names[int(self.parent[b])], self.names[int(b)]) for b in self.bodies]
        self._fixed_root = (tuple(float(v) for v in self.data.xpos[self.rm.root_body]),
                            tuple(float(v) for v in self.data.xquat[self.rm.root_body]))
        geoms = []
        for g in range(m.ngeom):
            kind = int(m.geom_type[g])
            if kind in (mujoco.mjtGeom.mjGEOM_PLANE, mujoco.mjtGeom.mjGEOM_HFIELD) or m.geom_bodyid[g] == 0:
                continue
            mat = int(m.geom_matid[g])
            rgba = m.mat_rgba[mat] if mat >= 0 else m.geom_rgba[g]
            if rgba[3] <= 0:
                continue
            geoms.append(_Geom(int(m.geom_bodyid[g]), kind, tuple(float(v) for v in m.geom_size[g]),  # type: ignore[arg-type]
                               tuple(float(v) for v in m.geom_pos[g]), tuple(float(v) for v in m.geom_quat[g]),  # type: ignore[arg-type]
                               tuple(float(v) for v in rgba), int(m.geom_dataid[g])))  # type: ignore[arg-type]
        self.geoms = geoms
        self.boxed_meshes: list[str] = []  # meshes drawn as their bounding box (over a cap)
        self._stl: dict[int, bytes] = {}  # mesh id -> binary STL (each mesh converted once)
        self._stl_total = 0
        self._bodies: list[tuple[str, str, dict[str, list[Any]]]] = []  # (frame, entity id, primitives)
        per_body: dict[int, list[_Geom]] = {}
        for geom in self.geoms:
            per_body.setdefault(geom.body, []).append(geom)
        for body, body_geoms in per_body.items():
            prims: dict[str, list[Any]] = {"cubes": [], "spheres": [], "cylinders": [], "models": []}
            for geom in body_geoms:
                self._primitive(geom, prims)
            self._bodies.append((self.names[body], f"{robot.name}/{self.names[body]}", prims))

    @property
    def frame_ids(self) -> list[str]:
        """Every frame this scene publishes, world first."""
        return list(self.names)

    # -- transforms ---------------------------------------------------------------------------
    def transforms(self, board_time_us: int, joints: Sequence[float],
                   base: tuple[Sequence[float], Sequence[float]] | None = None) -> FrameTransforms:
        """Every body in its parent's frame at ``joints`` (rad, servo order); ``base`` = (position m,
        quaternion w x y z) of a floating root (None: the MJCF's placement / the last one set)."""
        d, m = self.data, self.model
        r = self.rm.root_qpos
        if r is not None and base is not None:
            d.qpos[r:r + 3] = base[0]
            d.qpos[r + 3:r + 7] = base[1]
        d.qpos[self.rm.qpos_adr] = joints
        mujoco.mj_kinematics(m, d)
        b = self.bodies
        p = self.parent[b]
        xq_p = d.xquat[p]
        dp = d.xpos[b] - d.xpos[p]
        # rotate dp by conj(q_parent): rows of xmat are the parent's axes in world coordinates
        rel_p = np.einsum("nij,nj->ni", d.xmat[p].reshape(-1, 3, 3).transpose(0, 2, 1), dp)
        rel_q = _quat_conj_mul(xq_p, d.xquat[b])
        ts = stamp(board_time_us)
        names = self._pairs
        out = [FrameTransform(timestamp=ts, parent_frame_id=parent, child_frame_id=child,
                              translation=Vector3(x=px, y=py, z=pz), rotation=Quaternion(x=qx, y=qy, z=qz, w=qw))
               for (parent, child), (px, py, pz), (qw, qx, qy, qz) in zip(names, rel_p.tolist(), rel_q.tolist())]
        return FrameTransforms(transforms=out)

    # -- primitives ---------------------------------------------------------------------------
    @property
    def mesh_bytes(self) -> int:
        """STL bytes the scene's meshes carry (each mesh once, however many geoms use it)."""
        return self._stl_total

    def scene_update(self, board_time_us: int) -> SceneUpdate:
        """One entity per body that has visible geoms, in that body's frame (``frame_locked``, no
        lifetime: it stays until replaced), stamped ``board_time_us``. The primitives were built at
        construction; this only wraps them in new entities (a few µs per body)."""
        ts = stamp(board_time_us)
        return SceneUpdate(entities=[SceneEntity(timestamp=ts, frame_id=frame, id=eid, frame_locked=True,
                                                 cubes=p["cubes"], spheres=p["spheres"], cylinders=p["cylinders"],
                                                 models=p["models"])
                                     for frame, eid, p in self._bodies])

    def _mesh_stl(self, mesh: int) -> bytes | None:
        """Mesh ``mesh``'s binary STL (cached), or None when it is over a cap (see the module docstring)."""
        if mesh in self._stl:
            return self._stl[mesh]
        m = self.model
        nface = int(m.mesh_facenum[mesh])
        size = 84 + 50 * nface
        if nface > MAX_MESH_TRIANGLES or self._stl_total + size > MAX_SCENE_MESH_BYTES:
            return None
        v0, f0 = int(m.mesh_vertadr[mesh]), int(m.mesh_faceadr[mesh])
        data = stl_bytes(m.mesh_vert[v0:v0 + int(m.mesh_vertnum[mesh])], m.mesh_face[f0:f0 + nface],
                         header=f"ghostshell {m.mesh(mesh).name}".encode()[:80])
        self._stl[mesh] = data
        self._stl_total += len(data)
        return data

    def _primitive(self, g: _Geom, prims: dict[str, list[Any]]) -> None:
        T = mujoco.mjtGeom
        cubes, spheres, cylinders = prims["cubes"], prims["spheres"], prims["cylinders"]
        colour = Color(r=g.rgba[0], g=g.rgba[1], b=g.rgba[2], a=g.rgba[3])
        pose = _pose(g.pos, g.quat)
        sx, sy, sz = g.size
        if g.kind == T.mjGEOM_BOX:
            cubes.append(CubePrimitive(pose=pose, size=Vector3(x=2 * sx, y=2 * sy, z=2 * sz), color=colour))
        elif g.kind == T.mjGEOM_SPHERE:
            spheres.append(SpherePrimitive(pose=pose, size=Vector3(x=2 * sx, y=2 * sx, z=2 * sx), color=colour))
        elif g.kind == T.mjGEOM_ELLIPSOID:
            spheres.append(SpherePrimitive(pose=pose, size=Vector3(x=2 * sx, y=2 * sy, z=2 * sz), color=colour))
        elif g.kind == T.mjGEOM_CYLINDER:
            cylinders.append(CylinderPrimitive(pose=pose, size=Vector3(x=2 * sx, y=2 * sx, z=2 * sy),
                                               bottom_scale=1.0, top_scale=1.0, color=colour))
        elif g.kind == T.mjGEOM_CAPSULE:
            cylinders.append(CylinderPrimitive(pose=pose, size=Vector3(x=2 * sx, y=2 * sx, z=2 * sy),
                                               bottom_scale=1.0, top_scale=1.0, color=colour))
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, np.asarray(g.quat))
            axis = rot.reshape(3, 3)[:, 2] * sy
            for sign in (1.0, -1.0):
                spheres.append(SpherePrimitive(pose=_pose(np.asarray(g.pos) + sign * axis, g.quat),
                                               size=Vector3(x=2 * sx, y=2 * sx, z=2 * sx), color=colour))
        elif g.kind == T.mjGEOM_MESH and g.mesh >= 0:
            data = self._mesh_stl(g.mesh)
            if data is not None:
                prims["models"].append(ModelPrimitive(pose=pose, scale=Vector3(x=1.0, y=1.0, z=1.0), color=colour,
                                                      override_color=True, media_type=STL_MEDIA_TYPE, data=data))
                return
            m = self.model  # over a cap: its bounding box (centred where the vertices are)
            self.boxed_meshes.append(m.mesh(g.mesh).name or f"mesh{g.mesh}")
            v0 = int(m.mesh_vertadr[g.mesh])
            verts = m.mesh_vert[v0:v0 + int(m.mesh_vertnum[g.mesh])]
            lo, hi = verts.min(axis=0), verts.max(axis=0)
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, np.asarray(g.quat))
            centre = np.asarray(g.pos) + rot.reshape(3, 3) @ ((lo + hi) / 2)
            cubes.append(CubePrimitive(pose=_pose(centre, g.quat), color=colour,
                                       size=Vector3(x=float(hi[0] - lo[0]), y=float(hi[1] - lo[1]),
                                                    z=float(hi[2] - lo[2]))))

    def root_pose(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The root body's pose in the MJCF's placement (position m, quaternion w x y z)."""
        return self._fixed_root
