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

Scales are the serial codec's (:mod:`protocol.codec`): positions and IMU angles 1e-4 rad,
velocities 1e-3 rad/s, efforts 1e-3 N*m, all int16 with -32768 = unknown (NaN). Times that are
u64 in the serial codec travel as u48 microseconds (8.9 years; larger values clamp), except
SERVO_FRAME's apply-at, which is u32 modulo 2**32 as on serial. Telemetry counters travel as
u24 (clamped at 16 777 215).

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

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

from protocol.can.frame import fd_length
from protocol.can.ids import FunctionCode
from protocol.codec import WireSchema, schema_for
from protocol.messages import MsgType

__all__ = [
    "CRC_SIGNAL",
    "CanLayouts",
    "DEFAULT_SERVO_COUNT",
    "HEADER_BITS",
    "PART_BITS",
    "SEQ_BITS",
    "FIXED_LAYOUTS",
    "FixedLayout",
    "Placed",
    "SignalSpec",
    "can_layouts",
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


def _q16(name: str, scale: float, unit: str) -> SignalSpec:
    return SignalSpec(name, 16, True, scale, unit, "int16; -32768 = unknown (NaN)")


U48_TIME = "u48 microseconds (clamped)"


def _signals(n: int) -> dict[MsgType, tuple[FunctionCode, list[SignalSpec]]]:
    """Message type -> (function code, signals) for a robot of ``n`` servos."""
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


# Heartbeats exist in both directions with their own identifiers (one transmitter per id).
HEARTBEAT_SIGNALS = [SignalSpec("sender_time_us", 48, unit="us", comment=U48_TIME)]


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
    servos); ``schema``: the serial payload schema the bulk (ISO-TP) messages are encoded with."""

    servo_count: int
    fixed: Mapping[tuple[FunctionCode, bool], FixedLayout]
    schema: WireSchema

    @property
    def mask_bits(self) -> int:
        return 16 if self.servo_count <= 16 else 32

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
    out: dict[tuple[FunctionCode, bool], FixedLayout] = {}
    for fd in (False, True):
        for t, (fn, sigs) in _signals(n).items():
            try:
                out[(fn, fd)] = _build(t, fn, sigs, fd, n)
            except TooManyParts:
                continue  # no fixed layout in this frame kind: ISO-TP bulk (module docstring)
        for fn in (FunctionCode.HEARTBEAT_HOST, FunctionCode.HEARTBEAT_BOARD):
            out[(fn, fd)] = _build(MsgType.HEARTBEAT, fn, HEARTBEAT_SIGNALS, fd, n)
    return CanLayouts(n, out, schema)


#: (function code, is_fd) -> layout, for every fixed-layout function code, for :data:`DEFAULT_SERVO_COUNT` servos.
FIXED_LAYOUTS: Mapping[tuple[FunctionCode, bool], FixedLayout] = can_layouts(DEFAULT_SERVO_COUNT).fixed
