"""The Foxglove 3D scene comes from the robot's MJCF: transforms reproduce MuJoCo's kinematics, primitives its geoms."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from host.run.scene3d import STL_MEDIA_TYPE, RobotScene
from robots.registry import load_robot
from tests.support.mesh_robot import write_mesh_arm


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, q)
    return m.reshape(3, 3) @ v


@pytest.fixture(scope="module")
def scene() -> RobotScene:
    return RobotScene(load_robot("coco"))


def test_transform_tree_composes_to_mujoco_world_poses(scene: RobotScene) -> None:
    rng = np.random.default_rng(3)
    robot = scene.robot
    lo, hi = np.asarray(robot.servos.mins), np.asarray(robot.servos.maxs)
    joints = rng.uniform(lo, hi)
    yaw = 0.7
    base = ((0.3, -0.2, 0.11), (np.cos(yaw / 2), 0.05, -0.03, np.sin(yaw / 2)))
    base = (base[0], tuple(np.asarray(base[1]) / np.linalg.norm(base[1])))
    tf = scene.transforms(1_234_567, joints, base)
    # the SDK's messages have no getters: decode the encoded message with its own protobuf schema
    decoded = _decode(tf)
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {"world": (np.zeros(3), np.array([1.0, 0, 0, 0]))}
    parents = {t.child_frame_id: t for t in decoded.transforms}
    assert decoded.transforms[0].timestamp.seconds == 1 and decoded.transforms[0].timestamp.nanos == 234_567_000

    def world(name: str) -> tuple[np.ndarray, np.ndarray]:
        if name not in poses:
            t = parents[name]
            pp, pq = world(t.parent_frame_id)
            r = t.rotation
            q = np.array([r.w, r.x, r.y, r.z])
            p = np.array([t.translation.x, t.translation.y, t.translation.z])
            poses[name] = (pp + _rotate(pq, p), _quat_mul(pq, q))
        return poses[name]

    m = scene.model
    d = mujoco.MjData(m)
    scene.rm.set_state(d, [*base[0], *base[1]], joints)
    assert set(parents) == set(scene.names[1:])
    for b in range(1, m.nbody):
        p, q = world(scene.names[b])
        assert np.allclose(p, d.xpos[b], atol=1e-9), scene.names[b]
        assert abs(abs(float(np.dot(q, d.xquat[b]))) - 1.0) < 1e-9, scene.names[b]  # same rotation (q or -q)


def _decode(msg: Any) -> Any:
    """A foxglove-sdk message decoded through its own protobuf schema (mcap-protobuf-support)."""
    s = type(msg).get_schema()
    schema = Schema(id=1, name=s.name, encoding=s.encoding, data=bytes(s.data))
    return DecoderFactory().decoder_for("protobuf", schema)(msg.encode())


def test_every_visible_geom_becomes_a_primitive_in_its_body_frame(scene: RobotScene) -> None:
    upd = _decode(scene.scene_update(0))
    m = scene.model
    T = mujoco.mjtGeom
    want: dict[str, int] = {}
    for g in range(m.ngeom):
        if m.geom_bodyid[g] == 0 or m.geom_type[g] == T.mjGEOM_PLANE:
            continue
        name = scene.names[m.geom_bodyid[g]]
        want[name] = want.get(name, 0) + (3 if m.geom_type[g] == T.mjGEOM_CAPSULE else 1)  # capsule: cylinder + 2 caps
    got = {e.frame_id: len(e.cubes) + len(e.spheres) + len(e.cylinders) + len(e.models) for e in upd.entities}
    assert got == want
    assert all(e.frame_locked for e in upd.entities)
    torso = next(e for e in upd.entities if e.frame_id == "torso")
    box = torso.cubes[0]
    gid = m.geom("torso").id
    assert np.allclose([box.size.x, box.size.y, box.size.z], 2 * m.geom_size[gid])


_STL = np.dtype([("normal", "<f4", (3,)), ("v", "<f4", (3, 3)), ("attr", "<u2")])


def _stl_triangles(data: bytes) -> np.ndarray:
    """(n, 3, 3) vertices of a binary STL, read by its layout (80-byte header, u32 count, 50-byte records)."""
    n = int(np.frombuffer(data, "<u4", 1, 80)[0])
    assert len(data) == 84 + 50 * n
    return np.frombuffer(data, _STL, n, 84)["v"]


@pytest.fixture(scope="module")
def mesh_scene(tmp_path_factory: pytest.TempPathFactory) -> RobotScene:
    robots_dir = write_mesh_arm(tmp_path_factory.mktemp("mesh"), segments=16)
    return RobotScene(load_robot("mesh_arm", robots_dir))


def test_meshes_are_stl_models_holding_mujocos_compiled_triangles(mesh_scene: RobotScene) -> None:
    """Each mesh geom: one ModelPrimitive (model/stl, colour overridden) whose STL decodes back to MuJoCo's
    compiled mesh (``mesh_vert[mesh_face]``, float32), at the geom's pose in its body's frame."""
    import base64

    from google.protobuf.json_format import MessageToDict

    m = mesh_scene.model
    upd = _decode(mesh_scene.scene_update(2_500_000))
    by_frame = {e.frame_id: e for e in upd.entities}
    seen = 0
    for g in range(m.ngeom):
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH:
            continue
        entity = by_frame[mesh_scene.names[m.geom_bodyid[g]]]
        assert entity.frame_locked and entity.timestamp.seconds == 2 and entity.timestamp.nanos == 500_000_000
        mesh = int(m.geom_dataid[g])
        v0, f0, nf = int(m.mesh_vertadr[mesh]), int(m.mesh_faceadr[mesh]), int(m.mesh_facenum[mesh])
        want = m.mesh_vert[v0:v0 + int(m.mesh_vertnum[mesh])][m.mesh_face[f0:f0 + nf]].astype(np.float32)
        matches = []
        for model in entity.models:
            tri = _stl_triangles(bytes(model.data))
            if tri.shape == want.shape and np.array_equal(tri, want):
                matches.append(model)
        assert len(matches) == 1, m.mesh(mesh).name
        model = matches[0]
        assert model.media_type == STL_MEDIA_TYPE and model.override_color
        assert np.isclose(model.color.a, m.geom_rgba[g][3], atol=1e-6)
        p = model.pose.position
        assert np.allclose([p.x, p.y, p.z], m.geom_pos[g])
        assert MessageToDict(model)["data"] == base64.b64encode(bytes(model.data)).decode()  # what log decode sees
        seen += 1
    assert seen == 13 and mesh_scene.boxed_meshes == []
    assert mesh_scene.mesh_bytes == sum(84 + 50 * int(n) for n in m.mesh_facenum)


def test_a_mesh_over_the_cap_becomes_its_bounding_box(mesh_scene: RobotScene, monkeypatch: pytest.MonkeyPatch) -> None:
    import host.run.scene3d as scene3d

    m = mesh_scene.model
    biggest = int(np.argmax(m.mesh_facenum))
    monkeypatch.setattr(scene3d, "MAX_MESH_TRIANGLES", int(m.mesh_facenum[biggest]) - 1)
    scene = RobotScene(mesh_scene.robot)
    assert m.mesh(biggest).name in scene.boxed_meshes
    upd = _decode(scene.scene_update(0))
    assert sum(len(e.models) for e in upd.entities) == 13 - len(scene.boxed_meshes)
    assert sum(len(e.cubes) for e in upd.entities) == len(scene.boxed_meshes)


def test_scene_update_only_restamps_the_entities_built_once(mesh_scene: RobotScene) -> None:
    a, b = _decode(mesh_scene.scene_update(0)), _decode(mesh_scene.scene_update(7_000_000))
    assert [e.id for e in a.entities] == [e.id for e in b.entities]
    assert all(e.timestamp.seconds == 7 for e in b.entities)
    assert [bytes(x.data) for e in a.entities for x in e.models] == [bytes(x.data) for e in b.entities for x in e.models]
