"""Feetech's own SDK (``scservo_sdk`` from the ``feetech-servo-sdk`` package) drives the emulated
servos of the plant over a real pty, as it would drive real STS servos: ping, read the model
number, read the present positions (equal to what MuJoCo reports, to one encoder step), write goal
positions with GroupSyncWrite (in lockstep each write is one control period of physics) and read
them back with single READs. A client nobody in this project wrote."""

from __future__ import annotations

import math
import sys
import threading

import pytest
import scservo_sdk.port_handler
from scservo_sdk import COMM_SUCCESS, GroupSyncWrite, PacketHandler, PortHandler

from firmware_sim.cfirmware.servo_table import STEP_CENTRE
from firmware_sim.plant.bus import PlantBus
from firmware_sim.plant.devices import IMU_ID, PROBE_ID, REG, STS_MODEL
from firmware_sim.plant.server import serve
from firmware_sim.plant.world import World
from firmware_sim.transports.ports import PtyPort
from robots.registry import load_robot

ROBOT = load_robot("coco")
STEP = ROBOT.servos.model.resolution


@pytest.fixture
def bus(monkeypatch):
    # The plant answers from a thread of this process; the SDK polls its port in a busy loop holding the
    # GIL, so give the plant's thread its turns sooner and the SDK the answer time a USB adapter's
    # latency timer would (its LATENCY_TIMER constant, 16 ms by default, is the knob the SDK exposes).
    old = sys.getswitchinterval()
    sys.setswitchinterval(0.0002)
    monkeypatch.setattr(scservo_sdk.port_handler, "LATENCY_TIMER", 100)
    world = World(ROBOT)
    plant = PlantBus(world, lockstep=True)
    port = PtyPort()
    stop = threading.Event()
    th = threading.Thread(target=serve, args=(plant, port, stop), daemon=True)
    th.start()
    ph = PortHandler(port.name)
    assert ph.openPort() and ph.setBaudRate(1_000_000)
    yield world, ph, PacketHandler(0)  # 0: STS byte order (little-endian)
    ph.closePort()
    stop.set()
    th.join(5)
    port.close()
    sys.setswitchinterval(old)


def _joint(i: int, steps: int) -> float:
    s = ROBOT.servos[i]
    return s.neutral + s.direction * (steps - STEP_CENTRE) * STEP


def test_sdk_pings_and_reads_mujoco_positions(bus) -> None:
    world, port, ph = bus
    for s in ROBOT.servos:
        model, result, error = ph.ping(port, s.id)
        assert result == COMM_SUCCESS and error == 0 and model == STS_MODEL, (s.id, ph.getTxRxResult(result))
    assert ph.ping(port, IMU_ID)[1] == COMM_SUCCESS and ph.ping(port, PROBE_ID)[1] == COMM_SUCCESS
    assert ph.ping(port, 99)[1] != COMM_SUCCESS  # nobody there: the SDK times out
    mujoco_q = world.positions()
    for i, s in enumerate(ROBOT.servos):
        steps, result, _ = ph.read2ByteTxRx(port, s.id, REG.PRESENT_POSITION)
        assert result == COMM_SUCCESS
        assert abs(_joint(i, steps) - mujoco_q[i]) <= STEP / 2 + 1e-9, (s.name, _joint(i, steps), mujoco_q[i])


def test_sdk_sync_write_moves_the_joints_mujoco_reports(bus) -> None:
    world, port, ph = bus
    head = ROBOT.servos.by_name("head_yaw")
    i = head.index
    goal_rad = 0.5
    goal = STEP_CENTRE + head.direction * round((goal_rad - head.neutral) / STEP)
    writer = GroupSyncWrite(port, ph, REG.GOAL_POSITION, 2)
    for s in ROBOT.servos:
        cur, result, _ = ph.read2ByteTxRx(port, s.id, REG.PRESENT_POSITION)
        assert result == COMM_SUCCESS
        data = goal if s.id == head.id else cur
        assert writer.addParam(s.id, [data & 0xFF, data >> 8])
    steps_before = world.steps
    for _ in range(30):  # 0.6 s of physics, one control period per SYNC WRITE
        for _ in range(10):
            assert writer.txPacket() == COMM_SUCCESS
        # SYNC WRITE has no answer: a READ round trip paces the client, as a controller's tick would
        back, result, _ = ph.read2ByteTxRx(port, head.id, REG.GOAL_POSITION)
        assert result == COMM_SUCCESS and back == goal, ph.getTxRxResult(result)
    assert world.steps - steps_before == 300
    steps_now, result, _ = ph.read2ByteTxRx(port, head.id, REG.PRESENT_POSITION)
    assert result == COMM_SUCCESS
    q = world.positions()[i]
    assert abs(_joint(i, steps_now) - q) <= STEP / 2 + 1e-9
    assert abs(q - goal_rad) < math.radians(2), f"head_yaw at {math.degrees(q):.1f} deg, goal {math.degrees(goal_rad):.1f}"
