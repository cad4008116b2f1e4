"""Payload codec for protocol version 1: message dataclass <-> payload bytes.

Each message is declared once, as a class in :mod:`protocol.messages` (its type, sender, fields with
their wire types from :mod:`protocol.wiretypes`, and its CAN form); this module derives from those
classes :data:`MESSAGE_CLASSES`, one layout per wire schema (:data:`LAYOUTS`: message type -> ordered
``(field name, wire field)`` pairs) and :data:`CAN_FIXED`. All integers are little-endian. The layouts
also feed :data:`SCHEMA_HASH`, so any change to a type number, a field name, a
field's Python type or its wire format changes the hash that HELLO/CAPS compare.

Wire scales (``q16`` = signed 16-bit integer, ``-32768`` reserved for "unknown"):

=====================  ==========================  =====================================
quantity               encoding                    range / resolution
=====================  ==========================  =====================================
position, imu angle    q16 x 1e-4 rad              +-3.2767 rad, 0.1 mrad
velocity               q16 x 1e-3 rad/s            +-32.767 rad/s, 1 mrad/s
effort                 q16 x 1e-3 N*m              +-32.767 N*m, 1 mN*m
SIM_STATE pos / quat   IEEE float32                float32 precision
SERVO_FRAME apply-at   u32 us, wraps every 2**32   unwrap with :func:`unwrap_time_us`
other times            u64 us                      0 .. 2**64-1
=====================  ==========================  =====================================

Policy for values out of range (the board is authoritative for safety and clamps
targets again anyway):

* integer fields take ints (numpy integers too) or floats (rounded to the nearest
  integer); ``None``, strings and NaN are refused.
* numeric values are **clamped** to the wire range, never rejected: a position of
  4.0 rad travels as 3.2767 rad, a negative time as 0, a counter above 2**32-1
  saturates. Sequence numbers (``ack_seq``, ``last_applied_seq``) wrap modulo 2**16
  like the frame sequence. ``SERVO_FRAME.apply_at_us`` travels modulo 2**32.
* a NaN in a report (telemetry, sim state) travels as the reserved code and decodes
  as NaN; a NaN *target* in a SERVO_FRAME is refused (there is no safe value for it).
* structurally invalid messages raise :class:`PayloadError` (a ``ValueError``) at
  encode time: a mask with bits at or above the schema's ``max_servos``, a target count that is
  not ``popcount(mask)``, more than ``max_servos`` telemetry values, a string that
  is too long or not ASCII, an enum value that is not a member, a camera chunk whose
  index is not below its total.

Use :func:`quantize_position` and friends, or :func:`quantize_message`, to predict
exactly what survives a round trip.

Wire schemas (the robot on the wire). The layouts of three messages depend on how many servos the
robot has; everything else (HELLO, CAPS, NACK, ...) is the same for every robot, so the handshake
works before either side knows the other's robot. A :class:`WireSchema` is one complete set of
layouts with its own hash; :func:`schema_for` picks it from the robot's servo count N:

=========================  =====================  ======================================
schema                     robots                 SERVO_FRAME / FLUSH mask, TELEMETRY
=========================  =====================  ======================================
``WIRE_SCHEMA_16``         1 <= N <= 16           u16 mask (bit i = servo i); <= 16 values
``WIRE_SCHEMA_32``         17 <= N <= 32          u32 mask; <= 32 values per array
=========================  =====================  ======================================

The 16 schema is the protocol as it was before robots became data: its text and hash
(:data:`SCHEMA_HASH`) are unchanged, so every robot of up to 16 servos keeps its frames byte for
byte. The module-level :data:`LAYOUTS`, :data:`SCHEMA_HASH`, :func:`encode_payload`,
:func:`decode_payload` and :func:`quantize_message` are the 16 schema's (``schema=None``). The bound
32 (:data:`protocol.messages.MAX_WIRE_SERVOS`): the mask is at most one u32 (one register on an
MCU), and the largest message still fits a frame: payload bytes per message
(SERVO_FRAME = apply-at 4 + mask + 2 N; TELEMETRY = 35 + 6 N, 3 count bytes included)

=====  ===========  ============  ==========================================
N      SERVO_FRAME  TELEMETRY     serial wire bytes (SERVO_FRAME / TELEMETRY)
=====  ===========  ============  ==========================================
1      8            41            17 / 50
12     30           107           39 / 116
16     38           131           47 / 140
17     42           137           51 / 146
32     72           227 (of 255)  81 / 236
=====  ===========  ============  ==========================================

(wire bytes = payload + 9: header 5, CRC 2, COBS code byte 1, delimiter 1; :mod:`protocol.framing`).
A 33rd servo would need a second mask word; TELEMETRY would still fit up to 36 servos.
"""

from __future__ import annotations

import hashlib
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from protocol import messages as m
from protocol.messages import MAX_SERVOS, MAX_WIRE_SERVOS, Message, MsgType
from protocol.wiretypes import DECLARED, Field, _as_int, _Reader

# Re-exported: the wire field types, quantisers and bounds moved to protocol.wiretypes (the message
# declarations use them), and callers and tests import them from here.
from protocol.wiretypes import _F32_MAX, _Q16_MAX, _Q16_NAN, _q16_decode, _q16_encode, _seq_of_floats  # noqa: F401
from protocol.wiretypes import (  # noqa: F401
    EFFORT_SCALE, MAX_CHUNK_DATA, MAX_NACK_DETAIL_BYTES, MAX_NAME_BYTES, MAX_PAYLOAD, MAX_RESEND_BITMAP,
    MAX_SPEECH_TEXT_BYTES, POSITION_SCALE, VELOCITY_SCALE, Bool, CanField, EnumU8, F32Array, Flags16, Mask,
    PayloadError, Q16Array, RestBytes, SInt, Str8, UInt, field_unit, quantize_angle, quantize_apply_at,
    quantize_effort, quantize_f32, quantize_position, quantize_velocity, unwrap_time_us,
)

__all__ = [
    "CAN_FIXED",
    "CanField",
    "LAYOUTS",
    "MAX_PAYLOAD",
    "MAX_CHUNK_DATA",
    "MESSAGE_CLASSES",
    "PayloadError",
    "POSITION_SCALE",
    "VELOCITY_SCALE",
    "EFFORT_SCALE",
    "SCHEMA_HASH",
    "WIRE_SCHEMA_16",
    "WIRE_SCHEMA_32",
    "WIRE_SCHEMAS",
    "WireBoundError",
    "WireSchema",
    "compute_schema_hash",
    "schema_by_hash",
    "schema_for",
    "schema_text",
    "MAX_NAME_BYTES",
    "MAX_NACK_DETAIL_BYTES",
    "MAX_SPEECH_TEXT_BYTES",
    "decode_payload",
    "encode_payload",
    "field_unit",
    "msg_type_of",
    "quantize_angle",
    "quantize_effort",
    "quantize_f32",
    "quantize_message",
    "quantize_position",
    "quantize_velocity",
    "quantize_apply_at",
    "unwrap_time_us",
]

# --- layouts and tables, derived from the message declarations (protocol.messages) ------------

Layout = list[tuple[str, Field]]

#: Message type -> its dataclass (the :func:`protocol.wiretypes.message` declarations, in type order).
MESSAGE_CLASSES: dict[MsgType, type] = {MsgType(t): DECLARED[t].cls for t in sorted(DECLARED)}


def _layouts(max_servos: int) -> dict[MsgType, Layout]:
    """Message type -> ordered wire fields (the declared fields) for robots of up to ``max_servos``
    servos: only SERVO_FRAME, FLUSH and TELEMETRY depend on it."""
    return {t: DECLARED[t].layout(max_servos) for t in MESSAGE_CLASSES}


#: The messages that have a fixed CAN layout (the real-time path; every other message travels as
#: ISO-TP bulk with its serial payload), each with the CAN form of the fields that differ from the
#: serial one (field name -> :class:`CanField`), as declared (``can_fixed``, ``wire(..., can=...)``).
#: Signals follow the serial layout's field order; :mod:`protocol.can.layouts` places them per robot
#: servo count, :mod:`protocol.can.codec` packs the values, :mod:`protocol.can.make_dbc` writes the DBC,
#: :mod:`protocol.wire_tables` the reference from it.
CAN_FIXED: Mapping[MsgType, Mapping[str, CanField]] = {
    MsgType(t): d.can_forms() for t, d in DECLARED.items() if d.can_fixed}  # declaration order: the C table's rows


_TYPE_OF_CLASS: dict[type, MsgType] = {cls: t for t, cls in MESSAGE_CLASSES.items()}


# --- schema hash ---------------------------------------------------------------------------


def _annotation(cls: type, name: str) -> str:
    ann = cls.__annotations__.get(name)  # strings: messages.py uses postponed annotations
    return ann if isinstance(ann, str) else getattr(ann, "__name__", repr(ann))


def schema_text(
    layouts: Mapping[MsgType, Layout] | None = None,
    classes: Mapping[MsgType, type] | None = None,
    max_servos: int = MAX_SERVOS,
) -> str:
    """Canonical text the schema hash is computed from (one line per field); the default schema's
    layouts unless ``layouts`` is given (``max_servos`` names the schema in its first line)."""
    layouts = _DEFAULT_LAYOUTS if layouts is None else layouts
    classes = MESSAGE_CLASSES if classes is None else classes
    lines = [f"protocol {m.PROTOCOL_VERSION} max_servos {max_servos} max_payload {MAX_PAYLOAD}"]
    for t in sorted(layouts, key=int):
        cls = classes[t]
        lines.append(f"type {t.name}={int(t):#04x} {cls.__name__}")
        for name, f in layouts[t]:
            lines.append(f"  {name}: {_annotation(cls, name)} as {f.wire}")
    return "\n".join(lines) + "\n"


def compute_schema_hash(
    layouts: Mapping[MsgType, Layout] | None = None,
    classes: Mapping[MsgType, type] | None = None,
    max_servos: int = MAX_SERVOS,
) -> int:
    """u32: the first four bytes (big-endian) of SHA-256 over :func:`schema_text`."""
    digest = hashlib.sha256(schema_text(layouts, classes, max_servos).encode()).digest()
    return int.from_bytes(digest[:4], "big")


# --- wire schemas --------------------------------------------------------------------------


class WireBoundError(ValueError):
    """A servo count the wire cannot carry (below 1 or above :data:`protocol.messages.MAX_WIRE_SERVOS`)."""


def _encode(layouts: Mapping[MsgType, Layout], msg: Message) -> bytes:
    t = msg_type_of(msg)
    if t is MsgType.CAMERA_CHUNK and not (
        0 <= _as_int("index", msg.index, -1, 1 << 16) < _as_int("total", msg.total, -1, 1 << 16)  # type: ignore[union-attr]
    ):
        raise PayloadError(f"CAMERA_CHUNK: index {msg.index} not below total {msg.total}")  # type: ignore[union-attr]
    out = bytearray()
    ctx: dict[str, Any] = {}
    for name, f in layouts[t]:
        value = getattr(msg, name)
        try:
            f.encode(name, value, out, ctx)
        except PayloadError as e:
            raise PayloadError(f"{t.name}: {e}") from None
        except (TypeError, ValueError, OverflowError, struct.error) as e:
            raise PayloadError(f"{t.name}: {name}: cannot encode {value!r}: {e}") from None
        ctx[name] = value
    if len(out) > MAX_PAYLOAD:
        raise PayloadError(f"{t.name}: payload of {len(out)} bytes exceeds {MAX_PAYLOAD}")
    return bytes(out)


def _decode(layouts: Mapping[MsgType, Layout], msg_type: MsgType, payload: bytes) -> Message:
    try:
        t = msg_type if msg_type.__class__ is MsgType else MsgType(msg_type)  # no Enum call for a member
    except ValueError:
        raise PayloadError(f"unknown message type {msg_type!r}") from None
    r = _Reader(bytes(payload))
    values: dict[str, Any] = {}
    try:
        for name, f in layouts[t]:
            values[name] = f.decode(name, r, values)
    except PayloadError as e:
        raise PayloadError(f"{t.name}: {e}") from None
    if r.pos != len(r.buf):
        raise PayloadError(f"{t.name}: {len(r.buf) - r.pos} unexpected trailing byte(s) after {r.pos}")
    if t is MsgType.CAMERA_CHUNK and not values["index"] < values["total"]:
        raise PayloadError(f"CAMERA_CHUNK: index {values['index']} not below total {values['total']}")
    return MESSAGE_CLASSES[t](**values)  # type: ignore[no-any-return]


@dataclass(frozen=True, eq=False)
class WireSchema:
    """One complete set of payload layouts: the message definitions for robots of up to
    ``max_servos`` servos (16: u16 mask; 32: u32 mask), its canonical ``text`` and ``hash`` (u32,
    what HELLO and CAPS carry). Build one with :meth:`build`; use :func:`schema_for`."""

    max_servos: int
    layouts: Mapping[MsgType, Layout]
    text: str
    hash: int

    @classmethod
    def build(cls, max_servos: int) -> WireSchema:
        layouts = _layouts(max_servos)
        text = schema_text(layouts, MESSAGE_CLASSES, max_servos)
        return cls(max_servos, layouts, text, compute_schema_hash(layouts, MESSAGE_CLASSES, max_servos))

    @property
    def mask_bytes(self) -> int:
        """Bytes of the servo mask on the wire (2 or 4)."""
        return 2 if self.max_servos <= 16 else 4

    def encode_payload(self, msg: Message) -> bytes:
        """Pack a message into payload bytes (clamps numbers; ``PayloadError`` if structurally invalid)."""
        return _encode(self.layouts, msg)

    def decode_payload(self, msg_type: MsgType, payload: bytes) -> Message:
        """Unpack payload bytes into the message of ``msg_type`` (``PayloadError`` on any bad payload)."""
        return _decode(self.layouts, msg_type, payload)

    def quantize_message(self, msg: Message) -> Message:
        """Exactly what ``msg`` decodes as at the other end (clamped, rounded, wrapped)."""
        return _decode(self.layouts, msg_type_of(msg), _encode(self.layouts, msg))

    def __repr__(self) -> str:
        return f"WireSchema(max_servos={self.max_servos}, hash={self.hash:#010x})"


#: Robots of 1..16 servos: u16 mask. Its text and hash are the protocol's from before robots became data.
WIRE_SCHEMA_16 = WireSchema.build(MAX_SERVOS)
#: Robots of 17..32 servos: u32 mask, up to 32 values per TELEMETRY array.
WIRE_SCHEMA_32 = WireSchema.build(MAX_WIRE_SERVOS)
#: Every schema this build speaks, the default first.
WIRE_SCHEMAS: tuple[WireSchema, ...] = (WIRE_SCHEMA_16, WIRE_SCHEMA_32)
_DEFAULT_LAYOUTS = WIRE_SCHEMA_16.layouts

#: The default (16) schema's layouts: message type -> ordered wire fields.
LAYOUTS: Mapping[MsgType, Layout] = WIRE_SCHEMA_16.layouts
#: Hash of the default (16) schema; HELLO and CAPS carry their schema's hash so both ends can refuse a mismatch.
SCHEMA_HASH: int = WIRE_SCHEMA_16.hash


def schema_for(servo_count: int) -> WireSchema:
    """The schema of a robot with ``servo_count`` servos: :data:`WIRE_SCHEMA_16` for 1..16,
    :data:`WIRE_SCHEMA_32` for 17..32; :class:`WireBoundError` otherwise."""
    n = int(servo_count)
    for schema in WIRE_SCHEMAS:
        if 1 <= n <= schema.max_servos:
            return schema
    raise WireBoundError(f"{n} servos: the wire carries 1 to {MAX_WIRE_SERVOS} "
                         f"(its servo mask is at most one u32)")


def schema_by_hash(schema_hash: int) -> WireSchema | None:
    """The schema whose hash is ``schema_hash`` (None: not one this build speaks)."""
    return next((s for s in WIRE_SCHEMAS if s.hash == schema_hash), None)


# --- encode / decode -----------------------------------------------------------------------


def msg_type_of(msg: Message) -> MsgType:
    """The :class:`MsgType` of a message instance (``PayloadError`` if it is not a message)."""
    try:
        return _TYPE_OF_CLASS[type(msg)]
    except KeyError:
        raise PayloadError(f"not a protocol message: {type(msg).__name__}") from None


def encode_payload(msg: Message, schema: WireSchema | None = None) -> bytes:
    """Pack a message into payload bytes with ``schema`` (default: the 16 schema); clamps numbers,
    ``PayloadError`` if structurally invalid."""
    return _encode(_DEFAULT_LAYOUTS if schema is None else schema.layouts, msg)


def decode_payload(msg_type: MsgType, payload: bytes, schema: WireSchema | None = None) -> Message:
    """Unpack payload bytes into the message of ``msg_type`` with ``schema`` (default: the 16 schema);
    ``PayloadError`` on any bad payload."""
    return _decode(_DEFAULT_LAYOUTS if schema is None else schema.layouts, msg_type, payload)


def quantize_message(msg: Message, schema: WireSchema | None = None) -> Message:
    """Exactly what ``msg`` decodes as at the other end (clamped, rounded, wrapped)."""
    return decode_payload(msg_type_of(msg), encode_payload(msg, schema), schema)
