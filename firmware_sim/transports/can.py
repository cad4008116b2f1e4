"""The board's CAN transports: a python-can bus (SocketCAN, virtual, ...) or an SLCAN adapter on a pty.

Both share :class:`CanBoardTransport`, a thin adapter around the CAN wire engine shared with the
host (:class:`protocol.can.engine.CanEngine`: fixed-layout frames and ISO-TP in the robot's layout
table, :func:`protocol.can.layouts.can_layouts` for its ``servo_count``; a message without a fixed
layout in the link's frame kind, classic TELEMETRY above 27 servos, goes as bulk; the board's node
id selects its identifiers; the broadcast ESTOP 0x000 is honoured too). The board's own policy stays
here: a CAN controller's transmit priority (lowest identifier first), periodic bulk reports (newest
wins, sent only while a host is heard), NACKs without their detail text when they must be short.
Every frame sent and received goes to the frame log chosen by suffix (:mod:`protocol.logfile`:
python-can's writers, ``.log`` candump, ``.asc``, ``.blf``; wall-clock timestamps).

* :class:`BusBoardTransport` opens ``can.Bus(**spec.bus_kwargs())`` (python-can's configuration
  fills in what the spec leaves out) with a filter on the node id. A refused send (SocketCAN
  returns ENOBUFS when the interface's tx queue is full, python-can issue #2004) keeps the frame
  at the head of the queue and retries after a backoff of 1 ms doubling to 20 ms (counted in
  ``tx_retries``): nothing is lost and frame order is kept.
* :class:`SlcanBoardTransport` creates a pty and behaves as a USB-CAN adapter speaking SLCAN
  (the device engine :class:`protocol.can.slcan.SlcanDevice`), so the host uses python-can's own
  ``slcan`` interface.
"""

from __future__ import annotations

import dataclasses
import errno
import heapq
import os
import sys
import time
import tty
from collections import deque
from collections.abc import Callable
from typing import Any

import can

from firmware_sim.transports.base import PERIODIC_REPORTS, BoardTransport
from protocol.can.engine import CanEngine
from protocol.can.frame import CanFrame
from protocol.can.ids import FunctionCode
from protocol.can.layouts import CanLayouts, can_layouts
from protocol.can.pycan import from_can_message, to_can_message
from protocol.can.slcan import SlcanDevice, format_frame
from protocol.codec import PayloadError
from protocol.faults import FaultInjector
from protocol.framing import DecodeError, DecodeErrorKind, Frame
from protocol.linkspec import LinkSpec
from protocol.logfile import FrameLogWriter, open_frame_log
from protocol.messages import Message, MsgType, Nack

__all__ = [
    "BusBoardTransport",
    "CanBoardTransport",
    "SlcanBoardTransport",
    "to_can_message",
]

FRAME_COST = 16  # backlog bytes per queued frame (a SocketCAN struct can_frame)
NACK_BULK_BACKLOG = 8  # bulk messages waiting beyond which a NACK drops its detail text and goes fixed
SLCAN_WINDOW = 512  # SLCAN text bytes handed to the pty at a time; the rest waits in priority order
FAULTY_WINDOW = 32  # frames the tx fault injector released that may wait for the wire (then the queue waits)
BACKOFF_MIN_S = 0.001
BACKOFF_MAX_S = 0.02

class CanBoardTransport(BoardTransport):
    """Shared CAN logic over :class:`protocol.can.engine.CanEngine`; subclasses read and write frames."""

    def __init__(self, spec: LinkSpec, log_path: str | None = None, servo_count: int | None = None) -> None:
        super().__init__()
        self.spec = spec
        self.node = spec.node
        self.fd = spec.fd
        self.framelog: FrameLogWriter | None = None
        self.channel_name = spec.channel or "can0"
        self.layouts: CanLayouts = can_layouts() if servo_count is None else can_layouts(servo_count)
        #: ISO-TP's clock (ns): the ``now`` of the latest receive/queue/flush (the board loop's time, as the C link's)
        self._now_ns = 0
        self.engine = CanEngine(self.node, "board", self.fd, self._enqueue, self.layouts, clock=lambda: self._now_ns)
        self.engine.excuse_flow_control = self._unanswered_reports
        self._txq: list[tuple[int, int, CanFrame]] = []  # heap: (identifier, order, frame)
        self._order = 0
        self._retry_at: float | None = None
        self._backoff = BACKOFF_MIN_S
        self.tx_retries = 0
        self.tx_frames = 0
        #: per message type, the newest periodic bulk report (SIM_STATE; TELEMETRY where it has no fixed
        #: layout) not yet handed to ISO-TP, with its sequence number; they take turns (insertion order)
        self._periodic: dict[MsgType, tuple[int, bytes]] = {}
        self._periodic_in_flight = False  # the ISO-TP transfer under way is a periodic SIM_STATE
        self.host_heard = False  # a frame came from a host since the start, or since a periodic report went unanswered
        self.periodic_unheard = 0  # SIM_STATE reports not sent: no host heard yet (or it went away)
        self.periodic_unanswered = 0  # SIM_STATE transfers whose First Frame no host answered (flow control timeout)
        self._items: list[Frame | DecodeError] = []  # what ISO-TP completed between receives (never dropped)
        self.periodic_replaced = 0
        self.nack_details_dropped = 0  # NACKs sent as one fixed frame without their detail text
        self.error_frames = 0
        if log_path:
            self.framelog = open_frame_log(log_path, "can", channel=self.channel_name)
        # link fault injection (``--faults``, firmware_sim.transports.faulty.install_faults)
        self.rx_faults: FaultInjector[CanFrame] | None = None
        self.tx_faults: FaultInjector[CanFrame] | None = None
        self._faulty_out: deque[CanFrame] = deque()  # frames the tx injector released, not yet written

    @property
    def channel_name(self) -> str:
        """The bus as the frame log names it (the host's log names it the same way)."""
        return self._channel_name

    @channel_name.setter
    def channel_name(self, name: str) -> None:
        self._channel_name = name
        if self.framelog is not None:
            self.framelog.channel = name  # type: ignore[attr-defined]

    def use_board_clock(self, board_clock: Callable[[], int] | None) -> None:
        self.engine.use_board_clock(board_clock)

    @property
    def decoder(self) -> Any:
        """The engine's fixed-layout reassembler (its ``errors``, ``foreign``, ``duplicates`` counters)."""
        return self.engine.decoder

    @property
    def isotp(self) -> Any:
        """The engine's ISO-TP link."""
        return self.engine.isotp

    # subclass hooks ------------------------------------------------------------------------

    def _read_frames(self) -> list[CanFrame]:
        raise NotImplementedError

    def _write_frame(self, frame: CanFrame) -> bool | None:
        """Hand one frame to the wire: True sent; False refused now (retried later); None the wire
        cannot carry it (dropped and counted by the subclass: not logged, it never was on the bus)."""
        raise NotImplementedError

    def _wire_has_room(self) -> bool:
        """False while the wire below still holds enough to keep it busy (frames then wait, by priority)."""
        return True

    # ------------------------------------------------------------------------------------------

    def _enqueue(self, frame: CanFrame) -> None:
        # a CAN controller's transmit buffers go out lowest identifier first (bus priority);
        # frames of one identifier (the parts of a message) keep their order
        heapq.heappush(self._txq, (frame.arbitration_id, self._order, frame))
        self._order += 1

    def _log(self, frame: CanFrame, is_rx: bool) -> None:
        if self.framelog is not None:
            self.framelog.write_can("rx" if is_rx else "tx", frame)

    def _unanswered_reports(self, timeouts: int) -> int:
        """A periodic report (SIM_STATE; bulk TELEMETRY) whose First Frame nobody answers is no link error:
        no host is listening (it has not connected yet, or it went away mid-transfer). It is counted
        (``periodic_unanswered``), and reports wait until a host is heard again."""
        if not self._periodic_in_flight:
            return 0
        self.periodic_unanswered += timeouts
        self.host_heard = False
        return timeouts

    def _poll(self) -> None:
        """Advance ISO-TP; what it completes waits for :meth:`receive`."""
        self._items += self.engine.poll()
        if self._periodic_in_flight and not self.engine.isotp.layer.transmitting():
            self._periodic_in_flight = False

    def _take_line_errors(self) -> list[Frame | DecodeError]:
        return []

    def receive(self, now: float, *, read: bool = True) -> list[Frame | DecodeError]:
        self._now_ns = int(now * 1e9)
        frames = self._read_frames() if read else []
        if self.rx_faults is not None:  # what reaches the controller: after the injected faults
            for f in frames:
                self.rx_faults.push(f, now)
            # a frame the modelled line held arrives when it is let through, not when the bus delivered it
            frames = [dataclasses.replace(f, timestamp=None) for f in self.rx_faults.pop_due(now)]
        errors = self._take_line_errors()
        if not frames and not self.engine.busy and not self._items:
            return errors
        for f in frames:
            self._log(f, True)
        if frames:
            self.host_heard = True
        items = self.engine.feed_many(frames)
        if self._periodic_in_flight and not self.engine.isotp.layer.transmitting():
            self._periodic_in_flight = False
        taken, self._items = self._items, []
        return errors + taken + items

    def queue(self, msg: Message, seq: int, now: float) -> bool:
        self._now_ns = int(now * 1e9)
        if isinstance(msg, Nack) and msg.detail and self._nack_fixed(msg):
            # the reason code says it all; the detail text would take a multi-frame ISO-TP transfer
            msg = dataclasses.replace(msg, detail="")
            self.nack_details_dropped += 1
        try:
            kind = PERIODIC_REPORTS.get(type(msg))
            if self.engine.is_fixed(msg):
                self.engine.send(msg, seq)
            elif kind is not None:
                # periodic bulk (SIM_STATE; TELEMETRY too where it has no fixed layout): the newest
                # report wins, under the sequence number of the one it replaces (no gap for the host to
                # count as lost); it waits until the ISO-TP link is idle
                waiting = self._periodic.get(kind)
                if waiting is not None:
                    self.periodic_replaced += 1
                    seq = waiting[0]
                self._periodic[kind] = (seq, self.engine.encode_bulk(msg, seq))
                self._start_periodic()
                return waiting is None
            else:
                self.engine.send(msg, seq)
                self._poll()
        except (PayloadError, BufferError) as e:
            print(f"board: cannot send {type(msg).__name__} on CAN: {e}", file=sys.stderr, flush=True)
            return False
        return True

    def _nack_fixed(self, msg: Nack) -> bool:
        """Send this NACK as one fixed frame, without its detail text? Yes for a refused SERVO_FRAME
        (up to one per frame, 100 Hz: as ISO-TP transfers they queued up behind each other under
        load, 256 of them, and telemetry waited) and whenever bulk messages are already waiting."""
        return msg.msg_type == MsgType.SERVO_FRAME or self.engine.isotp.layer.tx_queue.qsize() >= NACK_BULK_BACKLOG

    def _start_periodic(self) -> None:
        if self._periodic and not self.host_heard:
            # a multi-frame ISO-TP transfer needs a receiver's flow control: with no host on the bus it could
            # only time out, so the report is left out (the next one after a host is heard goes)
            self.periodic_unheard += len(self._periodic)
            self._periodic.clear()
            return
        layer = self.engine.isotp.layer
        if self._periodic and not layer.transmitting() and layer.tx_queue.empty():
            _, sdu = self._periodic.pop(next(iter(self._periodic)))
            self.engine.send_bulk(sdu)
            self._periodic_in_flight = True
            self._poll()

    def flush(self, now: float) -> None:
        self._now_ns = int(now * 1e9)
        if self.engine.busy:
            self._poll()
        self._start_periodic()
        if self._retry_at is not None and now < self._retry_at:
            return
        self._retry_at = None
        while self._txq and self._wire_has_room() and len(self._faulty_out) < FAULTY_WINDOW:
            f = self._txq[0][2]
            sent = self._emit(f, now)
            if sent is False:
                self.tx_retries += 1
                self._retry_at = now + self._backoff
                self._backoff = min(self._backoff * 2, BACKOFF_MAX_S)
                return
            heapq.heappop(self._txq)
            self._backoff = BACKOFF_MIN_S
            if sent:
                self.tx_frames += 1
                self._log(f, False)
        self._drain_faulty(now)

    def _emit(self, frame: CanFrame, now: float) -> bool | None:
        """Send one frame, through the tx fault injector when one is installed."""
        if self.tx_faults is None:
            return self._write_frame(frame)
        self.tx_faults.push(frame, now)
        return True

    def _drain_faulty(self, now: float) -> None:
        """Write the frames the tx injector has released by ``now`` (a refused one waits, in order)."""
        if self.tx_faults is None:
            return
        self._faulty_out.extend(self.tx_faults.pop_due(now))
        while self._faulty_out and self._wire_has_room() and self._write_frame(self._faulty_out[0]) is not False:
            self._faulty_out.popleft()

    @property
    def backlog(self) -> int:
        # queued frames plus bulk messages still waiting in the ISO-TP layer (~one frame per 7 bytes)
        return FRAME_COST * (len(self._txq) + len(self._faulty_out) + 8 * self.engine.bulk_waiting)

    def next_io_time(self) -> float | None:
        due = [t for inj in (self.rx_faults, self.tx_faults) if inj is not None
               for t in (inj.next_due(),) if t is not None]
        if self._faulty_out:
            due.append(time.monotonic() + BACKOFF_MIN_S)
        if self._retry_at is not None:
            due.append(self._retry_at)
        if self.engine.busy or self._periodic:
            due.append(time.monotonic() + 0.002)
        return min(due) if due else None

    def exit_note(self) -> str | None:
        if not self.periodic_unanswered:
            return None
        lossy = " or the link lost the frames" if self.rx_faults is not None or self.tx_faults is not None else ""
        bulk_telemetry = self.layouts.layout(FunctionCode.TELEMETRY, self.fd) is None
        what = "SIM_STATE/TELEMETRY" if bulk_telemetry else "SIM_STATE"
        return (f"{self.periodic_unanswered} {what} report(s) got no ISO-TP flow control (the host had gone "
                f"away{lossy}); later reports waited until a host was heard again")

    def close(self) -> None:
        if self.framelog is not None:
            self.framelog.close()
            self.framelog = None


class BusBoardTransport(CanBoardTransport):
    """The board on a python-can bus: ``can.Bus(**spec.bus_kwargs())`` filtered on its node id."""

    def __init__(self, spec: LinkSpec, log_path: str | None = None, bus: can.BusABC | None = None,
                 servo_count: int | None = None) -> None:
        super().__init__(spec, log_path, servo_count)
        if bus is None:
            kw = spec.bus_kwargs()
            kw.setdefault("can_filters", [
                {"can_id": self.node, "can_mask": 0x7F, "extended": False},  # this node's identifiers
                {"can_id": 0x000, "can_mask": 0x7FF, "extended": False},  # the broadcast ESTOP
            ])
            bus = can.Bus(**kw)  # type: ignore[arg-type]
        self.bus = bus
        self.name = f"{spec}"
        self.channel_name = str(getattr(bus, "channel_info", "") or spec.channel or "can0")
        if spec.channel:
            self.channel_name = spec.channel
        try:
            self._fd: int | None = int(bus.fileno())
        except (NotImplementedError, OSError, AttributeError, ValueError):
            self._fd = None

    def fileno(self) -> int | None:
        return self._fd

    def _read_frames(self) -> list[CanFrame]:
        out: list[CanFrame] = []
        for _ in range(512):
            try:
                msg = self.bus.recv(timeout=0)
            except can.CanError as e:
                print(f"board: CAN receive error: {e}", file=sys.stderr, flush=True)
                break
            if msg is None:
                break
            if msg.is_error_frame:
                self.error_frames += 1
                continue
            out.append(from_can_message(msg))
        return out

    def _write_frame(self, frame: CanFrame) -> bool | None:
        try:
            self.bus.send(to_can_message(frame, None), timeout=0)
        except can.CanOperationError as e:
            code = getattr(e, "error_code", None)
            if code in (errno.ENOBUFS, errno.EAGAIN) or "buffer" in str(e).lower():
                return False
            print(f"board: CAN send failed ({e}); retrying", file=sys.stderr, flush=True)
            return False
        return True

    def close(self) -> None:
        try:
            self.bus.shutdown()
        except Exception:
            pass
        super().close()


class SlcanBoardTransport(CanBoardTransport):
    """The board as an SLCAN USB-CAN adapter on a new pty (``can:slcan:pty``)."""

    def __init__(self, spec: LinkSpec, log_path: str | None = None, servo_count: int | None = None) -> None:
        super().__init__(spec, log_path, servo_count)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.name = os.ttyname(self.slave)
        self.channel_name = self.name  # the frame log names the bus as the host's python-can does: the adapter's tty
        self.device = SlcanDevice()
        self._out = bytearray()
        self._line_errors: list[str] = []
        self.dropped_closed = 0

    def fileno(self) -> int:
        return self.master

    def _read_frames(self) -> list[CanFrame]:
        try:
            data = os.read(self.master, 65536)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError as e:
            if e.errno == errno.EIO:
                return []
            raise
        events, reply = self.device.feed(data)
        self._out += reply
        self._line_errors += [ev.error for ev in events if ev.error]
        return [ev.frame for ev in events if ev.frame is not None]

    def _wire_has_room(self) -> bool:
        return len(self._out) < SLCAN_WINDOW

    def _take_line_errors(self) -> list[Frame | DecodeError]:
        errs, self._line_errors = self._line_errors, []
        return [DecodeError(DecodeErrorKind.LENGTH, f"SLCAN: {e}", b"") for e in errs]

    def _write_frame(self, frame: CanFrame) -> bool | None:
        if not self.device.is_open:
            self.dropped_closed += 1  # a closed adapter is not on the bus: the frame is lost
            return None
        self._out += format_frame(frame)
        return True

    def flush(self, now: float) -> None:
        super().flush(now)
        while self._out:
            self._write_out()
            if self._out or not self._txq:
                break
            super().flush(now)  # the window drained: move the next frames (by priority) into it

    def _write_out(self) -> None:
        while self._out:
            try:
                n = os.write(self.master, self._out)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            del self._out[:n]

    @property
    def backlog(self) -> int:
        return super().backlog + len(self._out)

    @property
    def wants_write(self) -> bool:
        return bool(self._out)

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        super().close()
