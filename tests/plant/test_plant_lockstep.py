"""In lockstep the plant's world advances only on a SYNC WRITE that covers the goal position
(docs/reference/plant.md, ``python -m firmware_sim.plant --lockstep``): a plain WRITE of a goal sets it
and answers, but moves nothing and advances no time, however many come; a SYNC WRITE of another register
does not step either. Both wire protocols."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from firmware_sim.plant import dynamixel, feetech
from firmware_sim.plant.bus import PlantBus
from firmware_sim.plant.devices import REG
from firmware_sim.plant.dxl_table import ADDR
from firmware_sim.plant.world import World
from robots.registry import load_robot

ROBOT = load_robot("coco")


def _sts(sid: int, goal: int) -> tuple[bytes, bytes, bytes]:
    write = feetech.instruction_packet(sid, feetech.Inst.WRITE, bytes([REG.GOAL_POSITION]) + struct.pack("<H", goal))
    other = feetech.instruction_packet(feetech.BROADCAST_ID, feetech.Inst.SYNC_WRITE,
                                       bytes([REG.ACCELERATION, 1, sid, 0]))
    sync = feetech.instruction_packet(feetech.BROADCAST_ID, feetech.Inst.SYNC_WRITE,
                                      bytes([REG.GOAL_POSITION, 2, sid]) + struct.pack("<H", goal))
    return write, other, sync


def _dxl(sid: int, goal: int) -> tuple[bytes, bytes, bytes]:
    d = dynamixel.DxlInst
    write = dynamixel.instruction_packet(sid, d.WRITE, struct.pack("<Hi", ADDR.GOAL_POSITION, goal))
    other = dynamixel.instruction_packet(0xFE, d.SYNC_WRITE, struct.pack("<HHBB", ADDR.LED, 1, sid, 1))
    sync = dynamixel.instruction_packet(0xFE, d.SYNC_WRITE, struct.pack("<HHBi", ADDR.GOAL_POSITION, 4, sid, goal))
    return write, other, sync


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_plain_write_moves_nothing_until_a_goal_sync_write(protocol: str) -> None:
    world = World(ROBOT)
    plant = PlantBus(world, lockstep=True, protocol=protocol)
    sid = world.servos[0].id
    if protocol == "dxl2":  # a Dynamixel ships with torque off
        assert plant.feed(dynamixel.instruction_packet(sid, dynamixel.DxlInst.WRITE,
                                                       struct.pack("<HB", ADDR.TORQUE_ENABLE, 1)))
    goal = world.servos[0].present_steps + 200
    write, other, sync = (_sts if protocol == "sts" else _dxl)(sid, goal)
    qpos = world.data.qpos.copy()
    for _ in range(50):
        assert plant.feed(write), "a WRITE to one servo is answered"
    assert plant.feed(other) == b""
    assert world.time_us == 0
    assert world.servos[0].goal_steps == goal  # the goal is set ...
    np.testing.assert_array_equal(world.data.qpos, qpos)  # ... and nothing moved
    assert plant.feed(sync) == b""
    assert world.time_us == world.period_us  # one control period per goal SYNC WRITE
    for _ in range(49):
        plant.feed(sync)
    assert world.time_us == 50 * world.period_us
    assert not np.array_equal(world.data.qpos, qpos)
