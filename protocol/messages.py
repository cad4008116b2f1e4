"""The GhostShell wire protocol, version 1: the message set, each message declared once.

This module is the contract shared by the host and the board. Each message is one frozen dataclass
declared with :func:`protocol.wiretypes.message`: its :class:`MsgType`, its sender, its CAN form (a fixed
CAN layout or ISO-TP bulk) and, per field, its wire type (which carries the unit) and CAN form. Everything
else is derived from these classes: :data:`HOST_TO_BOARD` / :data:`BOARD_TO_HOST` here, the payload
layouts, schema hashes, :data:`protocol.codec.MESSAGE_CLASSES` and :data:`protocol.codec.CAN_FIXED`,
the CAN layouts, the C codec, the DBCs and the wire reference. Adding a message: a :class:`MsgType`
member, its class below (listed in :data:`Message`; import fails otherwise), and a handler on each end.
No I/O and no encoding here: :mod:`protocol.codec` packs messages into payloads and
:mod:`protocol.framing` puts payloads on the wire.

Units: times are integer microseconds (board clock unless the field says host),
positions radians, velocities rad/s, efforts N*m. Servo ``i`` (0-based) is the
servo with id ``i + 1`` in the robot's servo table; a ``mask`` has bit ``i`` set
for every servo a message covers, and per-servo tuples list only the masked
servos in ascending index order. A robot has 1 to :data:`MAX_WIRE_SERVOS` servos; the mask
travels as a u16 for robots of up to :data:`MAX_SERVOS` servos and as a u32 above
(:class:`protocol.codec.WireSchema`).
"""

from __future__ import annotations

import typing
from enum import IntEnum, IntFlag

from protocol.wiretypes import (
    APPLY_AT,
    CAN_COUNTER,
    CAN_TIME,
    DECLARED,
    MASK,
    MAX_CHUNK_DATA,
    MAX_NACK_DETAIL_BYTES,
    MAX_NAME_BYTES,
    MAX_RESEND_BITMAP,
    MAX_SERVOS,
    MAX_SPEECH_TEXT_BYTES,
    MAX_WIRE_SERVOS,
    SEQ16,
    U8,
    U16,
    U32,
    U64,
    Bool,
    CanField,
    EnumU8,
    F32Array,
    Flags16,
    Q16Array,
    RestBytes,
    Sender,
    SInt,
    Str8,
    UInt,
    message,
    per_servo,
    wire,
)

__all__ = ["MAX_SERVOS", "MAX_WIRE_SERVOS"]  # re-exported: many modules import them from here

PROTOCOL_VERSION = 1


class MsgType(IntEnum):
    """Message type byte carried in every frame header."""

    HELLO = 0x01
    CAPS = 0x02
    TIME_SYNC_REQUEST = 0x03
    TIME_SYNC_REPLY = 0x04
    CONFIG = 0x05
    HEARTBEAT = 0x06
    ADVANCE = 0x07
    SERVO_FRAME = 0x10
    FLUSH = 0x11
    ESTOP = 0x12
    ESTOP_CLEAR = 0x13
    TELEMETRY = 0x20
    SIM_STATE = 0x21
    ACK = 0x22
    NACK = 0x23
    SCREEN = 0x30
    SPEAKER = 0x31
    CAMERA_CAPTURE = 0x32
    CAMERA_CHUNK = 0x33
    CAMERA_RESEND = 0x34



class NackReason(IntEnum):
    """Why the board refused a message."""

    UNSPECIFIED = 0
    VERSION_MISMATCH = 1
    SCHEMA_MISMATCH = 2
    LATE = 3  # apply-at time already past beyond tolerance
    TOO_FAR_FUTURE = 4
    BUFFER_FULL = 5
    ESTOPPED = 6
    FAULT_LATCHED = 7
    BAD_VALUE = 8
    UNSUPPORTED = 9
    NO_RENDERER = 10
    BUSY = 11
    NOT_LOCKSTEP = 12
    SERVO_FAULT = 13  # a servo stopped answering on the board's servo bus (detail names it)


#: what each reason means, for a NACK that carries no detail: the CAN board sends a NACK to a SERVO_FRAME
#: as one fixed frame, reason code only (the text would need an ISO-TP transfer). Where the Python board's
#: detail says nothing beyond the reason (ESTOPPED, FAULT_LATCHED, NOT_LOCKSTEP), the text is that detail,
#: so a serial and a CAN link say the same.
NACK_REASON_TEXT: dict[NackReason, str] = {
    NackReason.UNSPECIFIED: "no reason given",
    NackReason.VERSION_MISMATCH: "another protocol version",
    NackReason.SCHEMA_MISMATCH: "another wire schema",
    NackReason.LATE: "its due time had passed",
    NackReason.TOO_FAR_FUTURE: "its due time is too far ahead",
    NackReason.BUFFER_FULL: "jitter buffer full",
    NackReason.ESTOPPED: "estop active; send ESTOP_CLEAR",
    NackReason.FAULT_LATCHED: "watchdog fault latched; send ESTOP_CLEAR",
    NackReason.BAD_VALUE: "a value out of range",
    NackReason.UNSUPPORTED: "not accepted by this board",
    NackReason.NO_RENDERER: "no camera renderer",
    NackReason.BUSY: "busy",
    NackReason.NOT_LOCKSTEP: "ADVANCE needs a --lockstep board",
    NackReason.SERVO_FAULT: "a servo stopped answering on the servo bus",
}


class FaultFlags(IntFlag):
    """Fault and state bits reported in telemetry."""

    NONE = 0
    ESTOP = 0x01  # emergency stop active
    WATCHDOG_HOLD = 0x02  # link silent: holding position
    WATCHDOG_FAULT = 0x04  # latched: crouched after a long silence, needs ESTOP_CLEAR
    CLAMPED = 0x08  # a target was clamped to a joint or speed limit since last report
    TICK_OVERRUN = 0x10  # realtime loop missed a deadline since last report
    LINK_ERRORS = 0x20  # bad frames were received since last report
    SERVO_FAULT = 0x40  # latched: a servo stopped answering on the servo bus; the others hold; needs ESTOP_CLEAR


class ConfigKey(IntEnum):
    """Board settings the host may change at run time (value is an int)."""

    TELEMETRY_RATE_HZ = 1
    WATCHDOG_MS = 2
    MAX_LATE_US = 3
    MAX_FUTURE_US = 4
    CROUCH_AFTER_MS = 5


class SpeakerAction(IntEnum):
    PLAY = 0
    STOP = 1


class SoundKind(IntEnum):
    SPEECH = 0
    CLIP = 1  # background music or a sound effect


class ScreenTarget(IntEnum):
    FACE = 0  # whole-face expression
    EYES = 1  # eye animation
    EARS = 2  # ear light animation


# --- the messages -------------------------------------------------------------------------------
#
# One class per message, the only place it is declared: its type (MsgType above), its sender, its CAN form
# (``can_fixed``: a fixed CAN layout; else ISO-TP bulk), and per field its wire type with its unit and, on
# CAN, its form where it differs from serial (protocol.wiretypes.wire). The serial layouts and schema hash
# (protocol.codec), the CAN layouts (protocol.can.layouts), the C codec (protocol.cgen), the DBCs
# (protocol.can.make_dbc) and the wire reference (protocol.wire_tables) all derive from these classes.

# --- the real-time path: messages with a fixed CAN layout (this order is the CAN layout table's rows) ---


@message(MsgType.ESTOP, Sender.HOST, can_fixed=True)
class Estop:
    pass


@message(MsgType.ESTOP_CLEAR, Sender.HOST, can_fixed=True)
class EstopClear:
    pass


@message(MsgType.SERVO_FRAME, Sender.HOST, can_fixed=True)
class ServoFrame:
    """Targets to reach at ``apply_at_us`` on the board clock (board interpolates between frames)."""

    apply_at_us: int = wire(APPLY_AT, can=CanField(comment="board clock modulo 2**32"))
    mask: int = wire(MASK, can=CanField(comment="bit i = servo i+1 present"))
    targets: tuple[float, ...] = wire(per_servo(10_000, "rad", mask_field="mask", allow_nan=False),
                                      can=CanField(signals="target"))


@message(MsgType.TIME_SYNC_REQUEST, Sender.HOST, can_fixed=True)
class TimeSyncRequest:
    """Host -> board: NTP-style probe; t1 is the host clock at send."""

    t1_host_us: int = wire(U64, can=CAN_TIME)


@message(MsgType.TIME_SYNC_REPLY, Sender.BOARD, can_fixed=True)
class TimeSyncReply:
    """Board -> host: t2 board clock at receive, t3 board clock at send."""

    t1_host_us: int = wire(U64, can=CAN_TIME)
    t2_board_us: int = wire(U64, can=CAN_TIME)
    t3_board_us: int = wire(U64, can=CAN_TIME)


@message(MsgType.FLUSH, Sender.HOST, can_fixed=True)
class Flush:
    """Drop buffered frames due at or after ``from_us`` for the masked servos."""

    from_us: int = wire(U64, can=CAN_TIME)
    mask: int = wire(MASK, can=CanField(comment="bit i = servo i+1"))


@message(MsgType.ADVANCE, Sender.HOST, can_fixed=True)
class Advance:
    """Host -> board, lockstep only: let the board clock run up to ``until_us``."""

    until_us: int = wire(U64, can=CAN_TIME)


@message(MsgType.HEARTBEAT, Sender.EITHER, can_fixed=True)
class Heartbeat:
    """Either direction; keeps the watchdog fed when nothing else is sent."""

    sender_time_us: int = wire(U64, can=CAN_TIME)


@message(MsgType.ACK, Sender.BOARD, can_fixed=True)
class Ack:
    ack_seq: int = wire(SEQ16)  # sequence number of the acknowledged host message
    msg_type: MsgType = wire(EnumU8(MsgType))


@message(MsgType.NACK, Sender.BOARD, can_fixed=True)
class Nack:
    ack_seq: int = wire(SEQ16)
    msg_type: MsgType = wire(EnumU8(MsgType))
    reason: NackReason = wire(EnumU8(NackReason))
    # short explanation, at most 64 bytes on the wire; not carried by the fixed CAN layout (a NACK with a
    # detail goes as ISO-TP bulk)
    detail: str = wire(Str8(MAX_NACK_DETAIL_BYTES), can=CanField(omitted=True), default="")


def nack_detail(nack: Nack) -> str:
    """The NACK's detail text, else what its reason means (:data:`NACK_REASON_TEXT`; an unknown reason
    code: ``"reason N"``): never empty, whichever link carried it."""
    if nack.detail:
        return nack.detail
    try:
        return NACK_REASON_TEXT[NackReason(nack.reason)]
    except (ValueError, KeyError):
        return f"reason {int(nack.reason)}"


@message(MsgType.TELEMETRY, Sender.BOARD, can_fixed=True)
class Telemetry:
    board_time_us: int = wire(U64, can=CAN_TIME)
    positions: tuple[float, ...] = wire(per_servo(10_000, "rad"), can=CanField(signals="position"))  # all servos, index order
    velocities: tuple[float, ...] = wire(per_servo(1_000, "rad/s"), can=CanField(signals="velocity"))
    efforts: tuple[float, ...] = wire(per_servo(1_000, "N*m"), can=CanField(signals="effort"))
    imu_rpy: tuple[float, float, float] = wire(  # body roll, pitch, yaw in radians
        Q16Array(10_000, fixed=3, unit="rad"), can=CanField(signals=("imu_roll", "imu_pitch", "imu_yaw")))
    faults: FaultFlags = wire(Flags16(FaultFlags))
    buffer_fill: int = wire(U16)
    last_applied_seq: int = wire(SEQ16)  # host sequence number of the last servo frame applied
    late_count: int = wire(U32, can=CAN_COUNTER)  # frames rejected as late, since boot
    dropped_count: int = wire(U32, can=CAN_COUNTER)  # frames rejected otherwise (future, full, estop), since boot
    link_errors: int = wire(U32, can=CAN_COUNTER)  # undecodable frames received, since boot


# --- messages that travel on CAN as ISO-TP bulk (their serial payload) ---------------------------


@message(MsgType.HELLO, Sender.HOST)
class Hello:
    """Host -> board: first message of a session."""

    protocol_version: int = wire(U8)
    schema_hash: int = wire(U32)  # u32, see protocol.codec.SCHEMA_HASH
    host_time_us: int = wire(U64)


@message(MsgType.CAPS, Sender.BOARD)
class Caps:
    """Board -> host: answer to HELLO; the host refuses a board whose robot, servo count or servo
    table hash differs from the robot it was started for."""

    protocol_version: int = wire(U8)
    schema_hash: int = wire(U32)
    servo_count: int = wire(U8)
    control_rate_hz: int = wire(U16)
    buffer_depth: int = wire(U16)  # servo frames the jitter buffer holds
    telemetry_rate_hz: int = wire(U16)
    board_time_us: int = wire(U64)
    lockstep: bool = wire(Bool())
    robot: str = wire(Str8(MAX_NAME_BYTES), default="")  # the robot the board drives (its robot.toml name)
    servo_table_hash: int = wire(U32, default=0)  # u32 over its servo table (robots.description.ServoTable.hash)


@message(MsgType.CONFIG, Sender.HOST)
class Config:
    key: ConfigKey = wire(EnumU8(ConfigKey))
    value: int = wire(SInt(4))


@message(MsgType.SIM_STATE, Sender.BOARD)
class SimState:
    """Emulator only: ground truth of the floating base (no real board can send this)."""

    board_time_us: int = wire(U64)
    base_pos: tuple[float, float, float] = wire(F32Array(3, "m"))  # metres, world frame
    base_quat: tuple[float, float, float, float] = wire(F32Array(4, "1"))  # w, x, y, z
    objects: int = wire(U8, default=0)  # movable scene objects (e.g. --scene bottles: 3)
    toppled: int = wire(U8, default=0)  # how many of them lean more than 45 deg from vertical


@message(MsgType.SCREEN, Sender.HOST)
class ScreenCommand:
    """Show an expression or animation from ``start_at_us`` for ``duration_ms`` (0 = until replaced)."""

    target: ScreenTarget = wire(EnumU8(ScreenTarget))
    name: str = wire(Str8(MAX_NAME_BYTES))  # UTF-8, at most 32 bytes
    start_at_us: int = wire(U64)
    duration_ms: int = wire(U32)


@message(MsgType.SPEAKER, Sender.HOST)
class SpeakerCommand:
    """Play or stop speech or a clip on the board clock."""

    action: SpeakerAction = wire(EnumU8(SpeakerAction))
    kind: SoundKind = wire(EnumU8(SoundKind))
    start_at_us: int = wire(U64)
    duration_ms: int = wire(U32)
    volume: int = wire(UInt(1))  # 0..100: the wire clamps to a byte, the board to 0..100
    name: str = wire(Str8(MAX_NAME_BYTES), default="")  # clip name, UTF-8, at most 32 bytes
    text: str = wire(Str8(MAX_SPEECH_TEXT_BYTES, "utf-8"), default="")  # speech text, UTF-8, at most 200 bytes


@message(MsgType.CAMERA_CAPTURE, Sender.HOST)
class CameraCapture:
    """Ask the head camera for one image."""

    request_id: int = wire(U32)
    width: int = wire(U16)
    height: int = wire(U16)


@message(MsgType.CAMERA_CHUNK, Sender.BOARD)
class CameraChunk:
    """One piece of an encoded image (PNG); ``index`` counts from 0 to ``total - 1``."""

    request_id: int = wire(U32)
    index: int = wire(U16)
    total: int = wire(U16)
    data: bytes = wire(RestBytes(MAX_CHUNK_DATA), repr=False)


@message(MsgType.CAMERA_RESEND, Sender.HOST)
class CameraResend:
    """Host -> board: send chunks of a kept image again (selective repeat over a lossy link).

    Chunk ``first + k`` is wanted when bit ``k`` of ``wanted`` is set (bit 0 = LSB of byte 0);
    an empty ``wanted`` asks for every chunk. The board keeps its last two images; it answers
    with the CAMERA_CHUNKs (no ACK), or NACK BAD_VALUE when it no longer has ``request_id``.
    """

    request_id: int = wire(U32)
    first: int = wire(U16)
    wanted: bytes = wire(RestBytes(MAX_RESEND_BITMAP), default=b"", repr=False)


Message = (
    Hello
    | Caps
    | TimeSyncRequest
    | TimeSyncReply
    | Config
    | Heartbeat
    | Advance
    | ServoFrame
    | Flush
    | Estop
    | EstopClear
    | Telemetry
    | SimState
    | Ack
    | Nack
    | ScreenCommand
    | SpeakerCommand
    | CameraCapture
    | CameraChunk
    | CameraResend
)


# --- derived from the declarations above ----------------------------------------------------------

if set(DECLARED) != set(MsgType) or set(typing.get_args(Message)) != {d.cls for d in DECLARED.values()}:
    raise ImportError("protocol.messages: every MsgType needs exactly one @message class, listed in Message")

#: the message types a host sends and a board receives (sender HOST or EITHER); the others
#: (:data:`BOARD_TO_HOST`) only a board sends. The board refuses a board-sent type it receives
#: (``firmware_sim.board.HOST_BOUND``) and a replay tells which end wrote a serial frame log by it
#: (``host.run.replay.host_to_board_dir``).
HOST_TO_BOARD: frozenset[MsgType] = frozenset(
    MsgType(t) for t, d in DECLARED.items() if d.sender is not Sender.BOARD)

#: the message types only a board sends (every type not in :data:`HOST_TO_BOARD`)
BOARD_TO_HOST: frozenset[MsgType] = frozenset(MsgType) - HOST_TO_BOARD
