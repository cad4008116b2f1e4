"""The CAN form comes from the one message declaration (protocol.codec: LAYOUTS + CAN_FIXED).

Proof that deriving the fixed CAN layouts and the raw signal values from the declaration changed
nothing: below is a **frozen copy** of the hand-written table generator and of the hand-written
``message_to_raw`` / ``raw_to_message`` as they were before (kept only here, never imported by the
library). For every servo count 1..32 the derived tables equal the frozen ones, every robot's DBC
(classic and FD, 1..32 servos) hashes as before, and hypothesis finds no message or raw value on
which the derived codec and the frozen one differ. Then: a field added to a declared layout reaches
the CAN signals without touching protocol.can.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol import codec as c
from protocol import messages as m
from protocol.can.codec import message_to_raw, raw_to_message
from protocol.can.frame import fd_length
from protocol.can.ids import FunctionCode
from protocol.can.layouts import (
    CLASSIC_PART_BITS,
    FD_PART_BITS,
    HEADER_BITS,
    MAX_PARTS,
    FixedLayout,
    Placed,
    SignalSpec,
    can_layouts,
    message_signals,
)
from protocol.can.make_dbc import DbcRobot, dbc_text
from protocol.codec import PayloadError, _as_int, _q16_decode, _q16_encode, msg_type_of
from protocol.messages import MAX_WIRE_SERVOS, Message, MsgType

# --- frozen copy of protocol/can/layouts.py's hand-written table (before the declaration) ------


class _TooManyParts(ValueError):
    pass


def _place(signals: list[SignalSpec], part_bits: int) -> tuple[list[Placed], int, list[int]]:
    placed: list[Placed] = []
    part, used = 0, 0
    used_by_part = [0]
    for s in signals:
        if used + s.bits > part_bits:
            part, used = part + 1, 0
            used_by_part.append(0)
        placed.append(Placed(s, part, HEADER_BITS + used))
        used += s.bits
        used_by_part[part] = used
    nparts = part + 1
    if nparts > MAX_PARTS:
        raise _TooManyParts
    return placed, nparts, [(HEADER_BITS + u + 7) // 8 for u in used_by_part]


def _q16(name: str, scale: float, unit: str) -> SignalSpec:
    return SignalSpec(name, 16, True, scale, unit, "int16; -32768 = unknown (NaN)")


U48_TIME = "u48 microseconds (clamped)"


def _frozen_signals(n: int) -> dict[MsgType, tuple[FunctionCode, list[SignalSpec]]]:
    mask_bits = 16 if n <= 16 else 32
    names = [f"{i + 1:02d}" for i in range(n)]
    return {
        MsgType.ESTOP: (FunctionCode.ESTOP, []),
        MsgType.ESTOP_CLEAR: (FunctionCode.ESTOP_CLEAR, []),
        MsgType.SERVO_FRAME: (
            FunctionCode.SERVO_FRAME,
            [
                SignalSpec("apply_at_us", 32, unit="us", comment="board clock modulo 2**32"),
                SignalSpec("mask", mask_bits, comment="bit i = servo i+1 present"),
                *[_q16(f"target_{k}", 1e-4, "rad") for k in names],
            ],
        ),
        MsgType.TIME_SYNC_REQUEST: (FunctionCode.TIME_SYNC_REQUEST,
                                    [SignalSpec("t1_host_us", 48, unit="us", comment=U48_TIME)]),
        MsgType.TIME_SYNC_REPLY: (
            FunctionCode.TIME_SYNC_REPLY,
            [SignalSpec(k, 48, unit="us", comment=U48_TIME) for k in ("t1_host_us", "t2_board_us", "t3_board_us")],
        ),
        MsgType.FLUSH: (
            FunctionCode.FLUSH,
            [SignalSpec("from_us", 48, unit="us", comment=U48_TIME),
             SignalSpec("mask", mask_bits, comment="bit i = servo i+1")],
        ),
        MsgType.ADVANCE: (FunctionCode.ADVANCE, [SignalSpec("until_us", 48, unit="us", comment=U48_TIME)]),
        MsgType.ACK: (FunctionCode.ACK, [SignalSpec("ack_seq", 16), SignalSpec("msg_type", 8)]),
        MsgType.NACK: (FunctionCode.NACK,
                       [SignalSpec("ack_seq", 16), SignalSpec("msg_type", 8), SignalSpec("reason", 8)]),
        MsgType.TELEMETRY: (
            FunctionCode.TELEMETRY,
            [
                SignalSpec("board_time_us", 48, unit="us", comment=U48_TIME),
                *[_q16(f"position_{k}", 1e-4, "rad") for k in names],
                *[_q16(f"velocity_{k}", 1e-3, "rad/s") for k in names],
                *[_q16(f"effort_{k}", 1e-3, "N*m") for k in names],
                _q16("imu_roll", 1e-4, "rad"),
                _q16("imu_pitch", 1e-4, "rad"),
                _q16("imu_yaw", 1e-4, "rad"),
                SignalSpec("faults", 16, comment="FaultFlags"),
                SignalSpec("buffer_fill", 16),
                SignalSpec("last_applied_seq", 16),
                SignalSpec("late_count", 24, comment="clamped"),
                SignalSpec("dropped_count", 24, comment="clamped"),
                SignalSpec("link_errors", 24, comment="clamped"),
            ],
        ),
    }


HEARTBEAT_SIGNALS = [SignalSpec("sender_time_us", 48, unit="us", comment=U48_TIME)]
CRC_SPEC = SignalSpec("crc16", 16, comment="CRC-16/X-25 over every part of the message with this field zero")


def _frozen_build(msg_type: MsgType, fn: FunctionCode, signals: list[SignalSpec], fd: bool, n: int) -> FixedLayout:
    if signals:
        signals = [*signals, CRC_SPEC]
    placed, nparts, part_bytes = _place(signals, FD_PART_BITS if fd else CLASSIC_PART_BITS)
    longest = max(part_bytes)
    length = fd_length(longest) if fd else (8 if nparts > 1 else longest)
    return FixedLayout(msg_type, fn, fd, tuple(placed), nparts, length, tuple(part_bytes), n)


def _frozen_table(n: int) -> dict[tuple[FunctionCode, bool], FixedLayout]:
    out: dict[tuple[FunctionCode, bool], FixedLayout] = {}
    for fd in (False, True):
        for t, (fn, sigs) in _frozen_signals(n).items():
            try:
                out[(fn, fd)] = _frozen_build(t, fn, sigs, fd, n)
            except _TooManyParts:
                continue
        for fn in (FunctionCode.HEARTBEAT_HOST, FunctionCode.HEARTBEAT_BOARD):
            out[(fn, fd)] = _frozen_build(MsgType.HEARTBEAT, fn, HEARTBEAT_SIGNALS, fd, n)
    return out


# --- frozen copy of protocol/can/codec.py's hand-written raw values ---------------------------

_U48 = (1 << 48) - 1
_U24 = (1 << 24) - 1


def _clamp(name: str, v: Any, hi: int) -> int:
    return min(max(_as_int(name, v, 0, hi), 0), hi)


def _servo_values(name: str, values: Any, cpu: int, n: int) -> list[int]:
    vals = list(values)
    if len(vals) > n:
        raise PayloadError(f"{name}: {len(vals)} values, the CAN layout carries {n}")
    try:
        codes = [_q16_encode(v, cpu) for v in vals]
    except (TypeError, ValueError):
        raise PayloadError(f"{name}: values must be numbers") from None
    return codes + [-32768] * (n - len(codes))


def _frozen_to_raw(msg: Message, n: int) -> dict[str, int]:
    t = msg_type_of(msg)
    raw: dict[str, int] = {}
    if isinstance(msg, m.ServoFrame):
        mask = _as_int("mask", msg.mask, -1, 1 << 32)
        if mask < 0 or mask >> n:
            raise PayloadError(f"SERVO_FRAME: mask {mask:#x} has bits outside the {n} CAN servos")
        targets = list(msg.targets)
        if len(targets) != mask.bit_count():
            raise PayloadError(f"SERVO_FRAME: {len(targets)} target(s) but popcount(mask) = {mask.bit_count()}")
        raw["apply_at_us"] = _as_int("apply_at_us", msg.apply_at_us, 0, 1 << 32) & 0xFFFF_FFFF
        raw["mask"] = mask
        it = iter(targets)
        for i in range(n):
            if mask >> i & 1:
                v = next(it)
                try:
                    code = _q16_encode(v, 10_000)
                except (TypeError, ValueError):
                    raise PayloadError(f"SERVO_FRAME: target {v!r} is not a number") from None
                if code == -32768:
                    raise PayloadError("SERVO_FRAME: NaN target is not allowed")
            else:
                code = -32768
            raw[f"target_{i + 1:02d}"] = code
    elif isinstance(msg, m.TimeSyncRequest):
        raw["t1_host_us"] = _clamp("t1_host_us", msg.t1_host_us, _U48)
    elif isinstance(msg, m.TimeSyncReply):
        for k in ("t1_host_us", "t2_board_us", "t3_board_us"):
            raw[k] = _clamp(k, getattr(msg, k), _U48)
    elif isinstance(msg, m.Flush):
        bits = 16 if n <= 16 else 32
        mask = _as_int("mask", msg.mask, -1, 1 << bits)
        if mask < 0 or mask >> bits:
            raise PayloadError(f"FLUSH: mask {mask:#x} does not fit {bits} bits")
        raw["from_us"] = _clamp("from_us", msg.from_us, _U48)
        raw["mask"] = mask
    elif isinstance(msg, m.Advance):
        raw["until_us"] = _clamp("until_us", msg.until_us, _U48)
    elif isinstance(msg, m.Heartbeat):
        raw["sender_time_us"] = _clamp("sender_time_us", msg.sender_time_us, _U48)
    elif isinstance(msg, (m.Ack, m.Nack)):
        raw["ack_seq"] = _as_int("ack_seq", msg.ack_seq, 0, 1 << 16) & 0xFFFF
        try:
            raw["msg_type"] = int(MsgType(msg.msg_type))
            if isinstance(msg, m.Nack):
                raw["reason"] = int(m.NackReason(msg.reason))
        except ValueError as e:
            raise PayloadError(f"{t.name}: {e}") from None
    elif isinstance(msg, m.Telemetry):
        raw["board_time_us"] = _clamp("board_time_us", msg.board_time_us, _U48)
        for prefix, values, cpu in (("position", msg.positions, 10_000), ("velocity", msg.velocities, 1_000),
                                    ("effort", msg.efforts, 1_000)):
            for i, code in enumerate(_servo_values(prefix, values, cpu, n)):
                raw[f"{prefix}_{i + 1:02d}"] = code
        rpy = list(msg.imu_rpy)
        if len(rpy) != 3:
            raise PayloadError(f"TELEMETRY: imu_rpy needs 3 values, got {len(rpy)}")
        for k, v in zip(("imu_roll", "imu_pitch", "imu_yaw"), rpy):
            raw[k] = _q16_encode(v, 10_000)
        faults = _as_int("faults", msg.faults, -1, 1 << 16)
        if faults < 0 or faults > 0xFFFF:
            raise PayloadError(f"TELEMETRY: faults {faults:#x} do not fit 16 bits")
        raw["faults"] = faults
        raw["buffer_fill"] = _clamp("buffer_fill", msg.buffer_fill, 0xFFFF)
        raw["last_applied_seq"] = _as_int("last_applied_seq", msg.last_applied_seq, 0, 1 << 16) & 0xFFFF
        for k in ("late_count", "dropped_count", "link_errors"):
            raw[k] = _clamp(k, getattr(msg, k), _U24)
    elif isinstance(msg, (m.Estop, m.EstopClear)):
        pass
    else:
        raise PayloadError(f"{t.name} has no fixed CAN layout")
    return raw


def _frozen_to_message(msg_type: MsgType, raw: dict[str, int], n: int) -> Message:
    if msg_type is MsgType.SERVO_FRAME:
        mask = raw["mask"]
        if mask >> n:
            raise PayloadError(f"SERVO_FRAME: mask {mask:#x} has bits outside the {n} CAN servos")
        codes = [raw[f"target_{i + 1:02d}"] for i in range(n) if mask >> i & 1]
        if -32768 in codes:
            raise PayloadError("SERVO_FRAME: targets: reserved code -32768 (NaN) is not allowed here")
        return m.ServoFrame(raw["apply_at_us"], mask, tuple(_q16_decode(c_, 10_000) for c_ in codes))
    if msg_type is MsgType.TIME_SYNC_REQUEST:
        return m.TimeSyncRequest(raw["t1_host_us"])
    if msg_type is MsgType.TIME_SYNC_REPLY:
        return m.TimeSyncReply(raw["t1_host_us"], raw["t2_board_us"], raw["t3_board_us"])
    if msg_type is MsgType.FLUSH:
        return m.Flush(raw["from_us"], raw["mask"])
    if msg_type is MsgType.ADVANCE:
        return m.Advance(raw["until_us"])
    if msg_type is MsgType.HEARTBEAT:
        return m.Heartbeat(raw["sender_time_us"])
    if msg_type in (MsgType.ACK, MsgType.NACK):
        try:
            mt = MsgType(raw["msg_type"])
            if msg_type is MsgType.ACK:
                return m.Ack(raw["ack_seq"], mt)
            return m.Nack(raw["ack_seq"], mt, m.NackReason(raw["reason"]), "")
        except ValueError as e:
            raise PayloadError(f"{msg_type.name}: {e}") from None
    if msg_type is MsgType.TELEMETRY:
        def arr(prefix: str, cpu: int) -> tuple[float, ...]:
            return tuple(_q16_decode(raw[f"{prefix}_{i + 1:02d}"], cpu) for i in range(n))

        rpy = tuple(_q16_decode(raw[k], 10_000) for k in ("imu_roll", "imu_pitch", "imu_yaw"))
        return m.Telemetry(raw["board_time_us"], arr("position", 10_000), arr("velocity", 1_000),
                           arr("effort", 1_000), (rpy[0], rpy[1], rpy[2]), m.FaultFlags(raw["faults"]),
                           raw["buffer_fill"], raw["last_applied_seq"], raw["late_count"], raw["dropped_count"],
                           raw["link_errors"])
    if msg_type is MsgType.ESTOP:
        return m.Estop()
    if msg_type is MsgType.ESTOP_CLEAR:
        return m.EstopClear()
    raise PayloadError(f"{msg_type.name} has no fixed CAN layout")


# --- the derived tables are the frozen ones --------------------------------------------------


@pytest.mark.parametrize("n", range(1, MAX_WIRE_SERVOS + 1))
def test_derived_table_is_the_hand_written_one(n: int) -> None:
    derived = dict(can_layouts(n).fixed)
    frozen = _frozen_table(n)
    assert sorted(derived, key=lambda k: (int(k[0]), k[1])) == sorted(frozen, key=lambda k: (int(k[0]), k[1]))
    for key, layout in frozen.items():
        assert derived[key] == layout, (n, key)
        # float scales equal exactly (1/10000 == 1e-4 as doubles), so the DBC text cannot change either
        assert [p.spec.scale for p in derived[key].signals] == [p.spec.scale for p in layout.signals]


#: SHA-256 over dbc_text(fd, (1, 2), robot=DbcRobot(f"chain{n}", f"Chain {n}", n)) for n = 1..32, fd False
#: then True: computed from the hand-written table before the declaration took over.
DBC_DIGEST_BEFORE = "3882f883481eb34482d24f30e775752bf535b75f735b949598c5e40f857f4c5a"


def test_every_robots_dbc_is_unchanged() -> None:
    h = hashlib.sha256()
    for n in range(1, MAX_WIRE_SERVOS + 1):
        for fd in (False, True):
            h.update(dbc_text(fd, (1, 2), robot=DbcRobot(f"chain{n}", f"Chain {n}", n)).encode())
    assert h.hexdigest() == DBC_DIGEST_BEFORE


# --- the derived raw values are the frozen ones ----------------------------------------------

FIXED_TYPES = [MsgType.SERVO_FRAME, MsgType.TIME_SYNC_REQUEST, MsgType.TIME_SYNC_REPLY, MsgType.FLUSH,
               MsgType.ADVANCE, MsgType.HEARTBEAT, MsgType.ACK, MsgType.NACK, MsgType.TELEMETRY, MsgType.ESTOP,
               MsgType.ESTOP_CLEAR]
TIMES = st.one_of(st.integers(-5, 1 << 50), st.integers(0, (1 << 64) - 1), st.floats(-1e3, 1e16, allow_nan=False))
Q = st.one_of(st.floats(-40, 40, allow_nan=False), st.just(math.nan), st.floats(allow_nan=False))
SMALL = st.one_of(st.integers(-3, 1 << 34), st.floats(-10, 1e11, allow_nan=False))


@st.composite
def _fixed_message(draw: st.DrawFn, n: int) -> Message:
    t = draw(st.sampled_from(FIXED_TYPES))
    if t is MsgType.SERVO_FRAME:
        mask = draw(st.one_of(st.integers(0, (1 << n) - 1), st.integers(-2, (1 << 33))))
        k = max(mask, 0).bit_count() + draw(st.sampled_from([0, 0, 0, 1, -1]))
        targets = draw(st.lists(st.one_of(st.floats(-4, 4, allow_nan=False), st.just(math.nan)),
                                min_size=max(k, 0), max_size=max(k, 0)))
        return m.ServoFrame(draw(st.one_of(TIMES, st.integers(-(1 << 40), 0))), mask, tuple(targets))
    if t is MsgType.FLUSH:
        return m.Flush(draw(TIMES), draw(st.integers(-2, 1 << 33)))
    if t is MsgType.TELEMETRY:
        def arr() -> tuple[float, ...]:
            return tuple(draw(st.lists(Q, max_size=n + draw(st.sampled_from([0, 0, 1])))))
        rpy = tuple(draw(st.lists(Q, min_size=draw(st.sampled_from([3, 3, 3, 2])), max_size=3)))
        return m.Telemetry(draw(TIMES), arr(), arr(), arr(), rpy,  # type: ignore[arg-type]
                           draw(st.integers(-1, 1 << 17)), draw(SMALL), draw(SMALL), draw(SMALL), draw(SMALL),
                           draw(SMALL))
    if t in (MsgType.ACK, MsgType.NACK):
        mt = draw(st.one_of(st.sampled_from(list(MsgType)), st.integers(0, 255)))
        if t is MsgType.ACK:
            return m.Ack(draw(SMALL), mt)
        return m.Nack(draw(SMALL), mt, draw(st.one_of(st.sampled_from(list(m.NackReason)), st.integers(0, 255))), "")
    if t is MsgType.TIME_SYNC_REPLY:
        return m.TimeSyncReply(draw(TIMES), draw(TIMES), draw(TIMES))
    cls = c.MESSAGE_CLASSES[t]
    return cls(*[draw(TIMES) for _ in c.LAYOUTS[t]])  # type: ignore[no-any-return]


def _same(a: object, b: object) -> bool:
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(_same(getattr(a, f.name), getattr(b, f.name))
                                          for f in dataclasses.fields(a))
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    if isinstance(a, tuple) and isinstance(b, tuple):
        return type(a) is type(b) and len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def _outcome(fn: Any, *args: Any) -> tuple[str, Any]:
    try:
        return "ok", fn(*args)
    except PayloadError:
        return "refused", None


SETTINGS = settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(data=st.data(), n=st.integers(1, MAX_WIRE_SERVOS))
def test_raw_values_as_the_hand_written_codec(data: st.DataObject, n: int) -> None:
    msg = data.draw(_fixed_message(n))
    want = _outcome(_frozen_to_raw, msg, n)
    got = _outcome(message_to_raw, msg, can_layouts(n))
    assert got == want, msg


@SETTINGS
@given(data=st.data(), n=st.integers(1, MAX_WIRE_SERVOS), fd=st.booleans())
def test_messages_from_raw_values_as_the_hand_written_codec(data: st.DataObject, n: int, fd: bool) -> None:
    table = can_layouts(n)
    layout = data.draw(st.sampled_from([lay for lay in table.fixed.values() if lay.fd == fd]))
    raw = {}
    for p in layout.signals:
        s = p.spec
        lo, hi = (-(1 << (s.bits - 1)), (1 << (s.bits - 1)) - 1) if s.signed else (0, (1 << s.bits) - 1)
        small = st.integers(0, 0x35) if s.bits == 8 else st.nothing()  # enum members (MsgType, NackReason)
        raw[s.name] = data.draw(st.one_of(st.integers(lo, hi), st.sampled_from([lo, hi, 0]), small, small))
    want = _outcome(_frozen_to_message, layout.msg_type, raw, n)
    got = _outcome(raw_to_message, layout.msg_type, raw, table)
    assert got[0] == want[0] and _same(got[1], want[1]), (raw, got, want)


# --- one declaration: a field added to a layout reaches CAN ----------------------------------


def test_a_field_added_to_the_declaration_becomes_a_signal() -> None:
    layout = [*c.WIRE_SCHEMA_16.layouts[MsgType.TELEMETRY], ("brownouts", c.UInt(4))]
    plain = message_signals(MsgType.TELEMETRY, c.WIRE_SCHEMA_16.layouts[MsgType.TELEMETRY], {}, 12)
    plus = message_signals(MsgType.TELEMETRY, layout, {}, 12)
    assert [s.name for s in plus] == [s.name for s in plain] + ["brownouts"]
    assert plus[-1] == SignalSpec("brownouts", 32)
    narrowed = message_signals(MsgType.TELEMETRY, layout, {"brownouts": c.CanField(bits=24, clamped=True)}, 12)
    assert narrowed[-1] == SignalSpec("brownouts", 24, comment="clamped")
    with pytest.raises(ValueError, match="SIM_STATE.base_pos: .*no fixed CAN form"):
        message_signals(MsgType.SIM_STATE, c.LAYOUTS[MsgType.SIM_STATE], {}, 12)
