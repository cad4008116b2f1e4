"""CoCo's description: data consistency and the neutral stand holding for 10 s in MuJoCo."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from robots.coco import MJCF_PATH, SERVO_COUNT, load_poses, load_servo_table
from robots.coco.model import load_model


def test_servo_table_matches_mjcf() -> None:
    table = load_servo_table()
    cm = load_model(table)
    m = cm.model
    assert len(table) == SERVO_COUNT == m.nu == 12
    assert [s.id for s in table] == list(range(1, 13))
    for s in table:
        j = m.joint(s.joint)
        assert j.range[0] == pytest.approx(s.min, abs=1e-4), s.name
        assert j.range[1] == pytest.approx(s.max, abs=1e-4), s.name
        assert m.actuator(s.actuator).trnid[0] == j.id
    # actuators are declared in servo-id order
    assert list(cm.act_id) == list(range(12))
    # legs 1..4 are front-right, front-left, back-left, back-right
    assert [table[2 * i].name for i in range(4)] == ["fr_hip", "fl_hip", "bl_hip", "br_hip"]
    assert {s.leg for s in table if s.leg} == {1, 2, 3, 4}


def test_model_is_coco_sized() -> None:
    m = mujoco.MjModel.from_xml_path(str(MJCF_PATH))
    assert 1.0 < m.body_subtreemass[m.body("torso").id] < 1.4
    assert m.camera("head_cam").bodyid[0] == m.body("head").id  # camera moves with the head
    for name in ("imu", "camera", "speaker", "microphone", "fr_foot"):
        m.site(name)


def test_servo_speed_is_hobby_servo_like() -> None:
    """Stall torque / joint damping ~ 8 rad/s no-load speed for every servo."""
    cm = load_model()
    m = cm.model
    for i in range(12):
        stall = m.actuator_forcerange[cm.act_id[i], 1]
        damping = m.dof_damping[cm.dof_adr[i]]
        assert stall / damping == pytest.approx(8.0, rel=0.05)
        assert m.dof_armature[cm.dof_adr[i]] > 0 and m.dof_frictionloss[cm.dof_adr[i]] > 0


def test_hip_and_knee_ranges_allow_walking() -> None:
    table = load_servo_table()
    for s in table:
        if s.name.endswith("_hip"):
            assert s.min <= math.radians(-55) and s.max >= math.radians(55)
        if s.name.endswith("_knee"):
            assert s.max >= math.radians(90)


def test_poses_complete_and_in_limits() -> None:
    poses = load_poses()
    assert {"neutral", "stand", "sit", "crouch"} <= set(poses)
    table = load_servo_table()
    assert poses["neutral"] == pytest.approx(table.neutral)
    for q in poses.values():
        assert len(q) == 12


def test_neutral_stand_holds_10s() -> None:
    cm = load_model()
    m, d = cm.model, cm.new_data()
    q = load_poses()["neutral"]
    cm.place_on_floor(d, q)
    steps = int(round(10.0 / m.opt.timestep))
    z, tilt, xy = [], [], []
    for k in range(steps):
        mujoco.mj_step(m, d)
        if k % 50 == 0:
            z.append(d.qpos[2])
            w, x, y, _ = d.qpos[3:7]
            # angle between the body z axis and the world z axis
            tilt.append(math.degrees(math.acos(max(-1.0, min(1.0, 1 - 2 * (x * x + y * y))))))
            xy.append(np.hypot(d.qpos[0], d.qpos[1]))
    z_arr = np.array(z[10:])  # after settling (0.5 s)
    assert 0.075 < z_arr.min() and z_arr.max() < 0.10, "body height out of bounds"
    assert z_arr.max() - z_arr.min() < 0.002, "body height drifts"
    assert max(tilt) < 2.0, "body tilts"
    assert max(xy) < 0.005, "body slides"
    err = np.degrees(np.abs(d.qpos[cm.qpos_adr] - q)).max()
    assert err < 2.0
