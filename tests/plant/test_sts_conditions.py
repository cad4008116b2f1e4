"""Injected hardware conditions seen through Feetech's SDK (``scservo_sdk``, STS): status error bits as
``getRxPacketError`` names them (overload and overheat also drop the torque), corrupted checksums, a
mis-mounted or uncalibrated servo (offset, reversed), another model number, a missing servo, two servos
on one id, a controller at the wrong baud. Lockstep: each goal SYNC WRITE is one control period, paced by
a READ round trip."""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import scservo_sdk.port_handler
from scservo_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, GroupSyncWrite, PacketHandler, PortHandler

from firmware_sim.plant.conditions import Conditions, ServoError
from firmware_sim.plant.devices import REG, STS_MODEL
from firmware_sim.plant.servo import Fault
from robots.hardware import ServoCalibration, rad_to_steps, steps_to_rad

from .harness import ROBOT, STEP, Served, served

Bus = tuple[Served, PortHandler, PacketHandler]


@contextmanager
def sts_bus(monkeypatch: pytest.MonkeyPatch, conditions: Conditions | None = None, *, robot: str = "coco",
            baud: int = 1_000_000) -> Iterator[Bus]:
    with served(monkeypatch, scservo_sdk.port_handler, protocol="sts", baud=baud, conditions=conditions,
                robot=robot) as s:
        port = PortHandler(s.port.name)
        assert port.openPort() and port.setBaudRate(baud)
        try:
            yield s, port, PacketHandler(0)
        finally:
            port.closePort()


def _periods(bus: Bus, n: int, ids: list[int]) -> None:
    s, port, ph = bus
    writer = GroupSyncWrite(port, ph, REG.GOAL_POSITION, 2)
    for sid in ids:
        g = s.world.by_id[sid].goal_steps
        assert writer.addParam(sid, [g & 0xFF, g >> 8 & 0xFF])
    for _ in range(n):
        assert writer.txPacket() == COMM_SUCCESS
        assert ph.read1ByteTxRx(port, ids[0], REG.MOVING)[1] == COMM_SUCCESS


@pytest.mark.parametrize("kind, bit, name, limp", [
    (Fault.OVERLOAD, 0x20, "Overload", True), (Fault.OVERHEAT, 0x04, "Overheat", True),
    (Fault.VOLTAGE, 0x01, "Input voltage", False)])
def test_error_bits_as_the_sdk_names_them(monkeypatch: pytest.MonkeyPatch, kind: int, bit: int, name: str,
                                           limp: bool) -> None:
    with sts_bus(monkeypatch, Conditions(errors=(ServoError(2, kind, 40_000),))) as bus:
        s, port, ph = bus
        assert ph.read2ByteTxRx(port, 2, REG.PRESENT_POSITION)[2] == 0
        _periods(bus, 25, [1, 2])  # 50 ms
        _, result, error = ph.read2ByteTxRx(port, 2, REG.PRESENT_POSITION)
        assert result == COMM_SUCCESS and error == bit
        assert name in ph.getRxPacketError(error)
        assert ph.ping(port, 2)[2] == bit and ph.ping(port, 1)[2] == 0
        assert ph.read1ByteTxRx(port, 2, REG.TORQUE_ENABLE)[0] == (0 if limp else 1)
        if kind == Fault.OVERHEAT:
            assert ph.read1ByteTxRx(port, 2, REG.PRESENT_TEMPERATURE)[0] > 70


@pytest.mark.parametrize("p", [0.0, 0.5, 1.0])
def test_corrupt_checksums(monkeypatch: pytest.MonkeyPatch, p: float) -> None:
    with sts_bus(monkeypatch, Conditions(corrupt=p, seed=11)) as (s, port, ph):
        results = [ph.read2ByteTxRx(port, 1 + k % 12, REG.PRESENT_POSITION)[1] for k in range(60)]
    bad = results.count(COMM_RX_CORRUPT)
    assert bad + results.count(COMM_SUCCESS) == 60
    assert (bad == 0) if p == 0.0 else (bad == 60) if p == 1.0 else (15 <= bad <= 45), bad


def test_offset_and_reverse(monkeypatch: pytest.MonkeyPatch) -> None:
    c = Conditions(offsets={9: 400}, reversed=frozenset({9, 3}))
    with sts_bus(monkeypatch, c) as bus:
        s, port, ph = bus
        q = s.world.positions()
        for sv in ROBOT.servos:
            cal = ServoCalibration(sv.id, c.offsets.get(sv.id, 0), -1 if sv.id in c.reversed else 1)
            raw, result, _ = ph.read2ByteTxRx(port, sv.id, REG.PRESENT_POSITION)
            assert result == COMM_SUCCESS and raw == rad_to_steps(sv, cal, float(q[sv.index]), STEP), sv.name
        head = ROBOT.servos.by_name("head_yaw")
        cal = ServoCalibration(head.id, 400, -1)
        goal = rad_to_steps(head, cal, 0.4, STEP)
        assert ph.write2ByteTxRx(port, head.id, REG.GOAL_POSITION, goal)[1] == COMM_SUCCESS
        _periods(bus, 150, [head.id])
        got = float(s.world.positions()[head.index])
        assert abs(got - 0.4) < math.radians(2) and abs(steps_to_rad(head, cal, goal, STEP) - 0.4) < STEP


def test_model_missing_duplicate(monkeypatch: pytest.MonkeyPatch) -> None:
    c = Conditions(models={3: 1234}, missing=frozenset({5}), duplicate=frozenset({6}))
    with sts_bus(monkeypatch, c) as (s, port, ph):
        assert ph.ping(port, 3)[:2] == (1234, COMM_SUCCESS) and ph.ping(port, 4)[:2] == (STS_MODEL, COMM_SUCCESS)
        assert ph.read2ByteTxRx(port, 3, REG.MODEL)[0] == 1234
        assert ph.ping(port, 5)[1] == COMM_RX_TIMEOUT
        for _ in range(3):
            assert ph.ping(port, 6)[1] != COMM_SUCCESS
            assert ph.read2ByteTxRx(port, 6, REG.PRESENT_POSITION)[1] != COMM_SUCCESS
            assert ph.ping(port, 7)[1] == COMM_SUCCESS


def test_wrong_baud_gets_no_answer(monkeypatch: pytest.MonkeyPatch) -> None:
    with sts_bus(monkeypatch) as (s, port, ph):
        assert port.setBaudRate(115_200)
        assert ph.ping(port, 1)[1] == COMM_RX_TIMEOUT
        assert port.setBaudRate(1_000_000)
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
