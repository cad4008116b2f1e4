"""Fuzz targets ``bus-sts`` and ``bus-dxl2``: a servo bus answering garbage to the board's bus layer.

The board's motor bus and its safety layer (:class:`~firmware_sim.servobus.driver.BusDriver` over
:class:`~firmware_sim.servobus.feetech.FeetechBus` or :class:`~firmware_sim.servobus.dynamixel.DynamixelBus`,
the vendor SDKs' packet code underneath) talk to an in-memory port (:class:`~firmware_sim.servobus.memport.MemPort`)
whose answers come from the input: well-formed status packets of a small register model (fuzzed
error bits, positions, model numbers), the same mutated (a byte flipped, cut short, sent twice), raw
garbage, or silence. The robot is the arm (6 servos), with a fuzzed calibration.

Input layout (a short read ends the input; the reader is :class:`firmware_sim.fuzz.Reader`)::

    cal u8                       bit k: servo k+1 calibrated by the next fields
      per calibrated servo: offset i16 (mod 512, centred), flags u8 (bit 0: direction -1), min u16, max u16 (mod 4096)
    then per packet the board writes that expects an answer, a control byte c:
      c & 7: 0-3 honest answer, 4 honest with one byte replaced (pos u8, value u8), 5 honest cut at u8,
             6 garbage (n u8 bytes), 7 silence;  c & 8: error bits (u8) in the status; c & 16: the
             answer twice; c & 32: a ping answers another model number
      honest present positions: 2048 + i8 (from the input, the first time a servo is read)
    and between packets, ops (u8 mod 5): 0 tick (6 x i16 commands, x 1e-3 rad), 1 tick with extreme
    commands (nan, +-inf, +-1e9 by u8), 2 ESTOP (u8 bit 0: the limp flavour), 3 ESTOP_CLEAR, 4 ten quiet ticks

Invariants (an ``AssertionError`` names the one that broke): no exception escapes but the
start-up's :class:`~firmware_sim.servobus.base.BusError`; every goal SYNC WRITE on the wire names
only the robot's servos and each goal is inside its servo's calibrated
:func:`robots.hardware.step_limits`; each tick writes exactly one goal SYNC WRITE and at most one
SYNC READ; the driver's state stays bounded (faults, miss counters, the port's buffers).
"""

from __future__ import annotations

import io
import math
import struct
import sys
from collections.abc import Callable

from firmware_sim.fuzz import Reader

__all__ = ["TICKS_PER_INPUT", "load", "main"]

TICKS_PER_INPUT = 60
UNDER_TEST = ("firmware_sim.servobus", "scservo_sdk", "dynamixel_sdk")
_EXTREME = (math.nan, math.inf, -math.inf, 1e9, -1e9, 0.0)


class _Model:
    """The honest side: registers per servo id, answering one protocol's instruction packets."""

    def __init__(self, protocol: str, r: Reader, ids: list[int], model: int) -> None:
        self.protocol, self.r, self.ids, self.model = protocol, r, set(ids), model
        self.tables: dict[int, bytearray] = {}
        self.indirect: dict[int, list[int]] = {}

    def table(self, i: int) -> bytearray:
        t = self.tables.get(i)
        if t is None:
            t = bytearray(256)
            try:
                pos = 2048 + struct.unpack("b", bytes([self.r.take("B")]))[0]
            except EOFError:
                pos = 2048
            t[3:5] = struct.pack("<H", self.model)
            t[0:2] = struct.pack("<H", self.model)
            t[56:58] = struct.pack("<H", pos)  # STS present position
            t[132:136] = struct.pack("<i", pos)  # Dynamixel present position
            self.tables[i] = t
        return t

    def regs(self, i: int, addr: int, n: int) -> bytes:
        t = self.table(i)
        base = 208 if self.model in (1190, 1200, 1210, 1220, 1230, 1240) else 224  # the 330 series' indirect data
        if self.protocol == "dxl2" and addr >= base:
            ind = self.indirect.get(i, [])
            return bytes(t[ind[k - base]] if 0 <= k - base < len(ind) and ind[k - base] < 256 else 0
                         for k in range(addr, addr + n))
        return bytes(t[addr:addr + n]).ljust(n, b"\0")

    def status(self, i: int, err: int, params: bytes) -> bytes:
        if self.protocol == "sts":
            body = bytes([i & 0xFF, len(params) + 2, err & 0x7F]) + params
            return b"\xff\xff" + body + bytes([~sum(body) & 0xFF])
        from dynamixel_sdk import PacketHandler

        n = len(params) + 4
        pkt = list(b"\xff\xff\xfd\x00" + bytes([i & 0xFF, n & 0xFF, n >> 8, 0x55, err & 0xFF]) + params)
        crc = PacketHandler(2.0).updateCRC(0, pkt, len(pkt))
        return bytes(pkt) + bytes([crc & 0xFF, crc >> 8])

    def answer(self, pkt: bytes, err: int, other_model: bool) -> list[bytes] | None:
        """Honest status packets for instruction ``pkt``; None: it needs none (a broadcast write)."""
        sts = self.protocol == "sts"
        if len(pkt) < (6 if sts else 10):
            return None
        i, inst = (pkt[2], pkt[4]) if sts else (pkt[4], pkt[7])
        p = pkt[5:-1] if sts else pkt[8:-2]
        if inst == 0x83:  # SYNC WRITE: the goals become the present positions (the servos got there)
            addr, n, k = (p[0], p[1], 2) if sts else (p[0] | p[1] << 8, p[2] | p[3] << 8, 4)
            goal = 42 if sts else 116
            while n and k + n < len(p) + 1 and addr == goal:
                t = self.table(p[k])
                if sts:
                    t[56:58] = p[k + 1:k + 3]
                else:
                    t[132:136] = p[k + 1:k + 5]
                k += n + 1
            return None
        if inst == 0x82:  # SYNC READ
            addr, n, ids = (p[0], p[1], p[2:]) if sts else (p[0] | p[1] << 8, p[2] | p[3] << 8, p[4:])
            return [self.status(j, err, self.regs(j, addr, n)) for j in ids if j in self.ids]
        if i not in self.ids:
            return []
        if inst == 1:
            model = self.model ^ 0x55 if other_model else self.model
            return [self.status(i, err, b"" if sts else struct.pack("<HB", model, 0x2E))]
        if inst == 2 and len(p) >= (2 if sts else 4):
            addr, n = (p[0], p[1]) if sts else (p[0] | p[1] << 8, p[2] | p[3] << 8)
            return [self.status(i, err, self.regs(i, addr, min(n, 64)))]
        if inst == 3:
            if not sts and len(p) >= 2 and (p[0] | p[1] << 8) == 168:
                data = p[2:]
                self.indirect[i] = [data[k] | data[k + 1] << 8 for k in range(0, len(data) - 1, 2)]
            elif len(p) >= (2 if sts else 3):  # any other WRITE lands in the table (the return delay)
                addr, data = (p[0], p[1:]) if sts else (p[0] | p[1] << 8, p[2:])
                t = self.table(i)
                if addr + len(data) <= len(t):
                    t[addr:addr + len(data)] = data
            return [self.status(i, err, b"")]
        return []


def load(protocol: str, instrument: bool = False) -> Callable[[bytes], None]:
    """The one-input function of the ``bus-<protocol>`` target (``protocol``: ``"sts"`` or ``"dxl2"``)."""
    if instrument:
        from firmware_sim.fuzz import _instrument_only

        with _instrument_only(UNDER_TEST):
            import firmware_sim.servobus.driver  # noqa: F401
            import firmware_sim.servobus.dynamixel  # noqa: F401
            import firmware_sim.servobus.feetech  # noqa: F401
    from firmware_sim.servobus import BusError, make_bus
    from firmware_sim.servobus.driver import BusDriver
    from firmware_sim.servobus.memport import MAX_PENDING, MemPort
    from robots.datatypes import RobotDataError
    from robots.hardware import DEFAULT_MODEL, Calibration, Hardware, ServoCalibration
    from robots.registry import load_robot

    robot = load_robot("arm")
    servos = list(robot.servos)
    ids = [s.id for s in servos]
    model = DEFAULT_MODEL[protocol]
    hardware = Hardware("sts" if protocol == "sts" else "dxl2", 1_000_000, model)
    sts = protocol == "sts"
    goal_addr, goal_n = (42, 2) if sts else (116, 4)

    def one_input(data: bytes) -> None:
        r = Reader(data)
        cals: dict[str, ServoCalibration] = {}
        try:
            mask = r.take("B")
            for k, s in enumerate(servos):
                if mask >> k & 1:
                    off = r.take("h") % 512 - 256
                    flags = r.take("B")
                    lo, hi = r.take("H") % 4096, r.take("H") % 4096
                    cals[s.name] = ServoCalibration(s.id, off, -1 if flags & 1 else 1, min(lo, hi), max(lo, hi))
        except EOFError:
            pass
        honest = _Model(protocol, r, ids, model)
        tick_log: list[bytes] = []

        def answer(pkt: bytes) -> bytes:
            tick_log.append(pkt)
            inst = pkt[4] if sts and len(pkt) > 4 else pkt[7] if len(pkt) > 7 else 0
            if inst == 0x83:
                check_goals(pkt)
                honest.answer(pkt, 0, False)
                return b""
            try:
                c = r.take("B")
                err = r.take("B") if c & 8 else 0
                kind = c & 7
                if kind == 6:
                    return r.raw(r.take("B"))
                if kind == 7:
                    return b""
                out = b"".join(honest.answer(pkt, err, bool(c & 32)) or [])
                if kind == 4 and out:
                    b = bytearray(out)
                    b[r.take("B") % len(b)] = r.take("B")
                    out = bytes(b)
                elif kind == 5:
                    out = out[:r.take("B")]
                return out * 2 if c & 16 else out
            except EOFError:
                return b""

        def check_goals(pkt: bytes) -> None:
            p = pkt[5:-1] if sts else pkt[8:-2]
            if len(p) < (2 if sts else 4):
                return
            addr, n, k = (p[0], p[1], 2) if sts else (p[0] | p[1] << 8, p[2] | p[3] << 8, 4)
            if addr != goal_addr:
                return
            assert n == goal_n, f"goal SYNC WRITE of {n} bytes"
            assert (len(p) - k) % (n + 1) == 0, "goal SYNC WRITE with a partial entry"
            for j in range(k, len(p), n + 1):
                sid, goal = p[j], int.from_bytes(p[j + 1:j + 1 + n], "little", signed=not sts)
                assert sid in ids, f"goal for servo id {sid}, not the robot's"
                lo, hi = driver.limits[ids.index(sid)]
                assert lo <= goal <= hi, f"goal {goal} for servo {sid} outside its step limits {lo}..{hi}"

        port = MemPort(answer)
        bus = make_bus(protocol, "mem", 1_000_000, port_handler=port)
        try:
            driver = BusDriver(bus, robot, hardware, Calibration(cals), estop_torque="hold", err=io.StringIO())
        except RobotDataError:
            return  # a calibration whose range misses the joint's: the board refuses it at start-up
        try:
            driver.start()
        except BusError:
            driver.close()
            return
        driver.torque_on()
        ticks = 0
        t_us = 0
        try:
            while ticks < TICKS_PER_INPUT:
                op = r.take("B") % 5
                if op in (0, 1, 4):
                    for _ in range(10 if op == 4 else 1):
                        if op == 0:
                            cmd = [r.take("h") * 1e-3 for _ in servos]
                        elif op == 1:
                            cmd = [_EXTREME[r.take("B") % len(_EXTREME)] for _ in servos]
                        else:
                            cmd = driver.measured().positions
                        tick_log.clear()
                        driver.exchange(cmd, t_us)
                        t_us += 2000
                        ticks += 1
                        kinds = [pkt[4] if sts else pkt[7] for pkt in tick_log if len(pkt) > 7]
                        writes = sum(1 for pkt in tick_log if len(pkt) > 8 and (pkt[4] if sts else pkt[7]) == 0x83
                                     and (pkt[5] if sts else pkt[8] | pkt[9] << 8) == goal_addr)
                        assert writes == 1, f"a tick wrote {writes} goal SYNC WRITEs"
                        assert kinds.count(0x82) <= 1, "a tick sent more than one SYNC READ"
                        assert len(driver.faults) <= 64 and all(m <= ticks for m in driver.miss)
                        assert len(port.rx) <= MAX_PENDING
                elif op == 2:
                    driver.estop_torque = "limp" if r.take("B") & 1 else "hold"
                    driver.on_estop()
                else:
                    driver.on_clear()
                driver.take_faults()
        except EOFError:
            pass
        finally:
            driver.close()
        assert not driver.torque.count(True), "torque left on after close"

    return one_input


def main(protocol: str) -> None:
    """``python -m firmware_sim.servobus.fuzz_<protocol> [libFuzzer flags] [corpus dirs]``."""
    import atheris  # type: ignore[import-not-found,unused-ignore]

    mod = "fuzz_sts" if protocol == "sts" else "fuzz_dxl2"
    atheris.Setup([f"{sys.executable} -m firmware_sim.servobus.{mod}", *sys.argv[1:]], load(protocol, True))
    atheris.Fuzz()
