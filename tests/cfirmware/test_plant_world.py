"""The plant's world (firmware_sim.plant.world) computes, per control period, exactly what the
per-servo formulas of its docstring give: the goal registers -> MuJoCo ctrl (angle limits,
sign-magnitude goals, the deadband), and the state -> present registers (position, speed, load,
moving). The reference below is the plain per-servo form those formulas were first written in;
the world reads all servos' registers in one block and runs over precomputed constants, so a wrong
offset, servo order or rounding mode shows here as a differing ctrl or register byte. The registers are
the STS control table (firmware_sim.plant.devices.ServoDevice), a view over each servo's
protocol-neutral state: written and read through it, as the bus does."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from firmware_sim.cfirmware.servo_table import STEP_CENTRE
from firmware_sim.plant.devices import REG, ServoDevice
from firmware_sim.plant.feetech import to_sign_magnitude
from firmware_sim.plant.world import World
from robots.registry import load_robot


def _u16(dev: ServoDevice, addr: int) -> int:
    data = dev.read(addr, 2)
    assert data is not None
    return int(struct.unpack("<H", data)[0])


def _set_u16(dev: ServoDevice, addr: int, v: int) -> None:
    assert dev.write(addr, struct.pack("<H", v))


def _present(devs: list[ServoDevice]) -> list[bytes]:
    out = []
    for dev in devs:
        block, moving = dev.read(REG.PRESENT_POSITION, REG.PRESENT_LOAD + 2 - REG.PRESENT_POSITION), dev.read(REG.MOVING, 1)
        assert block is not None and moving is not None
        out.append(block + moving)
    return out


def _reference_ctrl(w: World, devs: list[ServoDevice]) -> list[float]:
    q = w.data.qpos[w.cm.qpos_adr]
    out = []
    for i, s in enumerate(w.table):
        raw = _u16(devs[i], REG.GOAL_POSITION)
        steps = max(_u16(devs[i], REG.MIN_ANGLE), min(_u16(devs[i], REG.MAX_ANGLE), -(raw & 0x7FFF) if raw & 0x8000 else raw))
        g = min(max(s.neutral + s.direction * (steps - STEP_CENTRE) * w.step_rad, s.min), s.max)
        out.append(float(q[i]) if abs(g - q[i]) < w.deadband else g)
    return out


def _reference_present(w: World) -> list[bytes]:
    d, cm = w.data, w.cm
    out = []
    for i, s in enumerate(w.table):
        pos = max(0, min(4095, STEP_CENTRE + s.direction * int(round((float(d.qpos[cm.qpos_adr][i]) - s.neutral) / w.step_rad))))
        speed = int(round(s.direction * float(d.qvel[cm.dof_adr][i]) / w.step_rad))
        load = int(round(s.direction * float(d.actuator_force[cm.act_id][i]) / w.full[i] * 1000))
        out.append(struct.pack("<3H", pos, to_sign_magnitude(max(-32767, min(32767, speed)), 15),
                               to_sign_magnitude(max(-1000, min(1000, load)), 10))
                   + bytes([1 if abs(speed) > 2 else 0]))
    return out


@pytest.mark.parametrize("robot", ["coco", "arm"])
def test_world_matches_the_per_servo_formulas(robot: str) -> None:
    w = World(load_robot(robot))
    devs = [ServoDevice(st) for st in w.servos]
    rng = np.random.default_rng(7)
    ctrl_adr = w.cm.act_id
    held = clamped = joint_clamped = 0
    for k in range(300):
        for dev in devs:
            if k % 3 == 0:  # anywhere in the register, sign bit included: the limits must hold
                _set_u16(dev, REG.GOAL_POSITION, int(rng.integers(0, 1 << 16)))
            else:  # near the current present position, so the deadband decides some of them
                near = _u16(dev, REG.PRESENT_POSITION) + int(rng.integers(-3, 4))
                _set_u16(dev, REG.GOAL_POSITION, max(0, near))
        if k % 50 == 49:  # the firmware may narrow a servo's angle limits
            dev = devs[int(rng.integers(0, w.n))]
            _set_u16(dev, REG.MIN_ANGLE, _u16(dev, REG.MIN_ANGLE) + 5)
        if k % 50 == 24:  # ... or widen them to the whole turn: then the joint's own range must hold
            dev = devs[int(rng.integers(0, w.n))]
            _set_u16(dev, REG.MIN_ANGLE, 0)
            _set_u16(dev, REG.MAX_ANGLE, 4095)
        want = _reference_ctrl(w, devs)
        joint_clamped += sum(c in (s.min, s.max) for c, s in zip(want, w.table))
        held += int(np.sum(np.array(want) == w.data.qpos[w.cm.qpos_adr]))
        clamped += sum(dev.goal != _u16(dev, REG.GOAL_POSITION) for dev in devs)  # held to the angle limits
        w.step()
        got = w.data.ctrl[ctrl_adr].tolist()
        assert got == want, f"period {k}: ctrl differs"
        w.refresh()
        assert _present(devs) == _reference_present(w), f"period {k}: present registers differ"
    assert held > 0 and clamped > 0 and joint_clamped > 0, \
        f"the stream did not reach the deadband ({held}), the register limits ({clamped}) or a joint's range ({joint_clamped})"


@pytest.mark.parametrize("robot", ["coco", "arm"])
def test_present_registers_saturate_as_the_formulas_say(robot: str) -> None:
    """Joint angles past a whole turn, speeds and forces past the registers' ranges: each register
    holds its limit (position 0..4095, speed +-32767, load +-1000), signs in the sign bit."""
    w = World(load_robot(robot))
    devs = [ServoDevice(st) for st in w.servos]
    d, cm = w.data, w.cm
    for sign in (1.0, -1.0):
        d.qpos[cm.qpos_adr] = sign * 20.0
        d.qvel[cm.dof_adr] = sign * 1e4
        d.actuator_force[cm.act_id] = sign * 1e3
        w.refresh()
        present = _present(devs)
        assert present == _reference_present(w)
        for block, s in zip(present, w.table):
            pos, speed, load = struct.unpack("<3H", block[:6])
            outward = sign * s.direction > 0
            assert pos == (4095 if outward else 0)
            assert speed == (32767 if outward else 32767 | 0x8000)
            assert load == (1000 if outward else 1000 | 0x400)
