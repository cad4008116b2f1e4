"""The board core: message handling and the control tick, with no I/O.

``Board.handle(msg, seq)`` consumes one decoded host message and returns the
replies; ``Board.tick()`` runs one control period (frames due -> interpolation ->
servo model -> MuJoCo ctrl -> physics) and returns what the board sends
unprompted (TELEMETRY + SIM_STATE at the telemetry rate). In lockstep the caller
ticks only while :meth:`Board.can_tick` is true; in realtime a pacer calls
:meth:`Board.tick` at the control rate. Board time is ``now_us``: the time of the
next tick to run (tick ``k`` runs at ``k * tick_us``).

Reply policy: HELLO -> CAPS (or NACK VERSION_MISMATCH / SCHEMA_MISMATCH);
TIME_SYNC_REQUEST -> TIME_SYNC_REPLY; SERVO_FRAME -> nothing when accepted (telemetry's
``last_applied_seq`` confirms it), NACK with the reason when refused; HEARTBEAT ->
nothing; CONFIG, ADVANCE, FLUSH, ESTOP, ESTOP_CLEAR, SCREEN, SPEAKER -> ACK (or NACK; a CONFIG
with an unknown key too: NACK BAD_VALUE);
CAMERA_CAPTURE -> CAMERA_CHUNKs (or NACK NO_RENDERER / BAD_VALUE; the same request id again -> the
same image's chunks again); CAMERA_RESEND -> the wanted chunks of one of the last ``KEPT_IMAGES``
images (NACK BAD_VALUE when it is no longer kept); anything else -> NACK UNSUPPORTED.

A real servo bus (:meth:`Board.attach_bus`, ``python -m firmware_sim --servo-bus PORT``): the servo
model's command goes to the servos as goals (:class:`firmware_sim.servobus.driver.BusDriver` clamps
them again to the calibrated step limits) instead of into ``mj_step``, and what the servos measure
(positions, speeds, loads) is written into the model (``qpos``/``qvel``, ``mj_forward``, no physics):
MuJoCo mirrors the real robot, so TELEMETRY, SIM_STATE and camera captures show what it did. A servo
that fails latches SERVO_FAULT: every servo holds, an unsolicited NACK SERVO_FAULT (msg_type
SERVO_FRAME, the last received sequence number) names it, frames are refused until ESTOP_CLEAR.
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, ClassVar, cast

import mujoco
import numpy as np
from cobs import cobs

from firmware_sim.config import BoardConfig
from firmware_sim.jitter_buffer import JitterBuffer
from firmware_sim.native import GS_CAP, GS_INTERP, NativeTick, NativeUnavailable, kernel_choice, note_fallback
from firmware_sim.board_bus import SERVO_FAULT_DETAIL, BusBridge
from firmware_sim.board_camera import KEPT_IMAGES, BoardCamera, nack
from firmware_sim.board_reports import BoardReports, DeferredReports, quat_to_rpy
from firmware_sim.board_stream import TargetStream, copy_next
from firmware_sim.peripherals import Camera, CameraWorker, Screen, Speaker
from firmware_sim.safety import Mode, Safety
from firmware_sim.servo_model import ServoModel
from protocol.codec import MESSAGE_CLASSES, quantize_apply_at, schema_for, unwrap_time_us
from protocol.faults import GapDetector
from protocol.framing import CRC_SIZE, HEADER_SIZE, DecodeError, DecodeErrorKind, Frame, crc16
from protocol.messages import (
    BOARD_TO_HOST,
    PROTOCOL_VERSION,
    Ack,
    Advance,
    CameraCapture,
    CameraResend,
    Caps,
    Config,
    ConfigKey,
    Estop,
    EstopClear,
    FaultFlags,
    Flush,
    Heartbeat,
    Hello,
    Message,
    MsgType,
    Nack,
    NackReason,
    ScreenCommand,
    ServoFrame,
    SimState,
    SpeakerCommand,
    Telemetry,
    TimeSyncReply,
    TimeSyncRequest,
)
from robots.description import Robot
from robots.model import RobotModel
from robots.registry import load_robot

if TYPE_CHECKING:
    from firmware_sim.servobus.driver import BusDriver

__all__ = ["Board", "HOST_BOUND", "KEPT_IMAGES", "answerable", "quat_to_rpy"]


#: messages only the board sends (:data:`protocol.messages.BOARD_TO_HOST`): one arriving from the host is
#: refused (NACK UNSUPPORTED) before it counts as link traffic (it neither feeds the watchdog nor the
#: sequence-gap counter)
HOST_BOUND: tuple[type[Message], ...] = tuple(MESSAGE_CLASSES[t] for t in sorted(BOARD_TO_HOST))

#: a received-message handler: ``(board, msg, seq, rx_us) -> replies``
_Handler = Callable[["Board", Any, int, int], "list[Message]"]


#: :meth:`Board.run`: a quiet batch this long or longer runs on the native kernel's thread while the caller's
#: ``during`` runs (one tick, ~20 us of CoCo physics, does not pay for waking the thread and waiting for it)
OVERLAP_MIN_TICKS = 3

_CONFIG_KEYS = frozenset(int(k) for k in ConfigKey)
_CONFIG_BODY = HEADER_SIZE + 5 + CRC_SIZE  # a CONFIG frame: header, key u8 + value i32, CRC


def answerable(item: DecodeError) -> Frame | DecodeError:
    """A serial frame the codec refused that the board still answers, as a :class:`Frame`; else ``item``.

    The one such frame: a well-formed CONFIG (COBS, CRC, version, type and length all check, 5 payload
    bytes) whose key byte is no :class:`ConfigKey`. The codec refuses it (an unknown enum value), but the
    host waits for its ACK: it becomes ``Config(key=<the int>, value)`` and :meth:`Board.handle` answers
    NACK BAD_VALUE as for a value out of range (the C firmware: ``gs_board_unknown_config``). Every other
    decode error stays a silent link error (line noise gets no reply). ``item.raw``: the COBS block and
    its delimiter (a CAN decode error's raw bytes never qualify: they are not such a frame).
    """
    raw = item.raw
    if item.kind is not DecodeErrorKind.PAYLOAD or len(raw) != _CONFIG_BODY + 2 or raw[-1] != 0:
        return item
    try:
        body = cobs.decode(raw[:-1])
    except cobs.DecodeError:
        return item
    if (len(body) != _CONFIG_BODY or body[0] != PROTOCOL_VERSION or body[1] != MsgType.CONFIG
            or body[4] != 5 or body[5] in _CONFIG_KEYS
            or struct.unpack_from("<H", body, _CONFIG_BODY - CRC_SIZE)[0] != crc16(body[:-CRC_SIZE])):
        return item
    (seq,) = struct.unpack_from("<H", body, 2)
    (value,) = struct.unpack_from("<i", body, HEADER_SIZE + 1)
    return Frame(seq, MsgType.CONFIG, Config(body[5], value), raw)  # type: ignore[arg-type]  # key: not a ConfigKey


class Board:
    """A robot's emulated controller board (its N servos, MuJoCo physics)."""

    def __init__(
        self,
        cfg: BoardConfig | None = None,
        clock_us: Callable[[], int] | None = None,
        *,
        reuse: Board | None = None,
        robot: Robot | None = None,
    ) -> None:
        """A board at time 0, servos at neutral, robot standing on the floor (or on its fixed base).

        ``robot``: the robot it drives (default: ``cfg.robot`` found on the robot search path,
        :func:`robots.registry.load_robot`).

        ``reuse``: a board that is no longer used, of the same scene; the new board takes over its
        compiled model and its ``MjData`` (reset here, so the new board starts exactly as a fresh
        one) instead of compiling and allocating again. For harnesses that make a fresh board per
        input (the ``board`` fuzz target): every ``MjData`` carries MuJoCo's arena (14 MB for a 12-servo robot),
        and one allocated and freed per input, between the fuzzer's own long-lived allocations,
        fragments the C heap so the process's RSS creeps up. ``ValueError`` if the scenes differ.
        """
        self.cfg = (cfg or BoardConfig()).validate()
        self.robot = robot if robot is not None else load_robot(self.cfg.robot, self.cfg.robots_dir)
        self.table = self.robot.servos
        self.poses = self.robot.poses
        #: the scene of the world (the robot's default unless the config names one)
        self.scene = self.cfg.scene or self.robot.default_scene
        if reuse is not None and reuse.robot is not self.robot:
            raise ValueError(f"cannot reuse a {reuse.robot.name} board's model for {self.robot.name}")
        if reuse is not None and reuse.scene != self.scene:
            raise ValueError(f"cannot reuse a {reuse.scene!r} board's model for scene {self.scene!r}")
        self.cm: RobotModel = reuse.cm if reuse is not None else self.robot.model(self.scene)
        self.scene_objects = self.cm.objects
        self._all_mask = self.table.all_mask
        self._all_idx = list(range(len(self.table)))  # the servos of a frame with every mask bit set
        self.model = self.cm.model
        self.model.opt.timestep = self.cfg.dt
        if self.model.ntree <= 1:
            # one kinematic tree (the robot alone): every constraint is in the one island, so MuJoCo's
            # island discovery (~5 % of CoCo's mj_step) changes nothing but the cost; with scene objects
            # (several trees) it changes how the solver splits the problem, so it stays on
            self.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
        self.data: mujoco.MjData = reuse.data if reuse is not None else self.cm.new_data()
        self.n = len(self.table)
        #: the wire schema of this robot (u16 servo mask up to 16 servos, u32 above): HELLO must name it
        self.wire_schema = schema_for(self.n)
        neutral = np.array(self.table.neutral)
        self.cm.place_on_floor(self.data, neutral)
        self.servo = ServoModel(
            self.table.mins,
            self.table.maxs,
            self.table.max_speeds,
            self.table.model.resolution,
            self.table.model.deadband,
            self.cfg.tick_us / 1e6,
        )
        self.servo.reset(neutral)
        self.crouch = np.array(self.robot.pose(self.robot.safe_pose))  # the latched-watchdog pose
        #: its name (robot.toml ``safe_pose``: CoCo's crouch, the arm's rest), as the board's lines word the
        #: latched watchdog (Mode.CROUCH on the wire and in code)
        self.safe_pose_name = str(self.robot.safe_pose)
        self.buffer = JitterBuffer(self.cfg.buffer_depth, self.n)
        #: per servo the interpolation anchor and the next keyframe, the resume blend
        self.stream = TargetStream(self.n, self.buffer, self.cfg, neutral)
        #: the stream's anchors (board time us, rad), the arrays the native tick holds (updated in place)
        self.anchor_t: np.ndarray = self.stream.anchor_t
        self.anchor_v: np.ndarray = self.stream.anchor_v
        self.safety = Safety(self.cfg.watchdog_ms * 1000, self.cfg.crouch_after_ms * 1000)
        self.screen = Screen()
        self.speaker = Speaker()
        #: CAMERA_CAPTURE / CAMERA_RESEND and the images kept for them
        self.cameras = BoardCamera(self.model, self.robot.peripherals.camera)
        #: sequence gaps in what the host sent (lost messages), since the last HELLO
        self.rx_gaps = GapDetector()
        self._clock_us = clock_us
        self.hold_q = neutral.copy()
        self._desired: np.ndarray = neutral.astype(np.float64)
        self._ctrl: np.ndarray = self.data.ctrl[self.cm.act_id].astype(np.float64)
        #: TELEMETRY and SIM_STATE of the model; its slices of the servos' joints, actuators and dofs
        self.reports = BoardReports(self.cm, self.data)
        #: lockstep server with overlap: a report period's reports come as one DeferredReports (built later,
        #: while the next ticks run) instead of TELEMETRY and SIM_STATE (:meth:`_reports_due`)
        self.defer_reports = False
        self._qpos_at, self._ctrl_at, self._dof_at = self.reports.qpos_at, self.reports.ctrl_at, self.reports.dof_at
        self._tick_us = self.cfg.tick_us  # rate and dt are fixed for a board's life (CONFIG cannot change them)
        self._substeps = self.cfg.substeps
        self._telemetry_every = self.cfg.telemetry_every  # CONFIG TELEMETRY_RATE_HZ updates it
        #: the per-tick servo path in C (:mod:`firmware_sim.native`), or None: the Python reference path
        self.native: NativeTick | None = self._bind_native()
        self.now_us = 0
        self.ticks = 0
        self.advance_until = 0  # lockstep: ADVANCE lets ticks run while now_us < this
        self.covered_until = -1  # lockstep: latest accepted frame apply-at (tick at it may run)
        self.last_applied_seq = 0
        #: safety transitions not yet reported: (board time us of the first tick in the new mode,
        #: "hold"|the safe pose's name (the latched watchdog: "crouch", "rest")|"estop"|"resume", board time us of the last valid message / of the ESTOP's
        #: arrival / of the first held tick ("resume": a valid message ended a HOLD, the board runs again))
        self.watchdog_events: deque[tuple[int, str, int]] = deque(maxlen=16)
        self._estop_rx_us: int | None = None
        self.late_count = 0
        self.dropped_count = 0
        self.link_errors = 0
        self.clamped_ticks = 0
        self._flags_since = FaultFlags.NONE
        #: scripted pushes on the base (emulator only): (start us, end us, force N world frame), by start
        self._pushes: list[tuple[int, int, tuple[float, float, float]]] = []
        #: a real servo bus this board drives (:meth:`attach_bus`), else None: MuJoCo simulates the servos
        self.bus: BusDriver | None = None
        #: the board's side of that bus (exchange, mirror, NACK SERVO_FAULTs), else None
        self._bridge: BusBridge | None = None
        self._last_rx_seq = 0  # the sequence number of the last message handled (what those NACKs carry)

    def attach_bus(self, bus: BusDriver, positions: list[float]) -> None:
        """Drive a real servo bus from now on (before the first tick): the Python tick runs (the native
        one steps physics), the model mirrors ``positions`` (rad, servo order: the servos' measured
        positions at start-up) and the command, the interpolation anchors and the hold pose all start
        there, so the first goal is where each servo is and the speed limit ramps from it. The board
        exchanges with the bus on every ``bus.every``-th tick (:meth:`BusDriver.plan`: the bus period),
        from the first tick on; the ticks between run the servo model, interpolation and watchdog and
        leave the mirror where the last read put it."""
        if self.ticks:
            raise RuntimeError("attach_bus must come before the first tick")
        self.bus = bus
        self._bridge = BusBridge(bus, self.model, self.reports)
        self.native = None
        self.servo.native_counts = None
        q = np.asarray(positions, dtype=np.float64)
        self.servo.reset(q)
        cmd = self.servo.cmd
        self.anchor_v[:] = cmd
        self._desired[:] = cmd
        self.hold_q = cmd.copy()
        self._bridge.mirror(bus.measured())

    def _bind_native(self) -> NativeTick | None:
        """The C tick on this board's arrays, per ``cfg.kernel`` / ``$GHOSTSHELL_BOARD_KERNEL`` (see
        :mod:`firmware_sim.native`); None runs the Python reference path."""
        choice = kernel_choice(self.cfg.kernel)
        if choice == "python":
            return None
        s = self.servo
        arrays = {
            "qpos_adr": np.ascontiguousarray(self.cm.qpos_adr, dtype=np.int64),
            "act_id": np.ascontiguousarray(self.cm.act_id, dtype=np.int64),
            "anchor_t": self.anchor_t, "anchor_v": self.anchor_v,
            "next_ok": self.stream.next_ok, "next_t": self.stream.next_t, "next_v": self.stream.next_v,
            "desired": self._desired, "ctrl": self._ctrl, "cmd": s._cmd,
            "mins": np.ascontiguousarray(s.mins, dtype=np.float64), "maxs": np.ascontiguousarray(s.maxs, dtype=np.float64),
            "max_step": np.ascontiguousarray(s.max_step, dtype=np.float64),
            "max_speed": np.ascontiguousarray(s.max_speeds, dtype=np.float64),
        }
        try:
            native = NativeTick(self.model, self.data, self._substeps, s.period_s, s.resolution, s.deadband, arrays)
        except Exception as e:  # noqa: BLE001 - no build, no load, no bind: the Python path runs instead
            if choice == "native!":
                raise e if isinstance(e, NativeUnavailable) else NativeUnavailable(f"{type(e).__name__}: {e}") from e
            note_fallback(str(e))
            return None
        s.native_counts = native
        self._snap_len, regions = self.reports.snapshot_regions()
        native.set_snapshot(regions)
        return native

    def push(self, at_s: float, force: tuple[float, float, float], duration_s: float = 0.2) -> None:
        """Emulator only: push the robot's root body with ``force`` (N, world frame) from board time ``at_s``
        for ``duration_s`` (a disturbance for tests of falls; a real board cannot do this)."""
        start = int(at_s * 1e6)
        self._pushes.append((start, start + int(duration_s * 1e6), (float(force[0]), float(force[1]), float(force[2]))))
        self._pushes.sort()

    def _apply_pushes(self, t: int) -> None:
        body = self.cm.root_body
        total = [0.0, 0.0, 0.0]
        for start, end, f in self._pushes:
            if start <= t < end:
                total = [a + b for a, b in zip(total, f)]
        self.data.xfrc_applied[body, :3] = total
        self._pushes = [p for p in self._pushes if p[1] > t]  # finished pushes are dropped

    # --- time ------------------------------------------------------------------------------

    @property
    def tick_us(self) -> int:
        return self.cfg.tick_us

    def board_time_us(self) -> int:
        """Fine-grained board clock (realtime) or virtual time (lockstep)."""
        return self._clock_us() if self._clock_us is not None and not self.cfg.lockstep else self.now_us

    def can_tick(self) -> bool:
        """Lockstep: may the next tick run (covered by a frame or an ADVANCE)? Realtime: always."""
        if not self.cfg.lockstep:
            return True
        return self.now_us < self.advance_until or self.now_us <= self.covered_until

    def skip(self, n_ticks: int) -> None:
        """Realtime resync after falling far behind: the clock jumps, physics does not run."""
        self.now_us += n_ticks * self.tick_us
        self.ticks += n_ticks

    def note_overrun(self) -> None:
        self._flags_since |= FaultFlags.TICK_OVERRUN

    def on_link_error(self) -> None:
        """A received frame failed to decode (counted; never fed to the watchdog)."""
        self.link_errors += 1
        self._flags_since |= FaultFlags.LINK_ERRORS

    # --- messages --------------------------------------------------------------------------

    def handle(self, msg: Message, seq: int = 0, rx_time_us: int | None = None) -> list[Message]:
        """Consume one decoded host message (``seq`` = its frame sequence); return the replies.

        Dispatch is the table :attr:`_HANDLERS` (message class -> ``handler(self, msg, seq, rx_us)``).
        A message the board sends itself (:data:`HOST_BOUND`) or an object that is no message is
        refused before it counts as link traffic; any other message feeds the sequence-gap counter and
        the watchdog first, and one without a handler is refused after that (NACK UNSUPPORTED).
        """
        rx = self.board_time_us() if rx_time_us is None else rx_time_us
        handler = self._handler_for(type(msg))
        if handler is None and (isinstance(msg, HOST_BOUND) or not hasattr(msg, "__dataclass_fields__")):
            return [self._unsupported(msg, seq)]
        self._count(msg, seq)
        self._last_rx_seq = seq
        held_since = self.safety.hold_since_us
        if self.safety.feed(self.now_us):
            self._resume()
            self.watchdog_events.append((self.now_us, "resume", held_since if held_since is not None else self.now_us))
        if handler is None:
            return [self._unsupported(msg, seq)]
        return handler(self, msg, seq, rx)

    def _count(self, msg: Message, seq: int) -> None:
        if isinstance(msg, Hello) and seq == 0:
            # a new host numbers its messages from 0; a re-sent HELLO (seq > 0) continues its sender's
            # numbering, and a HELLO lost before it is a gap like any other (gs_board.c does the same)
            self.rx_gaps.new_sender()
        self.rx_gaps.feed(seq)

    def count_unhandled(self, msg: Message, seq: int) -> None:
        """Feed the sequence-gap counter with a message that was received (and logged) but will never be
        handled: a lockstep board stopped with messages still queued. So ``seq_gaps`` agrees with the
        board's frame log, as :meth:`handle` would have counted it (a message the board sends itself, or
        an object that is no message, is not link traffic and is not counted)."""
        if isinstance(msg, HOST_BOUND) or not hasattr(msg, "__dataclass_fields__"):
            return
        self._count(msg, seq)

    @classmethod
    def _handler_for(cls, msg_cls: type) -> _Handler | None:
        """The handler of ``msg_cls`` (or of its nearest base class in the table: a subclass dispatches
        as its base does), None when the board has none."""
        handler = cls._HANDLERS.get(msg_cls)
        if handler is None:
            for base in msg_cls.__mro__[1:]:
                handler = cls._HANDLERS.get(base)
                if handler is not None:
                    break
        return handler

    def _unsupported(self, msg: object, seq: int) -> Nack:
        return self._nack(msg, seq, NackReason.UNSUPPORTED, f"board does not accept {type(msg).__name__}")

    def _on_servo_frame(self, msg: ServoFrame, seq: int, rx: int) -> list[Message]:
        return self._servo_frame(msg, seq)

    def _on_heartbeat(self, msg: Heartbeat, seq: int, rx: int) -> list[Message]:
        return []

    def _on_time_sync(self, msg: TimeSyncRequest, seq: int, rx: int) -> list[Message]:
        return [TimeSyncReply(msg.t1_host_us, rx, self.board_time_us())]

    def _on_hello(self, msg: Hello, seq: int, rx: int) -> list[Message]:
        return [self._hello(msg, seq)]

    def _on_advance(self, msg: Advance, seq: int, rx: int) -> list[Message]:
        if not self.cfg.lockstep:
            return [self._nack(msg, seq, NackReason.NOT_LOCKSTEP, "ADVANCE needs a --lockstep board")]
        self.advance_until = max(self.advance_until, int(msg.until_us))
        return [Ack(seq, MsgType.ADVANCE)]

    def _on_flush(self, msg: Flush, seq: int, rx: int) -> list[Message]:
        for i in self.buffer.flush(int(msg.from_us), int(msg.mask)):
            self.stream.restart(i, self.now_us, self.servo.cmd_of(i))  # the new stream starts from the command
        self._recompute_cover()
        return [Ack(seq, MsgType.FLUSH)]

    def _on_estop(self, msg: Estop, seq: int, rx: int) -> list[Message]:
        if self._estop_rx_us is None and not self.safety.estopped:
            self._estop_rx_us = rx  # reported by the first tick that holds (watchdog_events)
        self.safety.estop()
        self.buffer.clear()
        self.hold_q = self.data.qpos[self.cm.qpos_adr].copy()
        self.servo.reset(self.hold_q)
        if self.bus is not None:
            self.bus.on_estop()  # limp: torque off now
        return [Ack(seq, MsgType.ESTOP)]

    def _on_estop_clear(self, msg: EstopClear, seq: int, rx: int) -> list[Message]:
        self.safety.clear(self.now_us)
        if self.bus is not None:  # torque back on, from where the servos are
            self.servo.reset(self.bus.on_clear())
            self.hold_q = self.servo.cmd
        self._resume()
        return [Ack(seq, MsgType.ESTOP_CLEAR)]

    def _on_config(self, msg: Config, seq: int, rx: int) -> list[Message]:
        return [self._config(msg, seq)]

    def _on_screen(self, msg: ScreenCommand, seq: int, rx: int) -> list[Message]:
        self.screen.command(msg)
        return [Ack(seq, MsgType.SCREEN)]

    def _on_speaker(self, msg: SpeakerCommand, seq: int, rx: int) -> list[Message]:
        self.speaker.command(msg)
        return [Ack(seq, MsgType.SPEAKER)]

    def _on_capture(self, msg: CameraCapture, seq: int, rx: int) -> list[Message]:
        return self.cameras.capture(msg, seq, self.data)

    def _on_resend(self, msg: CameraResend, seq: int, rx: int) -> list[Message]:
        return self.cameras.resend(msg, seq)

    #: the received-message table: message class -> ``handler(self, msg, seq, rx_us) -> replies``. Built
    #: once with the class, of plain functions: bound methods held by the instance would make every board a
    #: reference cycle, freed only by the cyclic GC (harnesses make a board per input, see ``reuse``).
    _HANDLERS: ClassVar[dict[type, _Handler]] = {
        ServoFrame: _on_servo_frame,
        Heartbeat: _on_heartbeat,
        TimeSyncRequest: _on_time_sync,
        Hello: _on_hello,
        Advance: _on_advance,
        Flush: _on_flush,
        Estop: _on_estop,
        EstopClear: _on_estop_clear,
        Config: _on_config,
        ScreenCommand: _on_screen,
        SpeakerCommand: _on_speaker,
        CameraCapture: _on_capture,
        CameraResend: _on_resend,
    }

    _nack = staticmethod(nack)

    def _hello(self, msg: Hello, seq: int) -> Message:
        if msg.protocol_version != PROTOCOL_VERSION:
            return self._nack(
                msg, seq, NackReason.VERSION_MISMATCH,
                f"host protocol v{msg.protocol_version}, board speaks v{PROTOCOL_VERSION}",
            )
        schema = self.wire_schema
        if msg.schema_hash != schema.hash:
            return self._nack(
                msg, seq, NackReason.SCHEMA_MISMATCH,
                f"host schema {msg.schema_hash:#010x} != board {schema.hash:#010x}",
            )
        return Caps(
            protocol_version=PROTOCOL_VERSION,
            schema_hash=schema.hash,
            servo_count=self.n,
            control_rate_hz=self.cfg.rate_hz,
            buffer_depth=self.cfg.buffer_depth,
            telemetry_rate_hz=self.cfg.telemetry_rate_hz,
            board_time_us=self.board_time_us(),
            lockstep=self.cfg.lockstep,
            robot=self.robot.name,
            servo_table_hash=self.table.hash,
        )

    def _servo_frame(self, msg: ServoFrame, seq: int) -> list[Message]:
        mask = int(msg.mask)
        idx = self._all_idx if mask == self._all_mask else [i for i in range(self.n) if mask >> i & 1]
        if not mask or mask & ~self._all_mask:
            self.dropped_count += 1
            return [self._nack(msg, seq, NackReason.BAD_VALUE, f"mask {mask:#06x} must cover servos 1..{self.n} only")]
        if len(msg.targets) != len(idx) or not all(map(math.isfinite, msg.targets)):
            self.dropped_count += 1
            return [self._nack(msg, seq, NackReason.BAD_VALUE, "targets must be finite, one per mask bit")]
        if self.safety.estopped:
            self.dropped_count += 1
            return [self._nack(msg, seq, NackReason.ESTOPPED, "estop active; send ESTOP_CLEAR")]
        if self.safety.fault_latched:
            self.dropped_count += 1
            return [self._nack(msg, seq, NackReason.FAULT_LATCHED, "watchdog fault latched; send ESTOP_CLEAR")]
        if self.safety.servo_fault:
            self.dropped_count += 1
            return [self._nack(msg, seq, NackReason.SERVO_FAULT, self._bridge.fault_detail if self._bridge else SERVO_FAULT_DETAIL)]
        now = self.now_us
        t = unwrap_time_us(quantize_apply_at(int(msg.apply_at_us)), now)
        if t < now - self.cfg.max_late_us:
            self.late_count += 1
            return [self._nack(msg, seq, NackReason.LATE, f"due {t} us, board at {now} us ({now - t} us late)")]
        if t > now + self.cfg.max_future_us:
            self.dropped_count += 1
            return [self._nack(msg, seq, NackReason.TOO_FAR_FUTURE, f"due {t} us, board at {now} us (> {self.cfg.max_future_us} us ahead)")]
        values = dict(zip(idx, map(float, msg.targets)))
        nxt = self.buffer.next_all()
        resume: list[int] = []
        if None in nxt:  # a servo with nothing buffered that was idle longer than the resume gap
            anchors, gap = self.anchor_t.tolist(), self.cfg.resume_gap_us
            resume = [i for i in idx if nxt[i] is None and now - anchors[i] > gap]
        if not self.buffer.push(t, seq, values):
            self.dropped_count += 1
            return [self._nack(msg, seq, NackReason.BUFFER_FULL, f"jitter buffer full ({self.cfg.buffer_depth} frames)")]
        for i in resume:  # an idle servo starts the new stream from where it is now
            self.anchor_t[i], self.anchor_v[i] = now, self.servo.cmd_of(i)
        self.covered_until = max(self.covered_until, t)
        return []

    def _config(self, msg: Config, seq: int) -> Message:
        v = int(msg.value)
        key = msg.key
        if key is ConfigKey.TELEMETRY_RATE_HZ and 1 <= v <= self.cfg.rate_hz:
            self.cfg.telemetry_rate_hz = v
            self._telemetry_every = self.cfg.telemetry_every
        elif key is ConfigKey.WATCHDOG_MS and v > 0:
            self.cfg.watchdog_ms = v
            self.safety.watchdog_us = v * 1000
        elif key is ConfigKey.CROUCH_AFTER_MS and v >= 0:
            self.cfg.crouch_after_ms = v
            self.safety.crouch_after_us = v * 1000
        elif key is ConfigKey.MAX_LATE_US and v >= 0:
            self.cfg.max_late_us = v
        elif key is ConfigKey.MAX_FUTURE_US and v > 0:
            self.cfg.max_future_us = v
        elif not isinstance(key, ConfigKey):  # a well-formed CONFIG with an unknown key (answerable())
            return self._nack(msg, seq, NackReason.BAD_VALUE, f"unknown CONFIG key {int(key)}")
        else:
            return self._nack(msg, seq, NackReason.BAD_VALUE, f"{key.name}={v} out of range")
        return Ack(seq, MsgType.CONFIG)

    @property
    def camera(self) -> Camera:
        """The camera renderer (the lockstep path's; :attr:`cameras` holds it)."""
        return self.cameras.camera

    @property
    def camera_worker(self) -> CameraWorker | None:
        """The realtime render thread once :meth:`start_camera_worker` ran, else None."""
        return self.cameras.worker

    def start_camera_worker(self) -> str | None:
        """Render captures in a background thread from now on; returns why not, if it can't."""
        return self.cameras.start_worker()

    def _resume(self) -> None:
        """Leaving a hold: buffered frames are gone, every servo continues from its command
        (:meth:`firmware_sim.board_stream.TargetStream.resume`: it blends into the host's stream)."""
        self.stream.resume(self.now_us, self.servo._cmd)
        self._recompute_cover()

    def _recompute_cover(self) -> None:
        latest = self.buffer.latest_apply_at
        self.covered_until = min(self.covered_until, latest if latest is not None else self.now_us - self.tick_us)

    # --- control tick ----------------------------------------------------------------------

    @property
    def desired(self) -> np.ndarray:
        """The interpolated targets of the last tick (rad, servo order), before the servo model."""
        return self._desired.copy()

    @property
    def ctrl(self) -> np.ndarray:
        """The actuator commands of the last tick (rad, servo order)."""
        return self._ctrl.copy()

    def tick(self) -> list[Message]:
        """Run one control period at board time ``now_us``; return telemetry when due.

        The hot path of lockstep runs: the per-servo work (interpolation, servo model, ctrl) and
        ``mj_step`` run in C (:mod:`firmware_sim.native`) or, as the reference, in plain Python on
        the servos' floats (:mod:`firmware_sim.servo_model`); reports are built only when due.
        """
        t = self.now_us
        mode, entered = self.safety.update(t)
        speed_cap: float | None = None
        native = self.native
        if self._estop_rx_us is not None and mode is Mode.ESTOP:
            # on the clock the ESTOP's arrival was stamped on (board_time_us: the fine-grained clock in
            # realtime, virtual time in lockstep), not the tick's scheduled time t: a realtime board
            # catching up on late ticks runs ticks whose t is before the arrival (it printed a negative
            # latency under load); the hold takes effect when this tick runs
            self.watchdog_events.append((self.board_time_us(), "estop", self._estop_rx_us))
            self._estop_rx_us = None
        if entered and mode in (Mode.HOLD, Mode.CROUCH):
            self.buffer.clear()
            self.hold_q = self.servo.cmd
            self.watchdog_events.append((t, self.safe_pose_name if mode is Mode.CROUCH else mode.value,
                                         self.safety.last_feed_us))
        desired: list[float] | np.ndarray | None = None  # None: the native tick interpolates
        if mode is Mode.RUN:
            self._apply_due(t)
            if self.stream.blending:
                desired = self.stream.blend(t)
            elif native is None:
                desired = self.stream.interpolate(t)
            else:
                self.stream.refresh_next()
        elif mode is Mode.CROUCH:
            desired, speed_cap = self.crouch, self.cfg.crouch_speed
        else:
            desired = self.hold_q
        if self._pushes:
            self._apply_pushes(t)
        if native is not None:
            flags = GS_INTERP if desired is None else 0
            if desired is not None:
                self._desired[:] = desired
            if speed_cap is not None:
                flags |= GS_CAP
            clamped = native.tick(t, flags, speed_cap or 0.0)
        else:
            assert desired is not None  # the Python path always interpolates above
            clamped = self._python_tick(desired if isinstance(desired, list) else desired.tolist(), speed_cap)
        if clamped and mode is Mode.RUN:
            self._flags_since |= FaultFlags.CLAMPED
            self.clamped_ticks += 1
        self.now_us = t + self._tick_us
        self.ticks += 1
        out = self.cameras.results() if self.cameras.worker is not None else []
        if self._bridge is not None and self._bridge.out:
            out += self._bridge.take_out()
        if self.ticks % self._telemetry_every == 0:
            out += self._reports_due()
        return out

    def run(self, max_ticks: int, during: Callable[[int], object] | None = None) -> tuple[int, list[Message]]:
        """Lockstep: run up to ``max_ticks`` ticks while :meth:`can_tick`; stop after the first tick
        that returns something or records a watchdog event. Returns (ticks run, that tick's messages).

        The same ticks and reports as calling :meth:`tick` that often, tick by tick: with the native
        kernel a run of *quiet* ticks (:meth:`_run_quiet`: the Python around each would only move the
        clock) goes to C in one call (:meth:`firmware_sim.native.NativeTick.run`); any other tick runs
        through :meth:`tick`. A realtime board's pacer calls :meth:`tick` instead.

        ``during(n)`` (the lockstep server's link work: encode and write what is queued, read what came)
        is called once per batch of ``n`` ticks, before the batch changes anything this board shows
        (board time, reports); for a quiet batch of :data:`OVERLAP_MIN_TICKS` or more while the C runs
        it on the kernel's own thread (:meth:`firmware_sim.native.NativeTick.run_during`; a shorter one
        would not pay for the hand-over). It must not touch the board. With :attr:`defer_reports` as well (the
        lockstep server's overlap) a batch ending in a report may go on with the quiet ticks after it in the
        same job (:meth:`_run_split`): the run then returns that report with the ticks after it counted; the
        report's ``now_us`` is the board time it was made at.
        """
        ran = 0
        while ran < max_ticks and self.can_tick():
            quiet = self._run_quiet(max_ticks - ran) if during is None else self._run_quiet(max_ticks - ran, during)
            if quiet is None:
                if during is not None:
                    during(1)
                n, out = 1, self.tick()
            else:
                n, out = quiet
            ran += n
            if out or self.watchdog_events:
                return ran, out
        return ran, []

    def _run_quiet(self, limit: int, during: Callable[[int], object] | None = None) -> tuple[int, list[Message]] | None:
        """Run the quiet ticks from ``now_us`` on (at most ``limit``, at least 1) in one native call and
        return (how many, the last one's reports); None (nothing run) when the next tick is not quiet.

        A tick is quiet when it runs in RUN mode and stays there (no ESTOP, hold or latched fault; the
        watchdog, once armed, fed within ``watchdog_us`` of it), with no resume blend, scripted push
        or camera worker, the native kernel, lockstep and :meth:`can_tick`, and no frame due at it,
        except at the first (applied here, as :meth:`tick` would, before the C runs); a report may be
        due only at the last. :meth:`tick` would do nothing else for it than
        ``native.tick(t, GS_INTERP)`` and move the clock. ``during``: see :meth:`run`."""
        if (self.native is None or not self.cfg.lockstep or self.stream.blending or self._pushes
                or self.camera_worker is not None or self._estop_rx_us is not None):
            return None
        sf = self.safety
        now, dt = self.now_us, self._tick_us
        if (sf.estopped or sf.fault_latched or sf.hold_since_us is not None
                or (sf.armed and now - sf.last_feed_us > sf.watchdog_us)):
            return None  # safety.update(now) would not say RUN without a change
        self._apply_due(now)  # what tick() does first in RUN mode (it may feed the watchdog)
        n = min(limit, self._telemetry_every - self.ticks % self._telemetry_every)
        n = min(n, (max(self.advance_until - 1, self.covered_until) - now) // dt + 1)  # can_tick
        if sf.armed:  # tick k (at now + k dt) stays fed while now + k dt - last_feed <= watchdog
            n = min(n, (sf.last_feed_us + sf.watchdog_us - now) // dt + 1)
        first = self.buffer.first_apply_at
        if first is not None:  # tick k >= 1 sees no frame due while now + k dt < first (> now here)
            n = min(n, -((now - first) // dt))
        n = max(1, n)  # tick 0 itself: can_tick held, the watchdog was fed, its frames are applied
        self.stream.refresh_next()
        if during is not None and self.defer_reports:
            split = self._run_split(now, n, limit, during)
            if split is not None:
                return split
        if during is None:
            clamped = self.native.run(now, n, dt, GS_INTERP)
        elif n < OVERLAP_MIN_TICKS:
            during(n)
            clamped = self.native.run(now, n, dt, GS_INTERP)
        else:
            failed: list[BaseException] = []

            def work() -> None:
                try:
                    during(n)
                except BaseException as e:  # raised below, once the ticks that ran meanwhile are counted
                    failed.append(e)

            clamped = self.native.run_during(now, n, dt, GS_INTERP, work)
            if failed:
                self._count_quiet(now, n, clamped)
                raise failed[0]
        return self._count_quiet(now, n, clamped)

    def _run_split(self, now: int, n1: int, limit: int, during: Callable[[int], object]) -> tuple[int, list[Message]] | None:
        """The quiet batch of ``n1`` ticks from ``now`` that :meth:`_run_quiet` planned, when it ends in a report,
        and the quiet ticks after it in one native call (:meth:`firmware_sim.native.NativeTick.run_split_during`),
        as :meth:`run` would run them in two: the report's snapshot is taken in C between them, and what
        :meth:`_apply_due` and ``refresh_next`` do at the second part's first tick is prepared here (into the
        kernel's ``pending`` arrays: the live ones are the first part's) and copied in by the C. Returns
        (``n1`` + the second part's ticks, [the report]) as :meth:`_count_quiet` and :meth:`_reports_due` would
        leave the board after both parts; None (nothing done) unless the second part is quiet at its start
        (:meth:`_run_quiet`'s conditions there, no ADVANCE or frame coverage missing) and the reports are
        deferred (the lockstep server's overlap). The second part stops before the next report, before the
        watchdog would starve, at the next frame due and where :meth:`can_tick` would stop: the ticks, the report and the
        state are those of two :meth:`run` calls (the lockstep server does nothing between them but its link
        work, which touches no board state)."""
        native, dt, every = self.native, self._tick_us, self._telemetry_every
        assert native is not None
        if n1 < OVERLAP_MIN_TICKS or every < 2 or limit - n1 < 1 or (self.ticks + n1) % every or self._bridge is not None:
            return None
        t2 = now + n1 * dt
        sf = self.safety
        if sf.armed and t2 - sf.last_feed_us > sf.watchdog_us:
            return None
        if not (t2 < self.advance_until or t2 <= self.covered_until):
            return None
        # the report's counters as _reports_due would take them after the first part (no CLAMPED yet: below)
        flags0, fill, seq = sf.flags, len(self.buffer), self.last_applied_seq
        # _apply_due(t2) and refresh_next into the kernel's pending arrays (the live ones are the first part's)
        p = native.pending
        pt, pv = p["anchor_t"], p["anchor_v"]
        pt[:] = self.anchor_t
        pv[:] = self.anchor_v
        self._apply_due(t2, pt, pv)
        nxt = self.buffer.next_all()
        nt, nv = p["next_t"], p["next_v"]
        nt[:] = self.stream.next_t  # refresh_next leaves a servo's without a next keyframe as they were
        nv[:] = self.stream.next_v
        copy_next(nxt, p["next_ok"], nt, nv)
        n2 = min(limit - n1, every - 1, (max(self.advance_until - 1, self.covered_until) - t2) // dt + 1)
        if sf.armed:
            n2 = min(n2, (sf.last_feed_us + sf.watchdog_us - t2) // dt + 1)
        first = self.buffer.first_apply_at
        if first is not None:
            n2 = min(n2, -((t2 - first) // dt))
        n2 = max(1, n2)
        buf = np.empty(self._snap_len)
        failed: list[BaseException] = []

        def work() -> None:
            try:
                during(n1 + n2)
            except BaseException as e:  # raised below, once the ticks that ran meanwhile are counted
                failed.append(e)

        c1, c2 = native.run_split_during(now, n1, n2, dt, GS_INTERP, buf, work)
        self.stream._next_src = nxt  # the C copied these next keyframes into the live arrays
        if c1:
            self._flags_since |= FaultFlags.CLAMPED
            self.clamped_ticks += c1
        self.now_us = t2
        self.ticks += n1
        since, self._flags_since = self._flags_since, FaultFlags.NONE
        counters = (flags0 | since if since else flags0, fill, seq & 0xFFFF, self.late_count, self.dropped_count,
                    self.link_errors)
        report = DeferredReports(self.reports, t2, counters, self.reports.snapshot_of(buf))
        if c2:
            self._flags_since |= FaultFlags.CLAMPED
            self.clamped_ticks += c2
        self.now_us = t2 + n2 * dt
        self.ticks += n2
        if failed:
            raise failed[0]
        return n1 + n2, cast("list[Message]", [report])

    def _count_quiet(self, now: int, n: int, clamped: int) -> tuple[int, list[Message]]:
        """After ``n`` quiet ticks from ``now`` ran in C: move the clock, count clamps, make the reports due."""
        if clamped:
            self._flags_since |= FaultFlags.CLAMPED
            self.clamped_ticks += clamped
        self.now_us = now + n * self._tick_us
        self.ticks += n
        if self.ticks % self._telemetry_every == 0:
            return n, self._reports_due()
        return n, []

    def _reports_due(self) -> list[Message]:
        """A report period's TELEMETRY and SIM_STATE; with :attr:`defer_reports` one
        :class:`firmware_sim.board_reports.DeferredReports` in their place (a snapshot now, the messages
        later: its ``messages()``)."""
        if not self.defer_reports:
            return [self.telemetry(), self.sim_state()]
        faults = self.safety.flags | self._flags_since if self._flags_since else self.safety.flags
        self._flags_since = FaultFlags.NONE
        counters = (faults, len(self.buffer), self.last_applied_seq & 0xFFFF, self.late_count, self.dropped_count,
                    self.link_errors)
        deferred = DeferredReports(self.reports, self.now_us, counters, self.reports.snapshot())
        return cast("list[Message]", [deferred])  # the one caller that sets defer_reports expects it

    def _apply_due(self, t: int, anchor_t: np.ndarray | None = None, anchor_v: np.ndarray | None = None) -> None:
        """A RUN tick at ``t`` starts here: the frames due by ``t`` leave the buffer and their targets
        become their servos' interpolation anchors (in lockstep an applied frame feeds the watchdog).
        ``anchor_t``/``anchor_v``: the arrays to write them to (default the live anchors; :meth:`_run_split`
        gives the native kernel's pending ones)."""
        due = self.buffer.pop_due(t)
        if due:
            at = self.anchor_t if anchor_t is None else anchor_t
            av = self.anchor_v if anchor_v is None else anchor_v
            for f in due:
                when = f.apply_at_us
                for i, v in f.values.items():
                    at[i] = when
                    av[i] = v
                self.last_applied_seq = f.seq
                if self.cfg.lockstep:
                    self.safety.feed(when)

    def _python_tick(self, desired: list[float], speed_cap: float | None) -> bool:
        """The reference path of one tick after interpolation: servo model, ctrl, then ``mj_step`` (or, on a
        real servo bus, :meth:`_bus_period`); True if clamped. On a bus ``ctrl`` (the deadband against
        the measured positions) is kept as in simulation, for reports only."""
        data = self.data
        ctrl, clamped = self.servo.step_list(desired, data.qpos[self._qpos_at].tolist(), speed_cap)
        self._desired[:] = desired
        self._ctrl[:] = ctrl
        data.ctrl[self._ctrl_at] = ctrl
        if self._bridge is not None:
            return self._bus_period(self._bridge, bool(clamped))
        substeps = self._substeps
        if substeps == 1:
            mujoco.mj_step(self.model, data)
        else:
            mujoco.mj_step(self.model, data, nstep=substeps)
        return bool(clamped)

    def _bus_period(self, bridge: BusBridge, clamped: bool) -> bool:
        """After the servo model on a real servo bus: on a bus tick (every ``bus.every``-th) its speed-limited
        command (rad) goes out as the goals and the measurement comes back into the model
        (:meth:`firmware_sim.board_bus.BusBridge.exchange`; quantised to steps there, the servo's own
        deadband acts in the servo); between bus periods the command moves on and the mirror holds. A
        new servo fault latches SERVO_FAULT: every servo holds its command, a NACK names the servo.
        Returns ``clamped`` or whether the step limits clamped a goal (CLAMPED in telemetry too)."""
        if self.ticks % bridge.bus.every:
            return clamped
        faults = bridge.exchange(self.servo._cmd.tolist(), self.now_us, self._last_rx_seq)
        if faults and not self.safety.servo_fault:
            self.safety.servo_faulted()
            self.buffer.clear()
            self.hold_q = self.servo.cmd
            bridge.fault_detail = f"{faults[0].detail}; send ESTOP_CLEAR"[:64]
        return clamped or bridge.bus.clamped

    # --- reports ---------------------------------------------------------------------------

    def telemetry(self) -> Telemetry:
        """TELEMETRY for the current state (clears the since-last-report flags)."""
        faults = self.safety.flags | self._flags_since if self._flags_since else self.safety.flags
        self._flags_since = FaultFlags.NONE
        return self.reports.telemetry(self.now_us, faults, len(self.buffer), self.last_applied_seq & 0xFFFF,
                                      self.late_count, self.dropped_count, self.link_errors)

    def sim_state(self) -> SimState:
        """Ground truth of the floating base (emulator only)."""
        return self.reports.sim_state(self.now_us)

    @property
    def mode(self) -> Mode:
        return self.safety.mode

    def positions(self) -> np.ndarray:
        """Measured joint angles (rad), servo order."""
        return self.data.qpos[self.cm.qpos_adr].copy()
