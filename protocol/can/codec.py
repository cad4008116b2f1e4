"""Messages <-> CAN frames: fixed layouts for the real-time path, an ISO-TP envelope for bulk.

``encode_fixed(msg, seq, node, fd=False, sender=..., layouts=None)`` -> the frames of one
fixed-layout message (``PayloadError`` if it has none or is invalid); ``encode_bulk(msg, seq,
schema=None)`` -> the ISO-TP service data unit ``type u8 | seq u16 LE | protocol.codec payload |
CRC-16/X-25 u16 LE`` for any message; ``decode_bulk`` is its inverse. ``is_fixed(msg, fd, layouts)``
says which path a message takes: HELLO/CAPS, CONFIG, SCREEN, SPEAKER, CAMERA_*, SIM_STATE and a
NACK with a detail text go as bulk, and so does a message the robot's layout table has no fixed
layout for in that frame kind (classic-CAN TELEMETRY above 27 servos); everything else as fixed
frames. Raw signal values (``message_to_raw`` / ``raw_to_message``) are what the DBC describes.

``layouts`` is the robot's table (:func:`protocol.can.layouts.can_layouts`); None means the default
table (:data:`protocol.can.layouts.DEFAULT_SERVO_COUNT` servos). Bulk payloads use the table's
serial schema (``layouts.schema``).
"""

from __future__ import annotations

import math
import struct
from functools import lru_cache
from typing import Any

from protocol import messages as m
from protocol.codec import (
    WIRE_SCHEMA_16,
    PayloadError,
    WireSchema,
    _q16_decode,
    _q16_encode,
    _as_int,
    msg_type_of,
)
from protocol.can.frame import CanFrame
from protocol.can.ids import FunctionCode, cob_id
from protocol.can.layouts import CRC_SIGNAL, SEQ_MASK, CanLayouts, FixedLayout, can_layouts
from protocol.framing import crc16
from protocol.messages import Message, MsgType

__all__ = [
    "BULK_HEADER",
    "Sender",
    "decode_bulk",
    "encode_bulk",
    "encode_fixed",
    "fixed_crc",
    "fixed_layout_for",
    "is_fixed",
    "message_to_raw",
    "pack_part",
    "raw_to_message",
    "unpack_part",
]

BULK_HEADER = struct.Struct("<BH")  # message type, sequence


class Sender:
    HOST = "host"
    BOARD = "board"


_FN_OF_TYPE: dict[MsgType, FunctionCode] = {
    MsgType.ESTOP: FunctionCode.ESTOP,
    MsgType.ESTOP_CLEAR: FunctionCode.ESTOP_CLEAR,
    MsgType.SERVO_FRAME: FunctionCode.SERVO_FRAME,
    MsgType.TIME_SYNC_REQUEST: FunctionCode.TIME_SYNC_REQUEST,
    MsgType.TIME_SYNC_REPLY: FunctionCode.TIME_SYNC_REPLY,
    MsgType.FLUSH: FunctionCode.FLUSH,
    MsgType.ADVANCE: FunctionCode.ADVANCE,
    MsgType.ACK: FunctionCode.ACK,
    MsgType.NACK: FunctionCode.NACK,
    MsgType.TELEMETRY: FunctionCode.TELEMETRY,
}

_U48 = (1 << 48) - 1
_U24 = (1 << 24) - 1


def _table(layouts: CanLayouts | None) -> CanLayouts:
    return can_layouts() if layouts is None else layouts


def _fn_of(msg_type: MsgType, sender: str) -> FunctionCode | None:
    if msg_type is MsgType.HEARTBEAT:
        return FunctionCode.HEARTBEAT_HOST if sender == Sender.HOST else FunctionCode.HEARTBEAT_BOARD
    return _FN_OF_TYPE.get(msg_type)


def is_fixed(msg: Message, fd: bool = False, layouts: CanLayouts | None = None) -> bool:
    """True when ``msg`` travels in fixed-layout frames of this frame kind (classic or FD) with the
    robot's ``layouts``, False when it goes as bulk (ISO-TP)."""
    t = msg_type_of(msg)
    if t is MsgType.NACK and msg.detail:  # type: ignore[union-attr]
        return False
    fn = _fn_of(t, Sender.HOST)
    return fn is not None and _table(layouts).layout(fn, fd) is not None


def fixed_layout_for(msg_type: MsgType, fd: bool, sender: str = Sender.HOST,
                     layouts: CanLayouts | None = None) -> FixedLayout:
    """The layout a message type uses (``PayloadError`` if it has no fixed layout)."""
    fn = _fn_of(msg_type, sender)
    layout = None if fn is None else _table(layouts).layout(fn, fd)
    if layout is None:
        raise PayloadError(f"{msg_type.name} has no fixed CAN layout"
                           + ("" if fn is None else f" for {_table(layouts).servo_count} servos on "
                              f"{'CAN FD' if fd else 'classic CAN'}") + " (it goes as ISO-TP bulk)")
    return layout


# --- raw signal values -----------------------------------------------------------------------


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


def message_to_raw(msg: Message, layouts: CanLayouts | None = None) -> dict[str, int]:
    """Raw (integer) signal values of a fixed-layout message, keyed by DBC signal name."""
    t = msg_type_of(msg)
    table = _table(layouts)
    n = table.servo_count
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
        bits = table.mask_bits
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
        for prefix, values, cpu in (
            ("position", msg.positions, 10_000),
            ("velocity", msg.velocities, 1_000),
            ("effort", msg.efforts, 1_000),
        ):
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


def raw_to_message(msg_type: MsgType, raw: dict[str, int], layouts: CanLayouts | None = None) -> Message:
    """Inverse of :func:`message_to_raw` (``PayloadError`` on values the message cannot hold)."""
    n = _table(layouts).servo_count
    if msg_type is MsgType.SERVO_FRAME:
        mask = raw["mask"]
        if mask >> n:
            raise PayloadError(f"SERVO_FRAME: mask {mask:#x} has bits outside the {n} CAN servos")
        codes = [raw[f"target_{i + 1:02d}"] for i in range(n) if mask >> i & 1]
        if -32768 in codes:  # as protocol.codec: a target has no "unknown" (there is no safe value for it)
            raise PayloadError("SERVO_FRAME: targets: reserved code -32768 (NaN) is not allowed here")
        targets = tuple(_q16_decode(c, 10_000) for c in codes)
        return m.ServoFrame(raw["apply_at_us"], mask, targets)
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

        rpy = tuple(_q16_decode(raw[n], 10_000) for n in ("imu_roll", "imu_pitch", "imu_yaw"))
        return m.Telemetry(
            raw["board_time_us"],
            arr("position", 10_000),
            arr("velocity", 1_000),
            arr("effort", 1_000),
            (rpy[0], rpy[1], rpy[2]),
            m.FaultFlags(raw["faults"]),
            raw["buffer_fill"],
            raw["last_applied_seq"],
            raw["late_count"],
            raw["dropped_count"],
            raw["link_errors"],
        )
    if msg_type is MsgType.ESTOP:
        return m.Estop()
    if msg_type is MsgType.ESTOP_CLEAR:
        return m.EstopClear()
    raise PayloadError(f"{msg_type.name} has no fixed CAN layout")


# --- frames ------------------------------------------------------------------------------------


@lru_cache(maxsize=None)
def _part_signals(layout: FixedLayout, part: int) -> tuple[tuple[str, int, int, bool, int], ...]:
    """(name, start bit, bits, signed, bit mask) of the signals in one part (cached per layout)."""
    return tuple(
        (p.spec.name, p.start, p.spec.bits, p.spec.signed, (1 << p.spec.bits) - 1) for p in layout.signals if p.part == part
    )


def pack_part(layout: FixedLayout, part: int, seq: int, raw: dict[str, int]) -> bytes:
    """Data bytes of part ``part`` of a message (``layout.length`` bytes, unused bits zero)."""
    word = (part & 0x1F) | ((seq & SEQ_MASK) << 5)
    for name, start, _bits, _signed, mask in _part_signals(layout, part):
        word |= (int(raw[name]) & mask) << start
    return word.to_bytes(layout.length, "little")


def unpack_part(layout: FixedLayout, part: int, data: bytes) -> dict[str, int]:
    """Raw signal values of one part's data (the caller checked the length)."""
    word = int.from_bytes(data, "little")
    out: dict[str, int] = {}
    for name, start, bits, signed, mask in _part_signals(layout, part):
        v = (word >> start) & mask
        if signed and v >> (bits - 1):
            v -= 1 << bits
        out[name] = v
    return out


def fixed_crc(layout: FixedLayout, seq: int, raw: dict[str, int]) -> int:
    """CRC-16/X-25 of a message with a ``crc16`` signal: over the data bytes of all its parts (in
    part order, headers included) packed with ``crc16`` = 0 (layout in :mod:`protocol.can.layouts`)."""
    zeroed = {**raw, CRC_SIGNAL: 0}
    return int(crc16(b"".join(pack_part(layout, k, seq, zeroed) for k in range(layout.parts))))


def encode_fixed(msg: Message, seq: int, node: int, fd: bool = False, sender: str = Sender.HOST,
                 layouts: CanLayouts | None = None) -> list[CanFrame]:
    """The frames (in part order) carrying ``msg`` with sequence ``seq`` to/from board ``node``, in
    the robot's ``layouts`` (default: :data:`protocol.can.layouts.DEFAULT_SERVO_COUNT` servos).

    ``sender`` only matters for HEARTBEAT (each end has its own identifier).
    Raises ``PayloadError`` for a message without a fixed layout or with invalid values.
    """
    t = msg_type_of(msg)
    if t is MsgType.NACK and msg.detail:  # type: ignore[union-attr]
        raise PayloadError("a NACK with a detail text goes as bulk (encode_bulk)")
    layout = fixed_layout_for(t, fd, sender, layouts)
    raw = message_to_raw(msg, layouts)
    if layout.has_crc:
        raw[CRC_SIGNAL] = fixed_crc(layout, seq, raw)
    aid = cob_id(layout.fn, node)
    return [CanFrame(aid, pack_part(layout, k, seq, raw), is_fd=bool(fd)) for k in range(layout.parts)]


def encode_bulk(msg: Message, seq: int, schema: WireSchema | None = None) -> bytes:
    """ISO-TP service data unit: ``type u8 | seq u16 LE | protocol.codec payload | crc u16 LE``
    (CRC-16/X-25 over everything before it, as the fixed layouts' ``crc16``); the payload in the
    robot's ``schema`` (default: the u16 schema; a table's is ``layouts.schema``)."""
    payload = (schema or WIRE_SCHEMA_16).encode_payload(msg)
    body = BULK_HEADER.pack(int(msg_type_of(msg)), int(seq) & 0xFFFF) + payload
    return body + int(crc16(body)).to_bytes(2, "little")


def decode_bulk(sdu: bytes, schema: WireSchema | None = None) -> tuple[int, Message]:
    """(seq, message) of an ISO-TP service data unit, payload in ``schema`` (``PayloadError`` on
    anything malformed)."""
    data = bytes(sdu)
    if len(data) < BULK_HEADER.size + 2:
        raise PayloadError(f"bulk message of {len(data)} byte(s) is shorter than its 3-byte header and 2-byte CRC")
    data, crc = data[:-2], int.from_bytes(data[-2:], "little")
    if crc16(data) != crc:
        raise PayloadError(f"bulk message: CRC {crc:#06x}, content gives {crc16(data):#06x}")
    t, seq = BULK_HEADER.unpack_from(data)
    try:
        mt = MsgType(t)
    except ValueError:
        raise PayloadError(f"bulk message: unknown message type {t:#04x}") from None
    return seq, (schema or WIRE_SCHEMA_16).decode_payload(mt, data[BULK_HEADER.size :])


def physical(raw: dict[str, int], layout: FixedLayout) -> dict[str, float]:
    """Scaled (physical) signal values as a DBC tool shows them (NaN codes stay scaled)."""
    scales = {p.spec.name: p.spec.scale for p in layout.signals}
    return {k: (v * scales[k] if not math.isnan(v) else v) for k, v in raw.items()}
