"""The Foxglove 3D scene comes from the robot's MJCF: transforms reproduce MuJoCo's kinematics, primitives its geoms."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import pytest
from mcap.records import Schema
from mcap_protobuf.decoder import DecoderFactory

from host.run.scene3d import RobotScene
from robots.registry import load_robot


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
    got = {e.frame_id: len(e.cubes) + len(e.spheres) + len(e.cylinders) + len(e.triangles) for e in upd.entities}
    assert got == want
    assert all(e.frame_locked for e in upd.entities)
    torso = next(e for e in upd.entities if e.frame_id == "torso")
    box = torso.cubes[0]
    gid = m.geom("torso").id
    assert np.allclose([box.size.x, box.size.y, box.size.z], 2 * m.geom_size[gid])
