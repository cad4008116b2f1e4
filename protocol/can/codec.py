"""Messages <-> CAN frames: fixed layouts for the real-time path, an ISO-TP envelope for bulk.

``encode_fixed(msg, seq, node, fd=False, sender=..., layouts=None)`` -> the frames of one
fixed-layout message (``PayloadError`` if it has none or is invalid); ``encode_bulk(msg, seq,
schema=None)`` -> the ISO-TP service data unit ``type u8 | seq u16 LE | protocol.codec payload |
CRC-16/X-25 u16 LE`` for any message; ``decode_bulk`` is its inverse. ``is_fixed(msg, fd, layouts)``
says which path a message takes: HELLO/CAPS, CONFIG, SCREEN, SPEAKER, CAMERA_*, SIM_STATE and a
NACK with a detail text go as bulk, and so does a message the robot's layout table has no fixed
layout for in that frame kind (classic-CAN TELEMETRY above 27 servos); everything else as fixed
frames. Raw signal values (``message_to_raw`` / ``raw_to_message``) are what the DBC describes; they
follow one rule per serial field kind over the fields the table derives from the declaration
(:data:`protocol.codec.CAN_FIXED`, :class:`protocol.can.layouts.CarriedField`), so no message is
spelled out here.

``layouts`` is the robot's table (:func:`protocol.can.layouts.can_layouts`); None means the default
table (:data:`protocol.can.layouts.DEFAULT_SERVO_COUNT` servos). Bulk payloads use the table's
serial schema (``layouts.schema``).
"""

from __future__ import annotations

import math
import struct
from functools import lru_cache
from typing import Any

from protocol.codec import (
    _Q16_NAN,
    CAN_FIXED,
    MESSAGE_CLASSES,
    WIRE_SCHEMA_16,
    Bool,
    EnumU8,
    Flags16,
    Mask,
    PayloadError,
    Q16Array,
    RestBytes,
    SInt,
    UInt,
    WireSchema,
    _as_int,
    _q16_decode,
    _q16_encode,
    _seq_of_floats,
    msg_type_of,
)
from protocol.can.frame import CanFrame
from protocol.can.ids import FunctionCode, cob_id
from protocol.can.layouts import CRC_SIGNAL, SEQ_MASK, CanLayouts, CarriedField, FixedLayout, can_layouts, function_codes
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


def _table(layouts: CanLayouts | None) -> CanLayouts:
    return can_layouts() if layouts is None else layouts


#: message type -> its function code (HEARTBEAT: by sender, :func:`_fn_of`), from the declaration
_FN_OF_TYPE: dict[MsgType, FunctionCode] = {t: function_codes(t)[0] for t in CAN_FIXED if t is not MsgType.HEARTBEAT}


def _fn_of(msg_type: MsgType, sender: str) -> FunctionCode | None:
    if msg_type is MsgType.HEARTBEAT:
        return FunctionCode.HEARTBEAT_HOST if sender == Sender.HOST else FunctionCode.HEARTBEAT_BOARD
    return _FN_OF_TYPE.get(msg_type)


def _carries_omitted(msg: Message, t: MsgType, table: CanLayouts) -> bool:
    """True when a field CAN omits (NACK's detail) is not empty: the message must go as bulk."""
    return any(cf.form.omitted and getattr(msg, cf.name) for cf in table.fields.get(t, ()))


def is_fixed(msg: Message, fd: bool = False, layouts: CanLayouts | None = None) -> bool:
    """True when ``msg`` travels in fixed-layout frames of this frame kind (classic or FD) with the
    robot's ``layouts``, False when it goes as bulk (ISO-TP)."""
    t = msg_type_of(msg)
    table = _table(layouts)
    if _carries_omitted(msg, t, table):
        return False
    fn = _fn_of(t, Sender.HOST)
    return fn is not None and table.layout(fn, fd) is not None


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
#
# One rule per serial field kind, applied to the fields of the declaration (protocol.codec.CAN_FIXED
# through protocol.can.layouts.CarriedField): integers clamp to the signal's width (wrapping fields
# wrap, as on serial), q16 values quantise as the serial codec does, a per-servo array has one signal
# per servo of the robot (-32768 where the mask has no bit or the array no value).


def _drives_array(carried: tuple[CarriedField, ...], mask_name: str) -> bool:
    return any(isinstance(cf.field, Q16Array) and cf.field.mask_field == mask_name for cf in carried)


def _q16_codes(t: MsgType, name: str, values: Any, cpu: int) -> list[int]:
    try:
        return [_q16_encode(v, cpu) for v in values]
    except (TypeError, ValueError):
        raise PayloadError(f"{t.name}: {name}: values must be numbers, got {list(values)!r}") from None


def _to_raw(t: MsgType, cf: CarriedField, value: Any, raw: dict[str, int], carried: tuple[CarriedField, ...],
            n: int) -> None:
    f, name, sigs = cf.field, cf.name, cf.signals
    if isinstance(f, UInt):
        hi = (1 << sigs[0].bits) - 1
        if f.wrap and not cf.form.clamped:
            raw[name] = _as_int(name, value, 0, hi + 1) & hi
        else:
            raw[name] = min(max(_as_int(name, value, 0, hi), 0), hi)
    elif isinstance(f, SInt):
        hi = (1 << (sigs[0].bits - 1)) - 1
        raw[name] = min(max(_as_int(name, value, -hi - 1, hi), -hi - 1), hi)
    elif isinstance(f, Bool):
        raw[name] = 1 if value else 0
    elif isinstance(f, EnumU8):
        try:
            raw[name] = int(f.cls(value))
        except ValueError as e:
            raise PayloadError(f"{t.name}: {e}") from None
    elif isinstance(f, Flags16):
        v = _as_int(name, value, -1, 1 << 16)
        if v < 0 or v > 0xFFFF:
            raise PayloadError(f"{t.name}: {name} {v:#x} do not fit 16 bits")
        raw[name] = v
    elif isinstance(f, Mask):
        bits = sigs[0].bits
        v = _as_int(name, value, -1, 1 << bits)
        if _drives_array(carried, name):  # its array has signals for the robot's n servos only
            if v < 0 or v >> n:
                raise PayloadError(f"{t.name}: {name} {v:#x} has bits outside the {n} CAN servos")
        elif v < 0 or v >> bits:
            raise PayloadError(f"{t.name}: {name} {v:#x} does not fit {bits} bits")
        raw[name] = v
    elif isinstance(f, Q16Array):
        vals = list(_seq_of_floats(name, value))
        if f.fixed is not None:
            if len(vals) != f.fixed:
                raise PayloadError(f"{t.name}: {name} needs {f.fixed} values, got {len(vals)}")
            codes = _q16_codes(t, name, vals, f.cpu)
        elif f.mask_field is not None:
            mask = raw[f.mask_field]
            if len(vals) != mask.bit_count():
                raise PayloadError(f"{t.name}: {len(vals)} {name} but popcount({f.mask_field}) = {mask.bit_count()}")
            it = iter(_q16_codes(t, name, vals, f.cpu))
            codes = [next(it) if mask >> i & 1 else _Q16_NAN for i in range(len(sigs))]
            if not f.allow_nan and any(mask >> i & 1 and code == _Q16_NAN for i, code in enumerate(codes)):
                raise PayloadError(f"{t.name}: {name}: NaN is not allowed here")
        else:
            if len(vals) > len(sigs):
                raise PayloadError(f"{t.name}: {name}: {len(vals)} values, the CAN layout carries {len(sigs)}")
            codes = _q16_codes(t, name, vals, f.cpu)
            codes += [_Q16_NAN] * (len(sigs) - len(codes))
        for s, code in zip(sigs, codes):
            raw[s.name] = code
    else:  # protocol.can.layouts refuses a field kind without a CAN form when it builds the table
        raise PayloadError(f"{t.name}: {name}: no CAN form for {type(f).__name__}")


def message_to_raw(msg: Message, layouts: CanLayouts | None = None) -> dict[str, int]:
    """Raw (integer) signal values of a fixed-layout message, keyed by DBC signal name; the rules per
    field come from the declaration (:data:`protocol.codec.CAN_FIXED`). ``PayloadError`` for a message
    without a fixed layout or with values it cannot carry (a NACK's detail is not carried: see
    :func:`is_fixed`)."""
    t = msg_type_of(msg)
    table = _table(layouts)
    carried = table.fields.get(t)
    if carried is None:
        raise PayloadError(f"{t.name} has no fixed CAN layout")
    raw: dict[str, int] = {}
    for cf in carried:
        if cf.signals:
            _to_raw(t, cf, getattr(msg, cf.name), raw, carried, table.servo_count)
    return raw


def _from_raw(t: MsgType, cf: CarriedField, raw: dict[str, int], values: dict[str, Any],
              carried: tuple[CarriedField, ...], n: int) -> Any:
    f, name, sigs = cf.field, cf.name, cf.signals
    if not sigs:  # omitted on CAN: a fixed-layout message has it empty
        return b"" if isinstance(f, RestBytes) else ""
    if isinstance(f, (UInt, SInt)):
        return raw[name]
    if isinstance(f, Bool):
        if raw[name] > 1:
            raise PayloadError(f"{t.name}: {name}: boolean must be 0 or 1, got {raw[name]}")
        return bool(raw[name])
    if isinstance(f, (EnumU8, Flags16)):
        try:
            return f.cls(raw[name])
        except ValueError as e:
            raise PayloadError(f"{t.name}: {e}") from None
    if isinstance(f, Mask):
        v = raw[name]
        if _drives_array(carried, name) and v >> n:
            raise PayloadError(f"{t.name}: {name} {v:#x} has bits outside the {n} CAN servos")
        return v
    if isinstance(f, Q16Array):
        if f.mask_field is not None:
            mask = values[f.mask_field]
            codes = [raw[s.name] for i, s in enumerate(sigs) if mask >> i & 1]
            if not f.allow_nan and _Q16_NAN in codes:  # as protocol.codec: a target has no "unknown"
                raise PayloadError(f"{t.name}: {name}: reserved code -32768 (NaN) is not allowed here")
        else:
            codes = [raw[s.name] for s in sigs]
        return tuple(_q16_decode(code, f.cpu) for code in codes)
    raise PayloadError(f"{t.name}: {name}: no CAN form for {type(f).__name__}")


def raw_to_message(msg_type: MsgType, raw: dict[str, int], layouts: CanLayouts | None = None) -> Message:
    """Inverse of :func:`message_to_raw` (``PayloadError`` on values the message cannot hold)."""
    table = _table(layouts)
    carried = table.fields.get(msg_type)
    if carried is None:
        raise PayloadError(f"{msg_type.name} has no fixed CAN layout")
    values: dict[str, Any] = {}
    for cf in carried:
        values[cf.name] = _from_raw(msg_type, cf, raw, values, carried, table.servo_count)
    return MESSAGE_CLASSES[msg_type](**values)  # type: ignore[no-any-return]


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
    if _carries_omitted(msg, t, _table(layouts)):
        omitted = [cf.name for cf in _table(layouts).fields[t] if cf.form.omitted]
        raise PayloadError(f"a {t.name} with a non-empty {'/'.join(omitted)} goes as bulk (encode_bulk)")
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
