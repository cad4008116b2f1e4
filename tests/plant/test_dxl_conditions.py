"""Injected hardware conditions seen through ROBOTIS's SDK (``dynamixel_sdk``, Protocol 2.0): torque off
is limp, hardware errors (alert bit + hardware error status, torque off on overload), corrupted CRCs,
a mis-mounted or uncalibrated servo (offset, reversed), another model number, a missing servo, two
servos on one id, a controller at the wrong baud, a servo that dies. In lockstep every goal SYNC WRITE
is one control period; each SYNC WRITE is paced by a read round trip (no sleeps)."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator
from contextlib import contextmanager

import dynamixel_sdk.port_handler
import pytest
from dynamixel_sdk import (
    COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, GroupBulkRead, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler,
)

from firmware_sim.plant.conditions import Conditions, ServoError
from firmware_sim.plant.dxl_table import ADDR, MODEL_XL330, MODEL_XM430
from firmware_sim.plant.dynamixel import ERR_ALERT, Result
from firmware_sim.plant.servo import Fault
from firmware_sim.plant.world import LOW_VOLTAGE_DV
from robots.hardware import ServoCalibration, rad_to_steps, steps_to_rad

from .harness import ROBOT, STEP, Served, served

BAUD = 1_000_000
Bus = tuple[Served, PortHandler, PacketHandler]


@contextmanager
def dxl_bus(monkeypatch: pytest.MonkeyPatch, conditions: Conditions | None = None, *, robot: str = "coco",
            baud: int = BAUD) -> Iterator[Bus]:
    with served(monkeypatch, dynamixel_sdk.port_handler, protocol="dxl2", baud=baud, conditions=conditions,
                robot=robot) as s:
        port = PortHandler(s.port.name)
        assert port.openPort() and port.setBaudRate(baud)
        try:
            yield s, port, PacketHandler(2.0)
        finally:
            port.closePort()


def _periods(bus: Bus, n: int, ids: list[int]) -> None:
    """``n`` control periods: a goal SYNC WRITE of the present goals, paced by a READ of the first id."""
    s, port, ph = bus
    writer = GroupSyncWrite(port, ph, ADDR.GOAL_POSITION, 4)
    for sid in ids:
        assert writer.addParam(sid, list(struct.pack("<i", s.world.by_id[sid].goal_steps)))
    for _ in range(n):
        assert writer.txPacket() == COMM_SUCCESS
        assert ph.read1ByteTxRx(port, ids[0], ADDR.MOVING)[1] == COMM_SUCCESS


def test_torque_off_is_limp_torque_on_holds(monkeypatch: pytest.MonkeyPatch) -> None:
    """The arm's shoulder and elbow under gravity: held with torque on, falling with it off."""
    with dxl_bus(monkeypatch, robot="arm") as bus:
        s, port, ph = bus
        ids = [1, 2, 3, 4, 5, 6]
        for sid in ids:
            assert ph.write1ByteTxRx(port, sid, ADDR.TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        _periods(bus, 100, ids)
        q0 = s.world.positions()
        _periods(bus, 100, ids)
        held = max(abs(a - b) for a, b in zip(s.world.positions(), q0))
        assert held < math.radians(1), f"torque on: moved {math.degrees(held):.2f} deg"
        for sid in ids:
            assert ph.write1ByteTxRx(port, sid, ADDR.TORQUE_ENABLE, 0) == (COMM_SUCCESS, 0)
        q1 = s.world.positions()
        _periods(bus, 250, ids)
        fell = max(abs(a - b) for a, b in zip(s.world.positions(), q1))
        assert fell > math.radians(10), f"torque off: moved only {math.degrees(fell):.2f} deg"
        assert ph.read1ByteTxRx(port, 2, ADDR.TORQUE_ENABLE)[0] == 0


def test_overload_sets_the_alert_bit_and_hardware_error_and_drops_torque(monkeypatch: pytest.MonkeyPatch) -> None:
    c = Conditions(errors=(ServoError(3, Fault.OVERLOAD, 100_000), ServoError(5, Fault.VOLTAGE, 0)))
    with dxl_bus(monkeypatch, c) as bus:
        s, port, ph = bus
        ids = [sv.id for sv in ROBOT.servos]
        for sid in ids:
            ph.write1ByteTxRx(port, sid, ADDR.TORQUE_ENABLE, 1)
        value, result, error = ph.read1ByteTxRx(port, 3, ADDR.HARDWARE_ERROR)
        assert (value, result, error) == (0, COMM_SUCCESS, 0)  # before 0.1 s: healthy
        _periods(bus, 60, ids)  # 0.12 s
        value, result, error = ph.read1ByteTxRx(port, 3, ADDR.HARDWARE_ERROR)
        assert result == COMM_SUCCESS and error & ERR_ALERT and value == 0x20  # bit 5: overload
        assert "Hardware error" in ph.getRxPacketError(error)
        assert ph.read1ByteTxRx(port, 3, ADDR.TORQUE_ENABLE)[0] == 0  # the servo let go
        assert not s.world._driven[2]
        # undervoltage: alert, bit 0, the reading below the minimum; the XL330 ships with Shutdown 53,
        # which includes the input voltage error, so its torque would not come on; with Shutdown 52 it does
        value, result, error = ph.read2ByteTxRx(port, 5, ADDR.PRESENT_VOLTAGE)
        assert result == COMM_SUCCESS and error == ERR_ALERT and value == LOW_VOLTAGE_DV
        assert ph.read1ByteTxRx(port, 5, ADDR.HARDWARE_ERROR)[0] == 0x01
        assert ph.read1ByteTxRx(port, 5, ADDR.SHUTDOWN)[0] == 53
        assert ph.read1ByteTxRx(port, 5, ADDR.TORQUE_ENABLE)[0] == 0
        assert ph.write1ByteTxRx(port, 5, ADDR.SHUTDOWN, 52) == (COMM_SUCCESS, ERR_ALERT)
        assert ph.write1ByteTxRx(port, 5, ADDR.TORQUE_ENABLE, 1) == (COMM_SUCCESS, ERR_ALERT)
        assert ph.read1ByteTxRx(port, 5, ADDR.TORQUE_ENABLE)[0] == 1
        # every status packet carries the alert, a PING too; the other servos are clean
        assert ph.ping(port, 3)[2] == ERR_ALERT and ph.ping(port, 4)[2] == 0
        # REBOOT clears it; the overload is still there, so the next period it is back
        assert ph.reboot(port, 3) == (COMM_SUCCESS, ERR_ALERT)
        assert ph.read1ByteTxRx(port, 3, ADDR.HARDWARE_ERROR) == (0, COMM_SUCCESS, 0)
        _periods(bus, 1, ids)
        assert ph.read1ByteTxRx(port, 3, ADDR.HARDWARE_ERROR) == (0x20, COMM_SUCCESS, ERR_ALERT)


@pytest.mark.parametrize("p", [0.0, 0.3, 1.0])
def test_corrupt_status_packets_fail_the_crc(monkeypatch: pytest.MonkeyPatch, p: float) -> None:
    with dxl_bus(monkeypatch, Conditions(corrupt=p, seed=4)) as (s, port, ph):
        results = [ph.ping(port, 1 + k % 12)[1] for k in range(60)]
    bad = results.count(COMM_RX_CORRUPT)
    assert bad + results.count(COMM_SUCCESS) == 60
    if p == 0.0:
        assert bad == 0
    elif p == 1.0:
        assert bad == 60
    else:
        assert 5 <= bad <= 35, bad


def test_offset_and_reversed_servos_read_and_drive_as_the_calibration_formula_says(monkeypatch: pytest.MonkeyPatch) -> None:
    c = Conditions(offsets={2: 300, 4: -150}, reversed=frozenset({4, 9}))
    with dxl_bus(monkeypatch, c) as bus:
        s, port, ph = bus
        q = s.world.positions()
        for sv in ROBOT.servos:
            cal = ServoCalibration(sv.id, c.offsets.get(sv.id, 0), -1 if sv.id in c.reversed else 1)
            raw, result, error = ph.read4ByteTxRx(port, sv.id, ADDR.PRESENT_POSITION)
            assert result == COMM_SUCCESS and raw == rad_to_steps(sv, cal, float(q[sv.index]), STEP), sv.name
        # drive servo 4 (offset and reversed) to a raw goal: the joint goes where the calibration says
        sv = ROBOT.servos.by_name("fl_knee")
        cal = ServoCalibration(sv.id, -150, -1)
        target = float(q[sv.index]) + 0.3
        goal = rad_to_steps(sv, cal, target, STEP)
        for sid in (sv.id,):
            assert ph.write1ByteTxRx(port, sid, ADDR.TORQUE_ENABLE, 1) == (COMM_SUCCESS, 0)
        assert ph.write4ByteTxRx(port, sv.id, ADDR.GOAL_POSITION, goal) == (COMM_SUCCESS, 0)
        _periods(bus, 150, [sv.id])
        got = float(s.world.positions()[sv.index])
        assert abs(got - steps_to_rad(sv, cal, goal, STEP)) < math.radians(3)
        # the same raw goal on a calibrated servo would have turned the joint the other way
        assert abs(got - target) < math.radians(3)


def test_model_numbers_and_mixed_layouts_on_one_bus(monkeypatch: pytest.MonkeyPatch) -> None:
    """``--model 7=1020``: servo 7 pings as an XM430 and keeps its indirect data at 224, the XL330s at
    208; one BULK READ reads both blocks."""
    with dxl_bus(monkeypatch, Conditions(models={7: MODEL_XM430, 8: 4242})) as (s, port, ph):
        assert ph.ping(port, 7)[0] == MODEL_XM430 and ph.ping(port, 8)[0] == 4242 and ph.ping(port, 6)[0] == MODEL_XL330
        for sid in (6, 7):
            for k in range(4):
                assert ph.write2ByteTxRx(port, sid, ADDR.INDIRECT_ADDRESS + 2 * k, ADDR.PRESENT_POSITION + k) == (COMM_SUCCESS, 0)
        assert ph.read2ByteTxRx(port, 7, ADDR.PRESENT_VOLTAGE)[0] == 120  # 12 V, the XM430's supply
        bulk = GroupBulkRead(port, ph)
        assert bulk.addParam(6, ADDR.INDIRECT_DATA_XL330, 4) and bulk.addParam(7, ADDR.INDIRECT_DATA_XM430, 4)
        assert bulk.txRxPacket() == COMM_SUCCESS
        assert bulk.getData(6, ADDR.INDIRECT_DATA_XL330, 4) == s.world.by_id[6].present_steps
        assert bulk.getData(7, ADDR.INDIRECT_DATA_XM430, 4) == s.world.by_id[7].present_steps
        # the XL330's table ends at 227: reading the XM430's indirect data there is a range error
        assert ph.readTxRx(port, 6, ADDR.INDIRECT_DATA_XM430 + 4, 4)[2] == Result.DATA_RANGE


def test_missing_servo_never_answers(monkeypatch: pytest.MonkeyPatch) -> None:
    with dxl_bus(monkeypatch, Conditions(missing=frozenset({4}))) as (s, port, ph):
        assert ph.ping(port, 4)[1] == COMM_RX_TIMEOUT
        assert ph.ping(port, 3)[1] == COMM_SUCCESS
        found, result = ph.broadcastPing(port)
        assert result == COMM_SUCCESS and 4 not in found and 3 in found and 5 in found
        # a SYNC READ stops at the silent servo; a FAST SYNC READ's one packet breaks off there
        reader = GroupSyncRead(port, ph, ADDR.PRESENT_POSITION, 4)
        for sid in (3, 4, 5):
            assert reader.addParam(sid)
        assert reader.txRxPacket() == COMM_RX_TIMEOUT
        assert reader.fastSyncRead() != COMM_SUCCESS
        assert reader.removeParam(4) is None and reader.fastSyncRead() == COMM_SUCCESS


def test_duplicate_id_answers_collide_into_garbage(monkeypatch: pytest.MonkeyPatch) -> None:
    with dxl_bus(monkeypatch, Conditions(duplicate=frozenset({2}))) as (s, port, ph):
        for _ in range(5):
            assert ph.ping(port, 2)[1] != COMM_SUCCESS
            assert ph.read4ByteTxRx(port, 2, ADDR.PRESENT_POSITION)[1] != COMM_SUCCESS
            assert ph.ping(port, 1)[1] == COMM_SUCCESS and ph.ping(port, 3)[1] == COMM_SUCCESS
        found, _ = ph.broadcastPing(port)
        assert 2 not in found and 1 in found


def test_a_controller_at_another_baud_gets_no_answer(monkeypatch: pytest.MonkeyPatch) -> None:
    with dxl_bus(monkeypatch, baud=57_600) as (s, port, ph):
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        assert port.setBaudRate(1_000_000)
        assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
        assert s.plant.garbage_bytes > 0 and s.plant.line_baud == 1_000_000
        assert port.setBaudRate(57_600)
        assert ph.ping(port, 1)[1] == COMM_SUCCESS


def test_killed_servo_stops_answering_at_its_time(monkeypatch: pytest.MonkeyPatch) -> None:
    with dxl_bus(monkeypatch) as bus:
        s, port, ph = bus
        s.plant.kill(5, 50_000)
        assert ph.ping(port, 5)[1] == COMM_SUCCESS
        _periods(bus, 30, [1, 5])  # 60 ms (the pacing READ goes to servo 1)
        assert ph.ping(port, 5)[1] == COMM_RX_TIMEOUT and ph.ping(port, 1)[1] == COMM_SUCCESS
