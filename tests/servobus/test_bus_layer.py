"""The bus layer alone, on the in-memory port (no pty, no board): ``PORT[:BAUD]``, what each kind of bad
answer becomes, the second clamp, the timing warning, torque off at close."""

from __future__ import annotations

import io
import math

import pytest

from firmware_sim.servobus import make_bus, parse_bus_spec
from firmware_sim.servobus.base import CORRUPT, OVERLOAD, TIMEOUT, VOLTAGE
from firmware_sim.servobus.driver import BusDriver
from firmware_sim.servobus.fuzz import _Model
from firmware_sim.servobus.memport import MemPort
from firmware_sim.fuzz import Reader
from robots.hardware import DEFAULT_MODEL, Calibration, Hardware, ServoCalibration
from tests.servobus.helpers import ARM, N

IDS = [s.id for s in ARM.servos]


def test_parse_bus_spec() -> None:
    assert parse_bus_spec("/dev/ttyUSB0") == ("/dev/ttyUSB0", None)
    assert parse_bus_spec("/dev/ttyUSB0:57600") == ("/dev/ttyUSB0", 57600)
    assert parse_bus_spec("COM3:1000000") == ("COM3", 1000000)
    assert parse_bus_spec("socket://host:7000x") == ("socket://host:7000x", None)
    for bad in ("", ":57600", "/dev/x:0", "/dev/x:-1"):
        with pytest.raises(ValueError):
            parse_bus_spec(bad)


class _Bus:
    """A driver on the in-memory port; ``mode(pkt) -> 'ok' | 'silent' | 'garbled' | ('error', bits)``
    decides each answer."""

    def __init__(self, protocol: str, cal: Calibration | None = None) -> None:
        self.mode = lambda pkt: "ok"
        self.model = _Model(protocol, Reader(b""), IDS, DEFAULT_MODEL[protocol])
        self.port = MemPort(self._answer)
        self.err = io.StringIO()
        self.driver = BusDriver(make_bus(protocol, "mem", 1_000_000, port_handler=self.port), ARM,
                                Hardware("sts" if protocol == "sts" else "dxl2", 1_000_000, DEFAULT_MODEL[protocol]),
                                cal or Calibration(), err=self.err)

    def _answer(self, pkt: bytes) -> bytes:
        m = self.mode(pkt)
        if m == "silent":
            self.model.answer(pkt, 0, False)
            return b""
        if isinstance(m, tuple):
            return b"".join(self.model.answer(pkt, m[1], False) or [])
        out = b"".join(self.model.answer(pkt, 0, False) or [])
        return out[:-1] + bytes([out[-1] ^ 0xFF]) if m == "garbled" and out else out


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_each_bad_answer_is_named(protocol: str) -> None:
    b = _Bus(protocol)
    q = b.driver.start()
    assert q == pytest.approx([0.0] * N, abs=0.01)
    b.driver.torque_on()
    sync_read = 0x82
    inst = (lambda p: p[4]) if protocol == "sts" else (lambda p: p[7])
    # servo 3 silent three reads in a row: lost
    b.mode = lambda pkt: "silent" if inst(pkt) == sync_read else "ok"
    for k in range(3):
        b.driver.exchange(q, k * 2000)
    faults = b.driver.take_faults()
    assert [(f.servo_id, f.what) for f in faults] == [(i, TIMEOUT) for i in IDS]  # the whole bus went silent
    # ESTOP_CLEAR tries them again; now one garbled answer after another
    b.driver.on_clear()
    b.mode = lambda pkt: "garbled" if inst(pkt) == sync_read else "ok"
    for k in range(3):
        b.driver.exchange(q, k * 2000)
    assert {f.what for f in b.driver.take_faults()} == {CORRUPT}
    # error bits: overload (STS bit 5 / Dynamixel hardware error bit 5) turns that servo's torque off
    b.driver.on_clear()
    if protocol == "sts":
        b.mode = lambda pkt: ("error", 0x20 | 0x01) if inst(pkt) == sync_read else "ok"
    else:
        for t in b.model.tables.values():
            t[70] = 0x20 | 0x01
        b.mode = lambda pkt: ("error", 0x80) if inst(pkt) == sync_read else "ok"
    b.driver.exchange(q, 0)
    faults = b.driver.take_faults()
    assert {f.what for f in faults} == {OVERLOAD, VOLTAGE}
    assert all(f.torque_off for f in faults if f.what == OVERLOAD)
    assert not any(b.driver.torque)
    assert "board: servo 1 (shoulder_pan): overload at board time 0.000 s; its torque is off" in b.err.getvalue()
    b.driver.close()


def test_goals_stay_inside_the_step_limits_whatever_the_command() -> None:
    cal = Calibration({"shoulder_pan": ServoCalibration(1, 100, -1, 1500, 2500)})
    b = _Bus("sts", cal)
    q = b.driver.start()
    b.driver.torque_on()
    lo, hi = b.driver.limits[0]
    assert (lo, hi) == (1500, 2500)
    for x in (math.nan, math.inf, -math.inf, 1e300, -1e300, 3.0, -3.0):
        b.driver.exchange([x] + q[1:], 0)
        assert lo <= b.driver.last_goals[1] <= hi
        assert b.driver.clamped or not math.isfinite(x)
    b.driver.close()
    assert not any(b.driver.torque)


def test_the_bus_period_line_names_no_option_that_does_not_exist() -> None:
    b = _Bus("dxl2")
    b.driver.start()
    b.driver.bus.baud = 57_600
    line = b.driver.plan(0.002)
    assert line.startswith("servo bus: 6 servos need ") and "at 57600 baud: goals every " in line, line
    assert "--rate" not in line and "lower" not in line
    s = _Bus("sts").driver
    s.start()
    assert s.plan(0.002).endswith("goals every tick (500 Hz)") and s.every == 1


def test_out_of_range_at_start_up_shows_the_calibrated_range() -> None:
    """The range in the line is the calibrated step limits in degrees, not the joint's: the line never
    contradicts itself (at -73.8 deg "outside -100..100")."""
    import struct

    from firmware_sim.servobus.base import BusSetupError
    from robots.hardware import steps_to_rad

    lift = ARM.servos[1]
    cal = Calibration({lift.name: ServoCalibration(lift.id, 0, 1, 1432, 2663)})
    b = _Bus("sts", cal)
    b.model.table(lift.id)[56:58] = struct.pack("<H", 3186)
    with pytest.raises(BusSetupError) as e:
        b.driver.start()
    deg = sorted(math.degrees(steps_to_rad(lift, cal.of(lift), s, ARM.servos.model.resolution)) for s in (1432, 2663))
    at = math.degrees(steps_to_rad(lift, cal.of(lift), 3186, ARM.servos.model.resolution))
    assert f"is at {at:.1f} deg, outside its range {deg[0]:.0f}..{deg[1]:.0f} deg (steps 3186, limits 1432..2663)" \
        in str(e.value), str(e.value)
    assert not deg[0] <= at <= deg[1]
    b.driver.close()


class _LateFirstAnswer(_Bus):
    """Servo 1 answers its first ping late: only when the board has re-sent the ping, just before its answer
    to the second (a realtime plant on a loaded machine, CI 2026-12-07: "answers a ping twice"). ``twin``: every
    ping of servo 1 gets two answers (a real duplicate id)."""

    def __init__(self, protocol: str, twin: bool = False) -> None:
        super().__init__(protocol)
        self.held: bytes | None = None
        self.pings = 0
        self.twin = twin

    def _answer(self, pkt: bytes) -> bytes:
        out = super()._answer(pkt)
        sts = self.model.protocol == "sts"
        dev, inst = (pkt[2], pkt[4]) if sts else (pkt[4], pkt[7])
        if dev != 1 or inst != 0x01:
            return out
        self.pings += 1
        if self.twin:
            return out + out
        if self.pings == 1:
            self.held = out
            return b""
        held, self.held = self.held or b"", None
        return held + out


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_a_late_answer_to_a_re_sent_ping_is_no_duplicate_id(protocol: str) -> None:
    b = _LateFirstAnswer(protocol)
    assert b.driver.start() == pytest.approx([0.0] * N, abs=0.01)
    assert b.pings >= 2
    b.driver.close()


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_two_answers_to_every_ping_are_a_duplicate_id(protocol: str) -> None:
    from firmware_sim.servobus.base import BusSetupError

    b = _LateFirstAnswer(protocol, twin=True)
    with pytest.raises(BusSetupError, match=r"servo 1 \(shoulder_pan\) answers a ping twice"):
        b.driver.start()
