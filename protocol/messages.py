"""The GhostShell wire protocol, version 1: the message set as plain dataclasses.

This module is the contract shared by the host and the board. It has no I/O and
no encoding: :mod:`protocol.codec` packs these into payloads and
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

from dataclasses import dataclass, field
from enum import IntEnum, IntFlag

PROTOCOL_VERSION = 1
#: Servos the default wire schema carries (its servo mask is a u16): every robot with up to 16 servos.
MAX_SERVOS = 16
#: The most servos the wire carries (robots with 17..32 servos use the u32-mask schema,
#: :func:`protocol.codec.schema_for`). Why 32: the servo mask is at most one u32, one register on an MCU,
#: and a 32-servo TELEMETRY (227 payload bytes) still fits a serial frame's 255-byte payload.
MAX_WIRE_SERVOS = 32


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


#: the message types a host sends and a board receives; the others (:data:`BOARD_TO_HOST`) only a board
#: sends. Each message's sender is declared here once, as a DBC names a message's transmitter: the
#: board refuses a board-sent type it receives (``firmware_sim.board.HOST_BOUND``) and a replay tells
#: which end wrote a serial frame log by it (``host.run.replay.host_to_board_dir``).
HOST_TO_BOARD: frozenset[MsgType] = frozenset({
    MsgType.HELLO, MsgType.TIME_SYNC_REQUEST, MsgType.CONFIG, MsgType.HEARTBEAT, MsgType.ADVANCE,
    MsgType.SERVO_FRAME, MsgType.FLUSH, MsgType.ESTOP, MsgType.ESTOP_CLEAR, MsgType.SCREEN, MsgType.SPEAKER,
    MsgType.CAMERA_CAPTURE, MsgType.CAMERA_RESEND,
})

#: the message types only a board sends (every type not in :data:`HOST_TO_BOARD`)
BOARD_TO_HOST: frozenset[MsgType] = frozenset(MsgType) - HOST_TO_BOARD


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


# --- handshake and clock -------------------------------------------------------------------


@dataclass(frozen=True)
class Hello:
    """Host -> board: first message of a session."""

    protocol_version: int
    schema_hash: int  # u32, see protocol.codec.SCHEMA_HASH
    host_time_us: int


@dataclass(frozen=True)
class Caps:
    """Board -> host: answer to HELLO; the host refuses a board whose robot, servo count or servo
    table hash differs from the robot it was started for."""

    protocol_version: int
    schema_hash: int
    servo_count: int
    control_rate_hz: int
    buffer_depth: int  # servo frames the jitter buffer holds
    telemetry_rate_hz: int
    board_time_us: int
    lockstep: bool
    robot: str = ""  # the robot the board drives (its robot.toml name), UTF-8, at most 32 bytes
    servo_table_hash: int = 0  # u32 over its servo table (robots.description.ServoTable.hash)


@dataclass(frozen=True)
class TimeSyncRequest:
    """Host -> board: NTP-style probe; t1 is the host clock at send."""

    t1_host_us: int


@dataclass(frozen=True)
class TimeSyncReply:
    """Board -> host: t2 board clock at receive, t3 board clock at send."""

    t1_host_us: int
    t2_board_us: int
    t3_board_us: int


@dataclass(frozen=True)
class Config:
    key: ConfigKey
    value: int


@dataclass(frozen=True)
class Heartbeat:
    """Either direction; keeps the watchdog fed when nothing else is sent."""

    sender_time_us: int


@dataclass(frozen=True)
class Advance:
    """Host -> board, lockstep only: let the board clock run up to ``until_us``."""

    until_us: int


# --- motion --------------------------------------------------------------------------------


@dataclass(frozen=True)
class ServoFrame:
    """Targets to reach at ``apply_at_us`` on the board clock (board interpolates between frames)."""

    apply_at_us: int
    mask: int
    targets: tuple[float, ...]


@dataclass(frozen=True)
class Flush:
    """Drop buffered frames due at or after ``from_us`` for the masked servos."""

    from_us: int
    mask: int


@dataclass(frozen=True)
class Estop:
    pass


@dataclass(frozen=True)
class EstopClear:
    pass


# --- board -> host -------------------------------------------------------------------------


@dataclass(frozen=True)
class Telemetry:
    board_time_us: int
    positions: tuple[float, ...]  # all servos, index order
    velocities: tuple[float, ...]
    efforts: tuple[float, ...]
    imu_rpy: tuple[float, float, float]  # body roll, pitch, yaw in radians
    faults: FaultFlags
    buffer_fill: int
    last_applied_seq: int  # host sequence number of the last servo frame applied
    late_count: int  # frames rejected as late, since boot
    dropped_count: int  # frames rejected otherwise (future, full, estop), since boot
    link_errors: int  # undecodable frames received, since boot


@dataclass(frozen=True)
class SimState:
    """Emulator only: ground truth of the floating base (no real board can send this)."""

    board_time_us: int
    base_pos: tuple[float, float, float]  # metres, world frame
    base_quat: tuple[float, float, float, float]  # w, x, y, z
    objects: int = 0  # movable scene objects (e.g. --scene bottles: 3)
    toppled: int = 0  # how many of them lean more than 45 deg from vertical


@dataclass(frozen=True)
class Ack:
    ack_seq: int  # sequence number of the acknowledged host message
    msg_type: MsgType


@dataclass(frozen=True)
class Nack:
    ack_seq: int
    msg_type: MsgType
    reason: NackReason
    detail: str = ""  # short ASCII explanation, at most 64 bytes on the wire


def nack_detail(nack: Nack) -> str:
    """The NACK's detail text, else what its reason means (:data:`NACK_REASON_TEXT`; an unknown reason
    code: ``"reason N"``): never empty, whichever link carried it."""
    if nack.detail:
        return nack.detail
    try:
        return NACK_REASON_TEXT[NackReason(nack.reason)]
    except (ValueError, KeyError):
        return f"reason {int(nack.reason)}"


# --- peripherals ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ScreenCommand:
    """Show an expression or animation from ``start_at_us`` for ``duration_ms`` (0 = until replaced)."""

    target: ScreenTarget
    name: str  # UTF-8, at most 32 bytes (codec.MAX_NAME_BYTES)
    start_at_us: int
    duration_ms: int


@dataclass(frozen=True)
class SpeakerCommand:
    """Play or stop speech or a clip on the board clock."""

    action: SpeakerAction
    kind: SoundKind
    start_at_us: int
    duration_ms: int
    volume: int  # 0..100
    name: str = ""  # clip name, UTF-8, at most 32 bytes (codec.MAX_NAME_BYTES)
    text: str = ""  # speech text, UTF-8, at most 200 bytes


@dataclass(frozen=True)
class CameraCapture:
    """Ask the head camera for one image."""

    request_id: int
    width: int
    height: int


@dataclass(frozen=True)
class CameraChunk:
    """One piece of an encoded image (PNG); ``index`` counts from 0 to ``total - 1``."""

    request_id: int
    index: int
    total: int
    data: bytes = field(repr=False)


@dataclass(frozen=True)
class CameraResend:
    """Host -> board: send chunks of a kept image again (selective repeat over a lossy link).

    Chunk ``first + k`` is wanted when bit ``k`` of ``wanted`` is set (bit 0 = LSB of byte 0);
    an empty ``wanted`` asks for every chunk. The board keeps its last two images; it answers
    with the CAMERA_CHUNKs (no ACK), or NACK BAD_VALUE when it no longer has ``request_id``.
    """

    request_id: int
    first: int
    wanted: bytes = field(default=b"", repr=False)


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
