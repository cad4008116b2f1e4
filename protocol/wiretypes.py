"""Wire field types and the message declaration machinery: what :mod:`protocol.messages` declares each
message with, and what :mod:`protocol.codec` (serial payloads), :mod:`protocol.can.layouts` (fixed CAN
layouts), :mod:`protocol.cgen` (the C codec), :mod:`protocol.can.make_dbc` (DBCs) and
:mod:`protocol.wire_tables` (the wire reference) read back from that one declaration.

A message is one class (:func:`message`): its :class:`~protocol.messages.MsgType`, its sender
(:class:`Sender`), its CAN form (a fixed CAN layout or ISO-TP bulk) and, per field, the wire type with its
unit (:func:`wire`: a :class:`Field`, or a :class:`PerSchema` for the fields whose form depends on the
robot's servo count) and, for a fixed-layout message, the field's CAN form where it differs from the
serial one (:class:`CanField`). Integers are little-endian; scales and the out-of-range policy are in
:mod:`protocol.codec`'s docstring. Pure: no I/O.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum, IntEnum, IntFlag
from typing import Any, TypeVar, dataclass_transform

#: Servos the default wire schema carries (its servo mask is a u16): every robot with up to 16 servos.
MAX_SERVOS = 16
#: The most servos the wire carries (robots with 17..32 servos use the u32-mask schema,
#: :func:`protocol.codec.schema_for`). Why 32: the servo mask is at most one u32, one register on an MCU,
#: and a 32-servo TELEMETRY (227 payload bytes) still fits a serial frame's 255-byte payload.
MAX_WIRE_SERVOS = 32

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



#: Header fields before CameraChunk.data: request_id u32, index u16, total u16.
MAX_CHUNK_DATA = MAX_PAYLOAD - 8
#: CameraResend.wanted: one bit per chunk after request_id u32, first u16 (1 976 chunks per request)
MAX_RESEND_BITMAP = MAX_PAYLOAD - 6

U8, U16, U32, U64 = UInt(1), UInt(2), UInt(4), UInt(8)
#: a 16-bit sequence number: wraps modulo 2**16 like the frame sequence
SEQ16 = UInt(2, wrap=True)
#: SERVO_FRAME's apply-at: u32 microseconds modulo 2**32
APPLY_AT = UInt(4, wrap=True)


class PerSchema:
    """A wire field whose form depends on the schema's servo count (a servo mask, a per-servo array):
    ``make(max_servos)`` gives the :class:`Field` of the schema for robots of up to ``max_servos`` servos."""

    def __init__(self, make: Callable[[int], Field]) -> None:
        self.make = make

    def bind(self, max_servos: int) -> Field:
        return self.make(max_servos)


#: the servo mask of the schema (u16 up to 16 servos, else u32)
MASK = PerSchema(Mask)


def per_servo(counts_per_unit: int, unit: str, **kw: Any) -> PerSchema:
    """A q16 array with one value per servo of the schema (:class:`Q16Array` with ``max_count`` = the
    schema's servos; ``kw``: its ``mask_field``, ``allow_nan``)."""
    return PerSchema(lambda n: Q16Array(counts_per_unit, max_count=n, unit=unit, **kw))


WireSpec = Field | PerSchema


def bind(spec: WireSpec, max_servos: int) -> Field:
    """The field ``spec`` stands for in the schema of ``max_servos`` servos."""
    return spec.bind(max_servos) if isinstance(spec, PerSchema) else spec


# --- the CAN form of the real-time messages ----------------------------------------------------


@dataclass(frozen=True)
class CanField:
    """How one field of a message declared ``can_fixed`` travels in a fixed CAN layout, where that differs from what
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
CAN_TIME = CanField(bits=48, clamped=True)
#: u32 telemetry counters travel as u24 on CAN (16 777 215; larger values clamp)
CAN_COUNTER = CanField(bits=24, clamped=True)


# --- the message declaration -------------------------------------------------------------------


class Sender(Enum):
    """Which end sends a message (as a DBC names a message's transmitter); the value is how the wire
    reference says it."""

    HOST = "host → board"
    BOARD = "board → host"
    EITHER = "both"


@dataclass(frozen=True)
class MessageSpec:
    """One declared message: its type, class, sender, whether it has a fixed CAN layout (else it travels
    on CAN as ISO-TP bulk with its serial payload), and its fields in wire order as
    ``(name, wire type, CAN form or None)``."""

    msg_type: IntEnum
    cls: type
    sender: Sender
    can_fixed: bool
    fields: tuple[tuple[str, WireSpec, CanField | None], ...]

    def layout(self, max_servos: int) -> list[tuple[str, Field]]:
        """The ordered wire fields of this message in the schema for ``max_servos`` servos."""
        return [(name, bind(spec, max_servos)) for name, spec, _ in self.fields]

    def can_forms(self) -> dict[str, CanField]:
        """Field name -> its CAN form, for the fields whose CAN form differs from the serial one."""
        return {name: can for name, _, can in self.fields if can is not None}


#: every declared message, in declaration order (type number -> its declaration); filled by :func:`message`
DECLARED: dict[int, MessageSpec] = {}

_C = TypeVar("_C", bound=type)


def wire(spec: WireSpec, *, can: CanField | None = None, default: Any = dataclasses.MISSING,
         repr: bool = True) -> Any:
    """Declare one message field: its wire type ``spec`` (the unit rides on it: an array's ``unit``,
    else the name's suffix, :func:`field_unit`), its CAN form ``can`` where it differs from the serial
    one (fixed-layout messages only), a ``default`` value and whether ``repr`` shows it."""
    return dataclasses.field(default=default, repr=repr, metadata={"wire": spec, "can": can})


@dataclass_transform(frozen_default=True, field_specifiers=(wire,))
def message(msg_type: IntEnum, sender: Sender, *, can_fixed: bool = False) -> Callable[[_C], _C]:
    """Class decorator: the class becomes a frozen dataclass, the message ``msg_type`` sent by ``sender``
    (``can_fixed``: it has a fixed CAN layout), registered in :data:`DECLARED`. Every field must be
    declared with :func:`wire`. ``ValueError`` for a type declared twice, a field without a wire type,
    or a CAN form on a message without a fixed CAN layout."""

    def register(cls: _C) -> _C:
        dataclass(frozen=True)(cls)  # in place: the same class object, now a frozen dataclass
        fields = []
        for f in dataclasses.fields(cls):
            spec = f.metadata.get("wire")
            if not isinstance(spec, (Field, PerSchema)):
                raise ValueError(f"{cls.__name__}.{f.name}: declare it with wire(<wire type>)")
            if f.metadata["can"] is not None and not can_fixed:
                raise ValueError(f"{cls.__name__}.{f.name}: a CAN form on a message that travels as ISO-TP bulk")
            fields.append((f.name, spec, f.metadata["can"]))
        if int(msg_type) in DECLARED:
            raise ValueError(f"{msg_type!r} declared twice ({DECLARED[int(msg_type)].cls.__name__}, {cls.__name__})")
        DECLARED[int(msg_type)] = MessageSpec(msg_type, cls, sender, can_fixed, tuple(fields))
        return cls

    return register
