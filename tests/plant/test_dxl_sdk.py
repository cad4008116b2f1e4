"""ROBOTIS's own SDK (``dynamixel_sdk``, Protocol 2.0) drives the plant's emulated Dynamixel X servos over
a real pty at 57 600 and 1 000 000 baud: ping, read/write, sync write + sync read, bulk read, indirect
addressing, error bits, EEPROM protection, torque off = limp. A client nobody in this project wrote."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator

import dynamixel_sdk.port_handler
import pytest
from dynamixel_sdk import (
    COMM_SUCCESS, GroupBulkRead, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler,
)

from firmware_sim.plant.dxl_table import ADDR, MODEL_XL330
from firmware_sim.plant.devices import IMU_ID, PROBE_ID
from firmware_sim.plant.dynamixel import Result
from robots.hardware import STEP_CENTRE

from .harness import ROBOT, STEP, Served, served

IDS = [s.id for s in ROBOT.servos]


@pytest.fixture(params=[57_600, 1_000_000], ids=["57600", "1M"])
def dxl(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[Served, PortHandler, PacketHandler]]:
    baud = request.param
    with served(monkeypatch, dynamixel_sdk.port_handler, protocol="dxl2", baud=baud) as s:
        port = PortHandler(s.port.name)
        assert port.openPort() and port.setBaudRate(baud)
        yield s, port, PacketHandler(2.0)
        port.closePort()


def _joint(i: int, steps: int) -> float:
    sv = ROBOT.servos[i]
    return sv.neutral + sv.direction * (steps - STEP_CENTRE) * STEP


def _ok(ph: PacketHandler, result: int, error: int = 0) -> None:
    assert result == COMM_SUCCESS, ph.getTxRxResult(result)
    assert error == 0, ph.getRxPacketError(error)


def test_ping_reads_model_numbers_and_broadcast_ping_lists_every_device(dxl) -> None:
    s, port, ph = dxl
    for sid in IDS:
        model, result, error = ph.ping(port, sid)
        _ok(ph, result, error)
        assert model == MODEL_XL330
    assert ph.ping(port, 99)[1] != COMM_SUCCESS  # nobody there: the SDK times out
    found, result = ph.broadcastPing(port)
    _ok(ph, result)
    assert sorted(found) == sorted([*IDS, IMU_ID, PROBE_ID])
    assert found[1] == [MODEL_XL330, 52]


def test_sync_write_goals_then_sync_read_present_positions_match_mujoco(dxl) -> None:
    s, port, ph = dxl
    for sid in IDS:
        _ok(ph, *ph.write1ByteTxRx(port, sid, ADDR.TORQUE_ENABLE, 1))
    head = ROBOT.servos.by_name("head_yaw")
    goal_rad = 0.4
    goal = STEP_CENTRE + head.direction * round((goal_rad - head.neutral) / STEP)
    reader = GroupSyncRead(port, ph, ADDR.PRESENT_POSITION, 4)
    for sid in IDS:
        assert reader.addParam(sid)
    _ok(ph, reader.txRxPacket())
    current = {sid: reader.getData(sid, ADDR.PRESENT_POSITION, 4) for sid in IDS}
    writer = GroupSyncWrite(port, ph, ADDR.GOAL_POSITION, 4)
    for sid in IDS:
        assert writer.addParam(sid, list(struct.pack("<i", goal if sid == head.id else current[sid])))
    before = s.world.steps
    for _ in range(200):  # 0.4 s of physics: one control period per SYNC WRITE, paced by the SYNC READ
        _ok(ph, writer.txPacket())
        _ok(ph, reader.txRxPacket())
    assert s.world.steps - before == 200
    q = s.world.positions()
    for i, sid in enumerate(IDS):
        assert reader.isAvailable(sid, ADDR.PRESENT_POSITION, 4)
        steps = reader.getData(sid, ADDR.PRESENT_POSITION, 4)
        assert abs(_joint(i, steps) - q[i]) <= STEP / 2 + 1e-9, (sid, steps)
    assert abs(q[head.index] - goal_rad) < math.radians(2)
    back, result, error = ph.read4ByteTxRx(port, head.id, ADDR.GOAL_POSITION)
    _ok(ph, result, error)
    assert back == goal


def test_read_write_and_bulk_read_across_devices(dxl) -> None:
    s, port, ph = dxl
    _ok(ph, *ph.write1ByteTxRx(port, 2, ADDR.LED, 1))
    led, result, error = ph.read1ByteTxRx(port, 2, ADDR.LED)
    _ok(ph, result, error)
    assert led == 1
    bulk = GroupBulkRead(port, ph)
    assert bulk.addParam(1, ADDR.PRESENT_POSITION, 4)
    assert bulk.addParam(2, ADDR.PRESENT_TEMPERATURE, 1)
    assert bulk.addParam(3, ADDR.PRESENT_VOLTAGE, 2)
    assert bulk.addParam(IMU_ID, 56, 6)
    _ok(ph, bulk.txRxPacket())
    assert bulk.getData(1, ADDR.PRESENT_POSITION, 4) == s.world.servos[0].present_steps
    assert bulk.getData(2, ADDR.PRESENT_TEMPERATURE, 1) == 30
    assert bulk.getData(3, ADDR.PRESENT_VOLTAGE, 2) == 50
    roll = bulk.getData(IMU_ID, 56, 2)
    assert roll is not None


def test_indirect_addresses_map_a_sync_read_block(dxl) -> None:
    """XL330 indirect address 1..7 (168..) -> present position (4), present temperature (1), present
    voltage (2); one SYNC READ of indirect data 1..7 (208..) returns them, as ROBOTIS's
    indirect_address example does; a goal written through indirect data reaches the goal register."""
    s, port, ph = dxl
    data1 = ADDR.INDIRECT_DATA_XL330
    targets = [*range(ADDR.PRESENT_POSITION, ADDR.PRESENT_POSITION + 4), ADDR.PRESENT_TEMPERATURE,
               ADDR.PRESENT_VOLTAGE, ADDR.PRESENT_VOLTAGE + 1]
    for sid in IDS:
        for k, a in enumerate(targets):
            _ok(ph, *ph.write2ByteTxRx(port, sid, ADDR.INDIRECT_ADDRESS + 2 * k, a))
    reader = GroupSyncRead(port, ph, data1, len(targets))
    for sid in IDS:
        assert reader.addParam(sid)
    _ok(ph, reader.txRxPacket())
    for st in s.world.servos:
        assert reader.getData(st.id, data1, 4) == st.present_steps
        assert reader.getData(st.id, data1 + 4, 1) == st.temperature_c
        assert reader.getData(st.id, data1 + 5, 2) == st.voltage_dv == 50
    # torque on: the indirect addresses are locked (access error), the indirect data writes through
    _ok(ph, *ph.write1ByteTxRx(port, 1, ADDR.TORQUE_ENABLE, 1))
    result, error = ph.write2ByteTxRx(port, 1, ADDR.INDIRECT_ADDRESS, ADDR.GOAL_POSITION)
    assert result == COMM_SUCCESS and error == Result.ACCESS
    _ok(ph, *ph.write1ByteTxRx(port, 1, ADDR.TORQUE_ENABLE, 0))
    for k in range(4):
        _ok(ph, *ph.write2ByteTxRx(port, 1, ADDR.INDIRECT_ADDRESS + 2 * k, ADDR.GOAL_POSITION + k))
    _ok(ph, *ph.write1ByteTxRx(port, 1, ADDR.TORQUE_ENABLE, 1))
    _ok(ph, *ph.write4ByteTxRx(port, 1, data1, 2100))
    back, result, error = ph.read4ByteTxRx(port, 1, ADDR.GOAL_POSITION)
    _ok(ph, result, error)
    assert back == 2100 and s.world.servos[0].goal_steps == 2100


def test_eeprom_write_with_torque_on_is_an_access_error(dxl) -> None:
    s, port, ph = dxl
    _ok(ph, *ph.write1ByteTxRx(port, 4, ADDR.RETURN_DELAY, 0))  # torque off (as shipped): allowed
    assert ph.read1ByteTxRx(port, 4, ADDR.RETURN_DELAY)[0] == 0
    _ok(ph, *ph.write1ByteTxRx(port, 4, ADDR.TORQUE_ENABLE, 1))
    result, error = ph.write4ByteTxRx(port, 4, ADDR.MAX_POSITION, 3000)
    assert result == COMM_SUCCESS and error == Result.ACCESS, ph.getRxPacketError(error)
    assert "not available" in ph.getRxPacketError(error)
    assert ph.read4ByteTxRx(port, 4, ADDR.MAX_POSITION)[0] != 3000
    result, error = ph.write1ByteTxRx(port, 4, ADDR.MODEL, 1)  # read-only
    assert error == Result.ACCESS
    result, error = ph.write2ByteTxRx(port, 4, ADDR.GOAL_POSITION, 1)  # half of a 4-byte item
    assert error == Result.DATA_LENGTH
    lo = ph.read4ByteTxRx(port, 4, ADDR.MIN_POSITION)[0]
    result, error = ph.write4ByteTxRx(port, 4, ADDR.GOAL_POSITION, lo - 10)  # below the position limit
    assert error == Result.DATA_LIMIT
    _, result, error = ph.readTxRx(port, 4, 250, 4)  # past the control table: a status without data
    assert result == COMM_SUCCESS and error == Result.DATA_RANGE


def test_fast_sync_read_returns_every_servo_in_one_packet(dxl) -> None:
    s, port, ph = dxl
    reader = GroupSyncRead(port, ph, ADDR.PRESENT_POSITION, 4)
    for sid in IDS:
        assert reader.addParam(sid)
    _ok(ph, reader.fastSyncRead())
    for st in s.world.servos:
        assert reader.getData(st.id, ADDR.PRESENT_POSITION, 4) == st.present_steps
