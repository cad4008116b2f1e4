"""Fixed CAN layouts of the real-time messages: signals, their placement in frames, raw values.

Every fixed-layout frame starts with a 16-bit little-endian header::

    bits 0..4   part   index of this frame within the message (0..31), the DBC multiplexer
    bits 5..15  seq    the protocol's 16-bit sequence number modulo 2**11

The rest of the frame carries signals, little-endian, never straddling a frame. A message whose
signals do not fit one frame is split into a fixed set of *parts* (classic CAN: 6 data bytes per
part; CAN FD: 62); all parts carry the same ``seq`` and a receiver surfaces the message only when
every part with that ``seq`` has arrived (:mod:`protocol.can.decoder`). Signals are placed in
declaration order, greedily: a signal that does not fit the rest of a part starts the next part.

The 11-bit ``seq`` maps to the 16-bit protocol sequence consistently: the receiver takes the
16-bit value nearest to the last sequence it saw from that sender whose low 11 bits match
(:func:`unwrap_seq`). Bulk (ISO-TP) messages carry the full 16 bits and re-anchor it. This is
exact while fewer than 1024 messages separate two received ones, far beyond what a sender has in
flight (the host sends a full-sequence TIME_SYNC every 0.5 s and a HEARTBEAT when idle).

Every message with signals (all but ESTOP and ESTOP_CLEAR, whose only content is the header) ends
with ``crc16``: CRC-16/X-25 (the serial framing's CRC, :data:`protocol.framing.CRC_NAME`) over the
data bytes of all its parts packed with this field zero, in part order, headers included; a
receiver drops a message whose CRC does not match (``CanErrorKind.CRC``). Why, when a CAN
controller already checks a 15-bit CRC per frame: that CRC protects each frame on the wire only. An
SLCAN adapter's serial line, a software (virtual) bus, a gateway or a driver bug can change data
after it, and fault injection (``--faults corrupt=P``) flips bits exactly there. Without it a single
flipped target bit would be applied as a wrong setpoint, and a flipped time bit (ADVANCE,
TIME_SYNC, TELEMETRY's board time) would throw the host's clock estimate or a lockstep board
seconds off; the header (part index, 11-bit sequence) alone cannot catch either. Cost on classic
CAN: one more part where the last one is full (SERVO_FRAME 6 parts, TIME_SYNC_REPLY 4, ADVANCE,
TIME_SYNC_REQUEST and HEARTBEAT 2); on CAN FD a few bytes (SERVO_FRAME 48 bytes).

The signals come from the one message declaration (the classes of :mod:`protocol.messages`), never from
a list of their own: :data:`protocol.codec.CAN_FIXED`, derived from the classes declared ``can_fixed``
with the ``can=`` forms of their fields, names the messages that have a fixed layout and the CAN
form of each field that differs from its serial form; :func:`message_fields` derives every signal
from the serial layout of the robot's schema and that form, in the layout's field order (integers
keep their serial width unless narrowed, a servo mask is the schema's, a per-servo array becomes one
int16 signal per servo, a fixed array one per element; a field kind with no CAN form is refused
with its name). So a field added to a real-time message reaches serial, CAN, the DBC, the C codec
and the reference at once. Scales are the serial codec's: positions and IMU angles 1e-4 rad,
velocities 1e-3 rad/s, efforts 1e-3 N*m, all int16 with -32768 = unknown (NaN). Times that are u64
in the serial codec travel as u48 microseconds (8.9 years; larger values clamp), except
SERVO_FRAME's apply-at, which is u32 modulo 2**32 as on serial. Telemetry counters travel as u24
(clamped at 16 777 215). NACK's detail text is not carried: a NACK with one goes as ISO-TP bulk.

Layouts per robot: :func:`can_layouts` builds (and caches) the table for a robot of N servos
(1 <= N <= :data:`protocol.messages.MAX_WIRE_SERVOS`): SERVO_FRAME carries ``target_01`` ..
``target_NN``, TELEMETRY ``position_NN``, ``velocity_NN``, ``effort_NN``; the ``mask`` signal of
SERVO_FRAME and FLUSH is 16 bits for N <= 16 and 32 bits above (as the serial codec's
:class:`protocol.codec.WireSchema`, which also encodes the bulk messages). A fixed layout has at
most 32 parts (the 5-bit part index), so a message that would need more has **no** fixed layout in
the table for that frame kind and travels as ISO-TP bulk instead: classic-CAN TELEMETRY takes
N + 5 parts, so a robot of more than 27 servos sends TELEMETRY over ISO-TP on classic CAN (on CAN
FD it always fits). Frames per message (classic: 8-byte parts; FD: frames x data bytes):

=====  ==========================  =============================================
N      SERVO_FRAME classic / FD    TELEMETRY classic / FD
=====  ==========================  =============================================
1      2 parts / 1 x 12 B          6 parts / 1 x 48 B
12     6 parts / 1 x 48 B          17 parts / 2 x 64 B
16     7 parts / 1 x 48 B          21 parts / 3 x 64 B
17     8 parts / 1 x 48 B          22 parts / 3 x 64 B
27     11 parts / 2 x 64 B         32 parts / 4 x 64 B
28     12 parts / 2 x 64 B         ISO-TP, 208-byte unit (30 frames) / 4 x 64 B
32     13 parts / 2 x 64 B         ISO-TP, 232-byte unit (34 frames) / 4 x 64 B
=====  ==========================  =============================================

:data:`FIXED_LAYOUTS` is the table for :data:`DEFAULT_SERVO_COUNT` (12) servos, what callers that
name no robot get (so their frames are the ones they always were).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache

from protocol.can.frame import fd_length
from protocol.can.ids import FunctionCode
from protocol.codec import (
    CAN_FIXED,
    Bool,
    CanField,
    EnumU8,
    Field,
    Flags16,
    Mask,
    Q16Array,
    RestBytes,
    SInt,
    Str8,
    UInt,
    WireSchema,
    field_unit,
    schema_for,
)
from protocol.messages import MsgType

__all__ = [
    "CRC_SIGNAL",
    "CanLayouts",
    "CarriedField",
    "DEFAULT_SERVO_COUNT",
    "HEADER_BITS",
    "PART_BITS",
    "SEQ_BITS",
    "FIXED_LAYOUTS",
    "FixedLayout",
    "Placed",
    "SignalSpec",
    "can_layouts",
    "function_codes",
    "message_fields",
    "message_signals",
    "unwrap_seq",
]

#: the servo count of the layouts callers get when they name no robot (:data:`FIXED_LAYOUTS`)
DEFAULT_SERVO_COUNT = 12
#: name of the integrity signal a layout may end with (see the module docstring)
CRC_SIGNAL = "crc16"
PART_BITS = 5
SEQ_BITS = 11
HEADER_BITS = PART_BITS + SEQ_BITS
SEQ_MASK = (1 << SEQ_BITS) - 1
MAX_PARTS = 1 << PART_BITS
CLASSIC_PART_BITS = 64 - HEADER_BITS  # 6 data bytes
FD_PART_BITS = 512 - HEADER_BITS  # 62 data bytes


@dataclass(frozen=True)
class SignalSpec:
    """One signal: raw integer of ``bits`` bits; physical = raw * ``scale`` in ``unit``."""

    name: str
    bits: int
    signed: bool = False
    scale: float = 1.0
    unit: str = ""
    comment: str = ""


@dataclass(frozen=True)
class Placed:
    """A signal placed in part ``part`` at little-endian start bit ``start`` of the frame."""

    spec: SignalSpec
    part: int
    start: int


@dataclass(frozen=True)
class FixedLayout:
    """The CAN form of one message type for one frame kind (classic or FD)."""

    msg_type: MsgType
    fn: FunctionCode
    fd: bool
    signals: tuple[Placed, ...]
    parts: int
    length: int  # bytes of every frame of this message (classic: <= 8; FD: a valid FD length)
    part_bytes: tuple[int, ...]  # bytes each part needs (header included)
    servos: int = DEFAULT_SERVO_COUNT  # the robot's servo count this layout is for

    def __hash__(self) -> int:
        # one layout per (message type, frame kind, servo count): hashing that, not every nested
        # signal, keeps the per-frame lookups keyed by layout (``codec._part_signals``) cheap
        return hash((self.msg_type, self.fd, self.servos))

    @property
    def name(self) -> str:
        return self.msg_type.name

    @property
    def has_crc(self) -> bool:
        """True when the message ends with the ``crc16`` integrity signal (every one with signals)."""
        return any(p.spec.name == CRC_SIGNAL for p in self.signals)


def unwrap_seq(seq11: int, reference: int) -> int:
    """16-bit sequence nearest to ``reference`` (mod 2**16) whose low 11 bits are ``seq11``."""
    span = 1 << SEQ_BITS
    delta = (int(seq11) - int(reference)) % span
    if delta >= span // 2:
        delta -= span
    return (int(reference) + delta) & 0xFFFF


class TooManyParts(ValueError):
    """The signals of a message need more parts than the 5-bit part index counts."""


def _place(signals: list[SignalSpec], part_bits: int) -> tuple[list[Placed], int, list[int]]:
    placed: list[Placed] = []
    part, used = 0, 0
    used_by_part = [0]
    for s in signals:
        if s.bits > part_bits:
            raise AssertionError(f"signal {s.name} ({s.bits} bits) cannot fit a part")
        if used + s.bits > part_bits:
            part, used = part + 1, 0
            used_by_part.append(0)
        placed.append(Placed(s, part, HEADER_BITS + used))
        used += s.bits
        used_by_part[part] = used
    nparts = part + 1
    if nparts > MAX_PARTS:
        raise TooManyParts(f"{nparts} parts do not fit the {PART_BITS}-bit part index")
    return placed, nparts, [(HEADER_BITS + u + 7) // 8 for u in used_by_part]


@dataclass(frozen=True)
class CarriedField:
    """One field of a message's serial layout and the CAN signals that carry it, in order
    (``signals`` empty: the field is omitted on CAN, :attr:`protocol.codec.CanField.omitted`)."""

    name: str
    field: Field
    form: CanField
    signals: tuple[SignalSpec, ...]


Q16_COMMENT = "int16; -32768 = unknown (NaN)"
_PLAIN = CanField()  # a field CAN_FIXED does not mention: its serial form


def _comment(form: CanField, unit: str, bits: int, default: str = "") -> str:
    if form.comment:
        return form.comment
    if form.clamped:
        return f"u{bits} microseconds (clamped)" if unit == "us" else "clamped"
    return default


def _field_signals(t: MsgType, name: str, f: Field, form: CanField, n: int) -> tuple[SignalSpec, ...]:
    """The signals of one serial field for a robot of ``n`` servos (rules: :class:`CanField`)."""
    if form.omitted:
        if not isinstance(f, (Str8, RestBytes)):
            raise ValueError(f"{t.name}.{name}: only a text or byte field can be omitted on CAN (it travels "
                             "when empty, the message goes as bulk otherwise)")
        return ()
    unit = field_unit(name, f)
    if isinstance(f, (UInt, SInt, Mask)):
        bits = form.bits or 8 * f.size
        return (SignalSpec(name, bits, isinstance(f, SInt), 1.0, unit, _comment(form, unit, bits)),)
    if isinstance(f, (Bool, EnumU8)):
        return (SignalSpec(name, 8, comment=_comment(form, unit, 8)),)
    if isinstance(f, Flags16):
        return (SignalSpec(name, 16, comment=_comment(form, unit, 16, f.cls.__name__)),)
    if isinstance(f, Q16Array):
        if f.fixed is not None:
            names = form.signals if isinstance(form.signals, tuple) else tuple(f"{name}_{i}" for i in range(f.fixed))
            if len(names) != f.fixed:
                raise ValueError(f"{t.name}.{name}: {len(names)} CAN signal names for {f.fixed} values")
        else:  # one signal per servo of the robot (a mask's unset bits and missing values: -32768)
            prefix = form.signals if isinstance(form.signals, str) else name
            names = tuple(f"{prefix}_{i + 1:02d}" for i in range(n))
        return tuple(SignalSpec(k, 16, True, 1 / f.cpu, unit, form.comment or Q16_COMMENT) for k in names)
    raise ValueError(f"{t.name}.{name}: a {type(f).__name__} ({f.wire}) has no fixed CAN form; declare it "
                     "omitted in protocol.codec.CAN_FIXED or let the message travel as ISO-TP bulk")


def message_fields(t: MsgType, layout: Sequence[tuple[str, Field]], forms: Mapping[str, CanField],
                   n: int) -> tuple[CarriedField, ...]:
    """Every field of ``layout`` (a message's serial layout) with its CAN signals for a robot of ``n``
    servos, given the message's CAN forms (:data:`protocol.codec.CAN_FIXED`); ``ValueError`` for a field
    that cannot travel in a fixed layout."""
    out = []
    for name, f in layout:
        form = forms.get(name, _PLAIN)
        out.append(CarriedField(name, f, form, _field_signals(t, name, f, form, n)))
    return tuple(out)


def message_signals(t: MsgType, layout: Sequence[tuple[str, Field]], forms: Mapping[str, CanField],
                    n: int) -> list[SignalSpec]:
    """The CAN signals of one message, in order (before the ``crc16`` the layout appends)."""
    return [s for cf in message_fields(t, layout, forms, n) for s in cf.signals]


def function_codes(t: MsgType) -> tuple[FunctionCode, ...]:
    """The identifiers' function codes a fixed-layout message type travels with: HEARTBEAT has one per
    direction (one transmitter per identifier), every other its namesake."""
    if t is MsgType.HEARTBEAT:
        return (FunctionCode.HEARTBEAT_HOST, FunctionCode.HEARTBEAT_BOARD)
    return (FunctionCode[t.name],)


CRC_SPEC = SignalSpec(CRC_SIGNAL, 16, comment="CRC-16/X-25 over every part of the message with this field zero")


def _build(msg_type: MsgType, fn: FunctionCode, signals: list[SignalSpec], fd: bool, n: int) -> FixedLayout:
    if signals:  # every message with content ends with the integrity CRC (module docstring)
        signals = [*signals, CRC_SPEC]
    placed, nparts, part_bytes = _place(signals, FD_PART_BITS if fd else CLASSIC_PART_BITS)
    longest = max(part_bytes)
    length = fd_length(longest) if fd else (8 if nparts > 1 else longest)
    return FixedLayout(msg_type, fn, fd, tuple(placed), nparts, length, tuple(part_bytes), n)


@dataclass(frozen=True, eq=False)
class CanLayouts:
    """The CAN form of the protocol for a robot of ``servo_count`` servos.

    ``fixed``: (function code, is_fd) -> layout, for every message that has a fixed layout in that
    frame kind (absent: the message travels as ISO-TP bulk there, e.g. classic TELEMETRY above 27
    servos); ``fields``: message type -> its serial fields with the signals carrying each (what
    :mod:`protocol.can.codec` packs values by), for every message of :data:`protocol.codec.CAN_FIXED`;
    ``schema``: the serial payload schema the bulk (ISO-TP) messages are encoded with."""

    servo_count: int
    fixed: Mapping[tuple[FunctionCode, bool], FixedLayout]
    schema: WireSchema
    fields: Mapping[MsgType, tuple[CarriedField, ...]]

    @property
    def mask_bits(self) -> int:
        return 8 * self.schema.mask_bytes

    def layout(self, fn: FunctionCode, fd: bool) -> FixedLayout | None:
        """The fixed layout of ``fn`` in this frame kind (None: that message goes as ISO-TP bulk)."""
        return self.fixed.get((fn, bool(fd)))


def can_layouts(servo_count: int = DEFAULT_SERVO_COUNT) -> CanLayouts:
    """The layout table for a robot of ``servo_count`` servos (cached: one value per N);
    :class:`protocol.codec.WireBoundError` (a ``ValueError``) outside 1..32."""
    return _can_layouts(int(servo_count))


@lru_cache(maxsize=None)
def _can_layouts(n: int) -> CanLayouts:
    schema = schema_for(n)  # refuses a count the wire cannot carry
    fields = {t: message_fields(t, schema.layouts[t], forms, n) for t, forms in CAN_FIXED.items()}
    out: dict[tuple[FunctionCode, bool], FixedLayout] = {}
    for fd in (False, True):
        for t, carried in fields.items():
            sigs = [s for cf in carried for s in cf.signals]
            for fn in function_codes(t):
                try:
                    out[(fn, fd)] = _build(t, fn, sigs, fd, n)
                except TooManyParts:
                    continue  # no fixed layout in this frame kind: ISO-TP bulk (module docstring)
    return CanLayouts(n, out, schema, fields)


#: (function code, is_fd) -> layout, for every fixed-layout function code, for :data:`DEFAULT_SERVO_COUNT` servos.
FIXED_LAYOUTS: Mapping[tuple[FunctionCode, bool], FixedLayout] = can_layouts(DEFAULT_SERVO_COUNT).fixed
