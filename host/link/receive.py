"""The session's receive path: decoded items in, each message to its handler through a table.

:class:`ReceivePath` is a part of :class:`host.link.client.BoardClient` (python-can's Notifier role):
the transport calls :meth:`ReceivePath.on_items` with what it decoded; undecodable items are
counted, never raised; every message goes to its handler by type (a table of bound methods made
once) and then to the ``on_received`` listeners. The handlers hand on:
TELEMETRY to :class:`host.link.telemetry.TelemetryFanout`, ACK/NACK and images to
:class:`host.link.requests.RequestTable`, CAPS and TIME_SYNC replies to
:class:`host.link.supervisor.Supervisor`, CAMERA_CHUNKs to :class:`host.link.camera.CameraAssembler`,
board times to :class:`host.link.board_time.BoardClock`. It holds the session only as
:class:`ReceiveLink`. A bug in a handler or listener is logged and the reader goes on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from host.link.board_time import BoardClock
from host.link.camera import CameraAssembler
from host.link.errors import HandshakeError, SchemaMismatch
from host.link.requests import RequestTable
from host.link.supervisor import Supervisor
from host.link.telemetry import TelemetryFanout
from host.link.timesync import host_now_us
from protocol.faults import GapDetector
from protocol.framing import DecodeError, Frame
from protocol.messages import (Ack, CameraChunk, Caps, Message, MsgType, Nack, NackReason, SimState, Telemetry,
                               TimeSyncReply)

__all__ = ["REORDER_DEPTH", "LinkStats", "ReceiveLink", "ReceivePath"]

log = logging.getLogger("host.link")


#: how many later board messages may overtake one before it counts as lost: over CAN a bulk ISO-TP transfer
#: (SIM_STATE, CAPS) waits behind the fixed TELEMETRY frames sent during it (up to 6 seen in 30 runs on a
#: loaded machine over SLCAN, where counting at once reported 1-2 gaps for a link that lost nothing)
REORDER_DEPTH = 32


@dataclass
class LinkStats:
    """Counters since the client was created."""

    tx_frames: int = 0
    #: SERVO_FRAMEs handed to the transport (each is one record in the host's frame log): a start's first
    #: frame and its re-sent ones included, unlike ``FrameStreamer.frames_sent`` (the grid's frames)
    servo_frames_sent: int = 0
    rx_frames: int = 0
    decode_errors: int = 0
    frame_nacks: int = 0
    telemetry: int = 0
    reconnects: int = 0
    retries: int = 0  # requests re-sent because no ACK/NACK came in time (a lost frame either way)
    #: board messages lost (gaps in the board's sequence numbers) since the handshake: a number counts once
    #: :data:`REORDER_DEPTH` later ones have arrived (before that it may still be on its way)
    seq_gaps: int = 0
    last_decode_error: str = ""  # kind and detail of the latest undecodable item, for reports


class ReceiveLink(Protocol):
    """What the receive path needs of the session: its name for messages, counters, the replies awaited
    by sequence number and the camera captures in progress."""

    @property
    def port_name(self) -> str: ...
    @property
    def stats(self) -> LinkStats: ...
    @property
    def requests(self) -> RequestTable: ...
    @property
    def camera(self) -> CameraAssembler: ...


class ReceivePath:
    """Received items -> handlers -> listeners (module docstring). ``latest_sim_state``, ``servo_fault``
    and ``servo_faults`` are what it kept of the board's messages."""

    def __init__(self, link: ReceiveLink, fanout: TelemetryFanout, clock: BoardClock, supervisor: Supervisor) -> None:
        self.link = link
        # the parts each message reaches, held directly: one attribute access per message
        self.stats, self.requests, self.camera = link.stats, link.requests, link.camera
        self.fanout, self.clock, self.supervisor = fanout, clock, supervisor
        self._rx_gaps = GapDetector()
        self.latest_sim_state: SimState | None = None
        #: the board's latest NACK SERVO_FAULT (its detail names the servo that stopped answering on its bus)
        self.servo_fault: Nack | None = None
        #: every NACK SERVO_FAULT so far, oldest first, the last 64 (the board reports each failed servo in
        #: its own: several silent at once; host.link.faultcheck.servo_fault_message reads them)
        self.servo_faults: list[Nack] = []
        #: called with every frame NACK nobody awaited (a servo frame's)
        self.on_nack: list[Callable[[Nack], None]] = []
        #: called with every message received, after it was handled (listeners, e.g. a run's recorder;
        #: python-can's Listener model)
        self.on_received: list[Callable[[Message], None]] = []
        #: received message class -> ``handler(msg, t4, nbytes)``: the message, the host time (µs) its read
        #: was taken, and the frame's wire bytes (a table, not an isinstance chain)
        self._handlers: dict[type[Message], Callable[[Any, int, int], None]] = {
            Telemetry: self._handle_telemetry,
            SimState: self._handle_sim_state,
            Ack: self._handle_ack,
            Nack: self._handle_nack,
            TimeSyncReply: self._handle_time_sync,
            Caps: self._handle_caps,
            CameraChunk: self._handle_chunk,
        }

    def on_items(self, items: Sequence[Frame | DecodeError]) -> None:
        t4 = host_now_us()
        for item in items:
            if isinstance(item, DecodeError):
                self.stats.decode_errors += 1
                self.stats.last_decode_error = f"{item.kind.value}: {item.detail} ({len(item.raw)} bytes)"
                log.debug("link: discarded %d bytes (%s: %s)", len(item.raw), item.kind.value, item.detail)
                continue
            self.stats.rx_frames += 1
            if type(item.msg) is Caps and self.supervisor.awaiting_caps():
                # the answer to the HELLO in flight: the board's numbering counts from here (a new board
                # numbers afresh); TELEMETRY frames that overtook this ISO-TP transfer still count
                self._rx_gaps.restart_from(item.seq)
            else:
                self._rx_gaps.feed(item.seq)
            self.stats.seq_gaps = self._rx_gaps.settled_lost(REORDER_DEPTH)
            try:
                self._dispatch(item.msg, t4, len(item.raw))
                for cb in self.on_received:
                    cb(item.msg)
            except Exception:  # a bug in a callback must not kill the reader
                log.exception("link: error handling %s", item.msg_type.name)

    def _dispatch(self, msg: Message, t4: int, nbytes: int) -> None:
        handler = self._handlers.get(type(msg))
        if handler is not None:
            handler(msg, t4, nbytes)

    def _handle_telemetry(self, msg: Telemetry, t4: int, nbytes: int) -> None:
        self.stats.telemetry += 1
        clock = self.clock
        if msg.board_time_us > clock.seen_us:
            clock.seen_us = msg.board_time_us
        self.fanout.on_telemetry(msg)

    def _handle_sim_state(self, msg: SimState, t4: int, nbytes: int) -> None:
        self.latest_sim_state = msg

    def _handle_ack(self, msg: Ack, t4: int, nbytes: int) -> None:
        self.requests.on_ack(msg)

    def _handle_time_sync(self, msg: TimeSyncReply, t4: int, nbytes: int) -> None:
        self.supervisor.on_sync_reply(msg, t4, nbytes)

    def _handle_caps(self, msg: Caps, t4: int, nbytes: int) -> None:
        self.supervisor.on_caps(msg)

    def _handle_chunk(self, msg: CameraChunk, t4: int, nbytes: int) -> None:
        done = self.camera.on_chunk(msg)
        if done is not None:
            self.requests.on_result(*done)

    def _handle_nack(self, msg: Nack, t4: int, nbytes: int) -> None:
        if msg.reason == NackReason.SERVO_FAULT:
            self.servo_fault = msg
            self.servo_faults.append(msg)
            del self.servo_faults[:-64]  # bounded: a faulted board refuses every frame with one
        if msg.msg_type == MsgType.HELLO:
            reason = msg.reason.name if hasattr(msg.reason, "name") else str(msg.reason)
            error = SchemaMismatch if msg.reason == NackReason.SCHEMA_MISMATCH else HandshakeError
            if self.supervisor.refuse_hello(error(
                f"the board on {self.link.port_name} refused the handshake: {reason}: {msg.detail or 'no detail'}; "
                "host and board must run the same protocol version and message schema"
            ), msg.ack_seq):
                return
        if self.requests.on_nack(msg):
            return  # it answered a request
        self.stats.frame_nacks += 1
        for cb in list(self.on_nack):
            cb(msg)
