"""Payload codec for protocol version 1: message dataclass <-> payload bytes.

Each message type has a declarative layout (:data:`LAYOUTS`): an ordered list of
``(field name, wire field)`` pairs. All integers are little-endian. The layouts
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

import dataclasses
import functools
import hashlib
import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import IntEnum, IntFlag
from typing import Any

from protocol import messages as m
from protocol.messages import MAX_SERVOS, MAX_WIRE_SERVOS, Message, MsgType

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

#: Largest payload a frame can carry (the header's length field is one byte).
MAX_PAYLOAD = 255

POSITION_SCALE = 1e-4  # rad per count (also IMU roll/pitch/yaw)
VELOCITY_SCALE = 1e-3  # rad/s per count
EFFORT_SCALE = 1e-3  # N*m per count

_Q16_MAX = 32767
_Q16_NAN = -32768  # reserved code: value unknown (NaN)

MAX_NAME_BYTES = 32
MAX_NACK_DETAIL_BYTES = 64
MAX_SPEECH_TEXT_BYTES = 200


class PayloadError(ValueError):
    """A payload (or a message about to be encoded) is structurally invalid."""


# --- quantisation helpers --------------------------------------------------------------------


def _q16_encode(value: float, counts_per_unit: int) -> int:
    v = float(value)
    if math.isnan(v):
        return _Q16_NAN
    scaled = v * counts_per_unit
    if scaled >= _Q16_MAX:
        return _Q16_MAX
    if scaled <= -_Q16_MAX:
        return -_Q16_MAX
    return int(round(scaled))


def _q16_decode(code: int, counts_per_unit: int) -> float:
    if code == _Q16_NAN:
        return math.nan
    return code / counts_per_unit


def quantize_position(rad: float) -> float:
    """What a position (rad) becomes on the wire: clamped to +-3.2767, rounded to 1e-4 (NaN stays NaN)."""
    return _q16_decode(_q16_encode(rad, 10_000), 10_000)


def quantize_angle(rad: float) -> float:
    """IMU roll/pitch/yaw use the position scale (covers +-pi)."""
    return quantize_position(rad)


def quantize_velocity(rad_s: float) -> float:
    """What a velocity (rad/s) becomes: clamped to +-32.767, rounded to 1e-3 (NaN stays NaN)."""
    return _q16_decode(_q16_encode(rad_s, 1_000), 1_000)


def quantize_effort(nm: float) -> float:
    """What an effort (N*m) becomes: clamped to +-32.767, rounded to 1e-3 (NaN stays NaN)."""
    return _q16_decode(_q16_encode(nm, 1_000), 1_000)


_F32 = struct.Struct("<f")
_F32_MAX = 3.4028234663852886e38


def quantize_f32(x: float) -> float:
    """What a float becomes as IEEE float32 (values beyond float32 range clamp to +-max)."""
    v = float(x)
    if not math.isnan(v):
        v = min(max(v, -_F32_MAX), _F32_MAX)
    return _F32.unpack(_F32.pack(v))[0]


def quantize_apply_at(t_us: int) -> int:
    """SERVO_FRAME apply-at times travel modulo 2**32 (the board clock wraps after ~71.6 min)."""
    return int(t_us) & 0xFFFF_FFFF


def unwrap_time_us(wrapped: int, reference_us: int, bits: int = 32) -> int:
    """Full-width time nearest to ``reference_us`` whose low ``bits`` bits equal ``wrapped``.

    The board calls this with its own clock as reference to recover a SERVO_FRAME's
    apply-at time; correct while the true time is within +-2**(bits-1) us (~35 min
    for 32 bits) of the reference.
    """
    span = 1 << bits
    half = span >> 1
    delta = (int(wrapped) - int(reference_us)) % span
    if delta >= half:
        delta -= span
    return int(reference_us) + delta


# --- wire field types --------------------------------------------------------------------------


def _as_int(name: str, value: Any, lo: int, hi: int) -> int:
    """An integer field value: ints (numpy too) as is, floats rounded, +-inf clamped; else PayloadError."""
    if value.__class__ is int:  # the common case, without the checks below (a hot path: every message field)
        return value  # type: ignore[no-any-return]
    if isinstance(value, (str, bytes, bytearray)) or value is None:
        raise PayloadError(f"{name}: expected an integer, got {value!r}")
    if isinstance(value, float) or (not hasattr(value, "__index__") and hasattr(value, "__float__")):
        f = float(value)
        if math.isnan(f):
            raise PayloadError(f"{name}: expected an integer, got NaN")
        if math.isinf(f):
            return hi if f > 0 else lo
        return round(f)
    try:
        return int(value.__index__() if hasattr(value, "__index__") else value)
    except (TypeError, ValueError):
        raise PayloadError(f"{name}: expected an integer, got {value!r}") from None


class _Reader:
    __slots__ = ("buf", "pos")

    def __init__(self, buf: bytes) -> None:
        self.buf = buf
        self.pos = 0

    def take(self, n: int, what: str) -> bytes:
        end = self.pos + n
        if end > len(self.buf):
            raise PayloadError(
                f"payload truncated: {what} needs {n} byte(s) at offset {self.pos}, "
                f"only {len(self.buf) - self.pos} left"
            )
        out = self.buf[self.pos : end]
        self.pos = end
        return out


class Field:
    """One wire field: ``wire`` describes the format (it enters the schema hash)."""

    wire: str = "?"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        raise NotImplementedError

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        raise NotImplementedError


class UInt(Field):
    """Unsigned integer; out-of-range values clamp (or wrap when ``wrap``)."""

    _FMT = {1: "<B", 2: "<H", 4: "<I", 8: "<Q"}

    def __init__(self, size: int, wrap: bool = False) -> None:
        self.size = size
        self.wrap = wrap
        self.max = (1 << (8 * size)) - 1
        self.st = struct.Struct(self._FMT[size])
        self.wire = f"u{8 * size}{'w' if wrap else ''}"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        v = _as_int(name, value, 0, self.max)
        v = v & self.max if self.wrap else min(max(v, 0), self.max)
        out += self.st.pack(v)

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        return self.st.unpack(r.take(self.size, name))[0]


class SInt(Field):
    """Signed integer; out-of-range values clamp."""

    _FMT = {1: "<b", 2: "<h", 4: "<i", 8: "<q"}

    def __init__(self, size: int) -> None:
        self.size = size
        self.max = (1 << (8 * size - 1)) - 1
        self.min = -self.max - 1
        self.st = struct.Struct(self._FMT[size])
        self.wire = f"i{8 * size}"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        out += self.st.pack(min(max(_as_int(name, value, self.min, self.max), self.min), self.max))

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        return self.st.unpack(r.take(self.size, name))[0]


class Bool(Field):
    wire = "bool8"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        out.append(1 if value else 0)

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        b = r.take(1, name)[0]
        if b > 1:
            raise PayloadError(f"{name}: boolean byte must be 0 or 1, got {b}")
        return bool(b)


class EnumU8(Field):
    """An ``IntEnum`` as one byte; values that are not members are refused both ways."""

    def __init__(self, cls: type[IntEnum]) -> None:
        self.cls = cls
        members = ",".join(f"{e.name}={int(e.value)}" for e in cls)
        self.wire = f"enum8[{cls.__name__}:{members}]"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        try:
            v = self.cls(value)
        except ValueError:
            raise PayloadError(f"{name}: {value!r} is not a {self.cls.__name__}") from None
        out.append(int(v))

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        b = r.take(1, name)[0]
        try:
            return self.cls(b)
        except ValueError:
            raise PayloadError(f"{name}: unknown {self.cls.__name__} value {b}") from None


class Flags16(Field):
    """An ``IntFlag`` as u16; unknown bits are kept."""

    def __init__(self, cls: type[IntFlag]) -> None:
        self.cls = cls
        members = ",".join(f"{e.name}={int(e.value)}" for e in cls)
        self.wire = f"flags16[{cls.__name__}:{members}]"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        v = _as_int(name, value, -1, 1 << 16)
        if v < 0 or v > 0xFFFF:
            raise PayloadError(f"{name}: flags {v:#x} do not fit 16 bits")
        out += struct.pack("<H", v)

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        return self.cls(struct.unpack("<H", r.take(2, name))[0])


class Mask(Field):
    """Servo mask of a schema for ``max_servos`` servos: u16 up to 16 servos, else u32; only bits below
    ``max_servos`` allowed (bit i = servo i)."""

    def __init__(self, max_servos: int = MAX_SERVOS) -> None:
        if not 1 <= max_servos <= MAX_WIRE_SERVOS:
            raise ValueError(f"a servo mask covers 1..{MAX_WIRE_SERVOS} servos, not {max_servos}")
        self.max_servos = max_servos
        self.size = 2 if max_servos <= 16 else 4
        self.st = struct.Struct("<H" if self.size == 2 else "<I")
        self.wire = f"mask{8 * self.size}[max={max_servos}]"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        v = _as_int(name, value, -1, 1 << self.max_servos)
        if v < 0 or v >> self.max_servos:
            raise PayloadError(f"{name}: {v:#x} has bits outside the {self.max_servos} servos")
        out += self.st.pack(v)

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        v: int = self.st.unpack(r.take(self.size, name))[0]
        if v >> self.max_servos:
            raise PayloadError(f"{name}: {v:#x} has bits outside the {self.max_servos} servos")
        return v


def _seq_of_floats(name: str, value: Any) -> Sequence[float]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        try:
            value = tuple(value)
        except TypeError:
            raise PayloadError(f"{name}: expected a sequence of numbers, got {type(value).__name__}") from None
    return value  # type: ignore[no-any-return]


@functools.lru_cache(maxsize=None)
def _q16_struct(n: int) -> struct.Struct:
    """The packer of ``n`` little-endian i16 codes (n is at most the wire's servo count, so few are made)."""
    return struct.Struct(f"<{n}h")


class Q16Array(Field):
    """Array of q16 values with one of three length rules.

    ``fixed=N``: exactly N values; ``mask_field=F``: popcount of field F values;
    otherwise a u8 count (at most ``max_count``, the schema's servos) precedes the values.
    A value is ``code / counts_per_unit`` in ``unit`` (``"rad"``, ``"rad/s"``, ``"N*m"``).
    """

    def __init__(
        self,
        counts_per_unit: int,
        *,
        fixed: int | None = None,
        mask_field: str | None = None,
        allow_nan: bool = True,
        max_count: int = MAX_SERVOS,
        unit: str = "",
    ) -> None:
        self.cpu = counts_per_unit
        self.fixed = fixed
        self.mask_field = mask_field
        self.allow_nan = allow_nan
        self.max_count = max_count
        self.unit = unit  # of the decoded value (documentation, DBC): not on the wire, not in the hash
        rule = f"fixed{fixed}" if fixed is not None else (f"popcount({mask_field})" if mask_field else "count8")
        self.wire = f"q16[{rule}]/{counts_per_unit}{'' if allow_nan else ',nonan'}"

    def _expected(self, name: str, ctx: Mapping[str, Any]) -> int | None:
        if self.fixed is not None:
            return self.fixed
        if self.mask_field is not None:
            return _as_int(self.mask_field, ctx[self.mask_field], 0, 0).bit_count()
        return None

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        vals = value if value.__class__ is tuple or value.__class__ is list else _seq_of_floats(name, value)
        n = len(vals)
        expected = self._expected(name, ctx)
        if expected is not None and n != expected:
            why = f"popcount({self.mask_field})" if self.mask_field else "fixed"
            raise PayloadError(f"{name}: {n} value(s) but {why} = {expected}")
        if expected is None:
            if n > self.max_count:
                raise PayloadError(f"{name}: {n} values, at most {self.max_count} allowed")
            out.append(n)
        cpu = self.cpu
        try:
            floats = list(map(float, vals))
            scaled = [f * cpu for f in floats]
            # every value inside the code range: round each (the codes _q16_encode gives) with no Python call
            # per value (a hot path: every TELEMETRY and SERVO_FRAME); else, or for a NaN that min/max passed
            # over (round raises), value by value with its clamps and the NaN code
            try:
                if not (scaled and -_Q16_MAX < min(scaled) and max(scaled) < _Q16_MAX):
                    raise ValueError
                codes = list(map(round, scaled))
            except ValueError:
                codes = [_q16_encode(v, cpu) for v in floats]
        except (TypeError, ValueError):
            raise PayloadError(f"{name}: values must be numbers, got {list(vals)!r}") from None
        if not self.allow_nan and _Q16_NAN in codes:
            raise PayloadError(f"{name}: NaN is not allowed here")
        out += _q16_struct(n).pack(*codes)

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        n = self._expected(name, ctx)
        if n is None:
            n = r.take(1, f"{name} count")[0]
            if n > self.max_count:
                raise PayloadError(f"{name}: count {n} exceeds {self.max_count}")
        codes = struct.unpack(f"<{n}h", r.take(2 * n, name))
        if _Q16_NAN in codes:
            if not self.allow_nan:
                raise PayloadError(f"{name}: reserved code -32768 (NaN) is not allowed here")
            return tuple(_q16_decode(c, self.cpu) for c in codes)
        # code / counts_per_unit per value, as _q16_decode, without a Python call per value (a hot path:
        # every TELEMETRY and SERVO_FRAME on both ends)
        return tuple(map(self.cpu.__rtruediv__, codes))


class F32Array(Field):
    """Fixed number of IEEE float32 values (in ``unit``: documentation only, not on the wire)."""

    def __init__(self, n: int, unit: str = "") -> None:
        self.n = n
        self.unit = unit
        self.st = struct.Struct(f"<{n}f")
        self.wire = f"f32[{n}]"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        vals = _seq_of_floats(name, value)
        if len(vals) != self.n:
            raise PayloadError(f"{name}: {len(vals)} value(s), expected {self.n}")
        try:
            floats = list(map(float, vals))
            # within float32's range (min/max: a NaN first makes them NaN and fails the test): packing rounds
            # each to float32 as quantize_f32 does; beyond it (or +-inf) quantize_f32 clamps each
            if floats and -_F32_MAX <= min(floats) and max(floats) <= _F32_MAX:
                out += self.st.pack(*floats)
            else:
                out += self.st.pack(*map(quantize_f32, floats))
        except (TypeError, ValueError):
            raise PayloadError(f"{name}: values must be numbers, got {list(vals)!r}") from None

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        return self.st.unpack(r.take(4 * self.n, name))


class Str8(Field):
    """u8 length + UTF-8 text, at most ``max_bytes`` bytes (bytes, not characters); too long raises.

    Every string on the wire is UTF-8 (names of faces and music clips in any
    language); the host checks the byte bound before sending (the mapper refuses
    a too-long value as a parameter error), so this check is the last line.
    """

    def __init__(self, max_bytes: int, encoding: str = "utf-8") -> None:
        self.max_bytes = max_bytes
        self.encoding = encoding
        self.wire = f"str8[{encoding},max={max_bytes}]"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        if not isinstance(value, str):
            raise PayloadError(f"{name}: expected str, got {type(value).__name__}")
        try:
            data = value.encode(self.encoding)
        except UnicodeEncodeError:
            raise PayloadError(f"{name}: {value!r} is not {self.encoding}") from None
        if len(data) > self.max_bytes:
            raise PayloadError(f"{name}: {len(data)} bytes, at most {self.max_bytes} allowed ({value[:32]!r}...)")
        out.append(len(data))
        out += data

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        n = r.take(1, f"{name} length")[0]
        if n > self.max_bytes:
            raise PayloadError(f"{name}: length {n} exceeds {self.max_bytes}")
        data = r.take(n, name)
        try:
            return data.decode(self.encoding)
        except UnicodeDecodeError:
            raise PayloadError(f"{name}: bytes are not valid {self.encoding}") from None


class RestBytes(Field):
    """Raw bytes filling the rest of the payload (must be the last field)."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.wire = f"rest[max={max_bytes}]"

    def encode(self, name: str, value: Any, out: bytearray, ctx: Mapping[str, Any]) -> None:
        if not isinstance(value, (bytes, bytearray, memoryview)):
            raise PayloadError(f"{name}: expected bytes, got {type(value).__name__}")
        if len(value) > self.max_bytes:
            raise PayloadError(f"{name}: {len(value)} bytes, at most {self.max_bytes} per message")
        out += value

    def decode(self, name: str, r: _Reader, ctx: Mapping[str, Any]) -> Any:
        return r.take(len(r.buf) - r.pos, name)


# --- layouts -------------------------------------------------------------------------------

_U8, _U16, _U32, _U64 = UInt(1), UInt(2), UInt(4), UInt(8)
_SEQ16 = UInt(2, wrap=True)
_APPLY_AT = UInt(4, wrap=True)

#: Header fields before CameraChunk.data: request_id u32, index u16, total u16.
MAX_CHUNK_DATA = MAX_PAYLOAD - 8
#: CameraResend.wanted: one bit per chunk after request_id u32, first u16 (1 976 chunks per request)
MAX_RESEND_BITMAP = MAX_PAYLOAD - 6

Layout = list[tuple[str, Field]]

#: Message type -> its dataclass.
MESSAGE_CLASSES: dict[MsgType, type] = {
    MsgType.HELLO: m.Hello,
    MsgType.CAPS: m.Caps,
    MsgType.TIME_SYNC_REQUEST: m.TimeSyncRequest,
    MsgType.TIME_SYNC_REPLY: m.TimeSyncReply,
    MsgType.CONFIG: m.Config,
    MsgType.HEARTBEAT: m.Heartbeat,
    MsgType.ADVANCE: m.Advance,
    MsgType.SERVO_FRAME: m.ServoFrame,
    MsgType.FLUSH: m.Flush,
    MsgType.ESTOP: m.Estop,
    MsgType.ESTOP_CLEAR: m.EstopClear,
    MsgType.TELEMETRY: m.Telemetry,
    MsgType.SIM_STATE: m.SimState,
    MsgType.ACK: m.Ack,
    MsgType.NACK: m.Nack,
    MsgType.SCREEN: m.ScreenCommand,
    MsgType.SPEAKER: m.SpeakerCommand,
    MsgType.CAMERA_CAPTURE: m.CameraCapture,
    MsgType.CAMERA_CHUNK: m.CameraChunk,
    MsgType.CAMERA_RESEND: m.CameraResend,
}

def _layouts(max_servos: int) -> dict[MsgType, Layout]:
    """Message type -> ordered wire fields (names match the dataclass fields) for robots of up to
    ``max_servos`` servos: only SERVO_FRAME, FLUSH and TELEMETRY depend on it."""
    mask = Mask(max_servos)
    n = max_servos
    return {
        MsgType.HELLO: [("protocol_version", _U8), ("schema_hash", _U32), ("host_time_us", _U64)],
        MsgType.CAPS: [
            ("protocol_version", _U8),
            ("schema_hash", _U32),
            ("servo_count", _U8),
            ("control_rate_hz", _U16),
            ("buffer_depth", _U16),
            ("telemetry_rate_hz", _U16),
            ("board_time_us", _U64),
            ("lockstep", Bool()),
            ("robot", Str8(MAX_NAME_BYTES)),
            ("servo_table_hash", _U32),
        ],
        MsgType.TIME_SYNC_REQUEST: [("t1_host_us", _U64)],
        MsgType.TIME_SYNC_REPLY: [("t1_host_us", _U64), ("t2_board_us", _U64), ("t3_board_us", _U64)],
        MsgType.CONFIG: [("key", EnumU8(m.ConfigKey)), ("value", SInt(4))],
        MsgType.HEARTBEAT: [("sender_time_us", _U64)],
        MsgType.ADVANCE: [("until_us", _U64)],
        MsgType.SERVO_FRAME: [
            ("apply_at_us", _APPLY_AT),
            ("mask", mask),
            ("targets", Q16Array(10_000, mask_field="mask", allow_nan=False, max_count=n, unit="rad")),
        ],
        MsgType.FLUSH: [("from_us", _U64), ("mask", mask)],
        MsgType.ESTOP: [],
        MsgType.ESTOP_CLEAR: [],
        MsgType.TELEMETRY: [
            ("board_time_us", _U64),
            ("positions", Q16Array(10_000, max_count=n, unit="rad")),
            ("velocities", Q16Array(1_000, max_count=n, unit="rad/s")),
            ("efforts", Q16Array(1_000, max_count=n, unit="N*m")),
            ("imu_rpy", Q16Array(10_000, fixed=3, unit="rad")),
            ("faults", Flags16(m.FaultFlags)),
            ("buffer_fill", _U16),
            ("last_applied_seq", _SEQ16),
            ("late_count", _U32),
            ("dropped_count", _U32),
            ("link_errors", _U32),
        ],
        MsgType.SIM_STATE: [("board_time_us", _U64), ("base_pos", F32Array(3, "m")), ("base_quat", F32Array(4, "1")),
                            ("objects", _U8), ("toppled", _U8)],
        MsgType.ACK: [("ack_seq", _SEQ16), ("msg_type", EnumU8(MsgType))],
        MsgType.NACK: [
            ("ack_seq", _SEQ16),
            ("msg_type", EnumU8(MsgType)),
            ("reason", EnumU8(m.NackReason)),
            ("detail", Str8(MAX_NACK_DETAIL_BYTES)),
        ],
        MsgType.SCREEN: [
            ("target", EnumU8(m.ScreenTarget)),
            ("name", Str8(MAX_NAME_BYTES)),
            ("start_at_us", _U64),
            ("duration_ms", _U32),
        ],
        MsgType.SPEAKER: [
            ("action", EnumU8(m.SpeakerAction)),
            ("kind", EnumU8(m.SoundKind)),
            ("start_at_us", _U64),
            ("duration_ms", _U32),
            ("volume", UInt(1)),  # clamps; the board clamps to 0..100
            ("name", Str8(MAX_NAME_BYTES)),
            ("text", Str8(MAX_SPEECH_TEXT_BYTES, "utf-8")),
        ],
        MsgType.CAMERA_CAPTURE: [("request_id", _U32), ("width", _U16), ("height", _U16)],
        MsgType.CAMERA_CHUNK: [
            ("request_id", _U32),
            ("index", _U16),
            ("total", _U16),
            ("data", RestBytes(MAX_CHUNK_DATA)),
        ],
        MsgType.CAMERA_RESEND: [("request_id", _U32), ("first", _U16), ("wanted", RestBytes(MAX_RESEND_BITMAP))],
    }


def field_unit(name: str, f: Field) -> str:
    """Unit of a field's decoded value: the array's declared unit (``"rad"``, ``"rad/s"``, ``"N*m"``,
    ``"m"``), else by the name's suffix: ``_us`` -> ``"us"``, ``_ms`` -> ``"ms"``, ``_hz`` -> ``"Hz"``;
    ``""`` for counts, flags and enums."""
    unit = getattr(f, "unit", "")
    if unit:
        return str(unit)
    for suffix, u in (("_us", "us"), ("_ms", "ms"), ("_hz", "Hz")):
        if name.endswith(suffix):
            return u
    return ""


# --- the CAN form of the real-time messages ----------------------------------------------------


@dataclass(frozen=True)
class CanField:
    """How one field of :data:`LAYOUTS` travels in a fixed CAN layout, where that differs from what
    :mod:`protocol.can.layouts` derives from the serial field (one signal of the serial width; a servo
    mask as wide as the schema's; a per-servo array as one int16 signal per servo of the robot,
    named ``FIELD_01`` ..; a fixed array as ``FIELD_0`` ..).

    ``bits``: the width on CAN when narrower than on serial; ``clamped``: larger values saturate at
    the CAN width (the DBC comment says so); ``signals``: a per-servo array's signal name prefix
    (``"target"`` -> ``target_01`` .. ``target_NN``) or a fixed array's signal names; ``comment``:
    the DBC comment (default: derived, :func:`protocol.can.layouts.message_signals`); ``omitted``: not
    carried on CAN: the message goes as ISO-TP bulk when the field is not empty, and a fixed-layout
    message decodes with it empty."""

    bits: int | None = None
    clamped: bool = False
    signals: str | tuple[str, ...] | None = None
    comment: str = ""
    omitted: bool = False


#: u64 microseconds on serial travel as u48 on CAN (8.9 years; larger values clamp)
_CAN_TIME = CanField(bits=48, clamped=True)
#: u32 telemetry counters travel as u24 on CAN (16 777 215; larger values clamp)
_CAN_COUNTER = CanField(bits=24, clamped=True)

#: The messages that have a fixed CAN layout (the real-time path; every other message travels as
#: ISO-TP bulk with its serial payload), each with the CAN form of the fields that differ from the
#: serial one (field name -> :class:`CanField`). Signals follow the serial layout's field order;
#: :mod:`protocol.can.layouts` places them per robot servo count, :mod:`protocol.can.codec` packs the
#: values, :mod:`protocol.can.make_dbc` writes the DBC, :mod:`protocol.refdoc` the reference from it.
CAN_FIXED: Mapping[MsgType, Mapping[str, CanField]] = {
    MsgType.ESTOP: {},
    MsgType.ESTOP_CLEAR: {},
    MsgType.SERVO_FRAME: {
        "apply_at_us": CanField(comment="board clock modulo 2**32"),
        "mask": CanField(comment="bit i = servo i+1 present"),
        "targets": CanField(signals="target"),
    },
    MsgType.TIME_SYNC_REQUEST: {"t1_host_us": _CAN_TIME},
    MsgType.TIME_SYNC_REPLY: {"t1_host_us": _CAN_TIME, "t2_board_us": _CAN_TIME, "t3_board_us": _CAN_TIME},
    MsgType.FLUSH: {"from_us": _CAN_TIME, "mask": CanField(comment="bit i = servo i+1")},
    MsgType.ADVANCE: {"until_us": _CAN_TIME},
    MsgType.HEARTBEAT: {"sender_time_us": _CAN_TIME},
    MsgType.ACK: {},
    MsgType.NACK: {"detail": CanField(omitted=True)},
    MsgType.TELEMETRY: {
        "board_time_us": _CAN_TIME,
        "positions": CanField(signals="position"),
        "velocities": CanField(signals="velocity"),
        "efforts": CanField(signals="effort"),
        "imu_rpy": CanField(signals=("imu_roll", "imu_pitch", "imu_yaw")),
        "late_count": _CAN_COUNTER,
        "dropped_count": _CAN_COUNTER,
        "link_errors": _CAN_COUNTER,
    },
}



_TYPE_OF_CLASS: dict[type, MsgType] = {cls: t for t, cls in MESSAGE_CLASSES.items()}


def _check_layouts(layouts: Mapping[MsgType, Layout]) -> None:
    assert set(MESSAGE_CLASSES) == set(MsgType), "every MsgType needs a class"
    assert set(layouts) == set(MsgType), "every MsgType needs a layout"
    for t, cls in MESSAGE_CLASSES.items():
        names = [f.name for f in dataclasses.fields(cls)]
        assert names == [n for n, _ in layouts[t]], f"{t.name}: layout fields {layouts[t]} != {names}"
    for t, forms in CAN_FIXED.items():
        unknown = set(forms) - {n for n, _ in layouts[t]}
        assert not unknown, f"CAN_FIXED[{t.name}] names fields the layout does not have: {sorted(unknown)}"


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
        _check_layouts(layouts)
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
