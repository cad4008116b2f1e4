"""Link I/O around the board core: receive messages, run the clock, send replies and telemetry.

The server works only against :class:`firmware_sim.transports.base.BoardTransport`
(serial, CAN, ...): the transport owns framing, the wire model and the frame log.

One thread, one ``select`` loop. Realtime: ticks are paced by
:class:`firmware_sim.clock.RealtimeClock`; received frames are handled and output flushed between
ticks, also while the loop catches up on late ones. Lockstep: the board ticks as fast as it can while the host has covered
the next tick, and waits on the link otherwise; it also waits while the
outgoing backlog is large, so a slow reader never loses telemetry.
Outgoing bytes are bounded: telemetry is dropped (counted in ``tx_dropped``) when the
backlog passes ``TELEMETRY_BACKLOG`` or, with a modelled wire rate on a realtime board, when the
wire is already busy for more than 20 ms (so replies never queue behind telemetry the line
cannot carry); a lockstep board waits for such a line instead (its time is its own: dropping
there lost reports only because it ran faster than real time); replies are dropped only past
``MAX_BACKLOG``. Reports dropped while no host has
been heard for ``NO_HOST_S`` are counted apart (``tx_dropped_no_host``): nobody was reading then,
which is not a slow link.

Lockstep overlap: the server hands :meth:`Board.run` its link work (:meth:`BoardServer._link_work`), which
runs while the native kernel ticks a batch on its own thread (:meth:`firmware_sim.native.NativeTick.run_during`):
the reports a batch made are held (``_outbox``) and encoded, frame-logged (at the board time they were made)
and written during the next long batch, before any reply, or before the board waits; what arrived is read
and decoded meanwhile (it takes effect only when the board cannot tick, as ever). Same bytes, same order, same
frame log. Off by default: ``$GHOSTSHELL_LOCKSTEP_OVERLAP=1`` turns it on. Measured on this 2-core machine, quiet
(``bench/bench_board.py --lockstep-only --rounds 3``, 2026-12-08), the hand-overs to and from the kernel's thread
cost more than the overlap saves: pty/bare 0.45 with it and 0.53 without (CoCo), 0.34 and 0.40 (the arm).

Transmit timestamps: over a modelled line (``--baud``) a TIME_SYNC_REPLY queues behind the reports
already on the wire (at 115 200 baud a report pair is ~14 ms of every 20). Its ``t3`` is stamped for
the moment its first byte goes on the wire (board now + the line's committed time), as a UART driver
that fills the timestamp when it dequeues the reply, or PTP's hardware timestamping, would. Otherwise
the queueing counts as path asymmetry: the host's NTP offset is biased by half of it, and with it
every board time the host derives (seen: an uplink estimate of 4.5 ms median, 12 ms p99, where the
pty's is ~0.5 ms).
"""

from __future__ import annotations

import dataclasses
import os
import select
import sys
import time
from collections import deque
from typing import IO

from firmware_sim.board import OVERLAP_MIN_TICKS, Board, answerable
from firmware_sim.board_reports import DeferredReports
from firmware_sim.clock import RealtimeClock
from firmware_sim.objects_log import ObjectsLog
from firmware_sim.transports.base import PERIODIC_REPORTS, BoardTransport
from protocol.framing import DecodeError, Frame
from protocol.messages import Message, TimeSyncReply

__all__ = ["BoardServer"]

TELEMETRY_BACKLOG = 16 * 1024
TELEMETRY_WIRE_BACKLOG_S = 0.02  # with --baud: drop telemetry rather than queue > 20 ms of wire time
LOCKSTEP_BACKLOG = 8 * 1024
MAX_BACKLOG = 4 * 1024 * 1024
INBOX_LIMIT = 4096  # lockstep: stop reading (the pty buffers, the host blocks) beyond this
OVERLAP_ENV = "GHOSTSHELL_LOCKSTEP_OVERLAP"
OUTBOX_HOLD = 8  # lockstep: held reports queued at the latest once this many batches made some (_link_work)
NO_HOST_S = 1.0  # wall seconds without a valid message after which no host is taken to be listening


class BoardServer:
    """Serves one :class:`Board` over one :class:`BoardTransport` until :meth:`stop` or a signal."""

    def __init__(
        self,
        board: Board,
        transport: BoardTransport,
        viewer: object | None = None,
        err: IO[str] | None = None,
        objects_log: ObjectsLog | None = None,
    ) -> None:
        self.board = board
        self.objects_log = objects_log
        self.transport = transport
        transport.log_time = self._t
        self.tx_seq = 0
        self.tx_dropped = 0  # dropped while a host was talking to the board: the link was too slow
        self.tx_dropped_no_host = 0  # dropped while no host had been heard for NO_HOST_S
        self.last_rx: float | None = None  # monotonic time of the last valid message
        self.viewer = viewer
        self.err: IO[str] = sys.stderr if err is None else err
        self.running = True
        self.inbox: deque[Frame | DecodeError] = deque()  # lockstep: decoded, not yet handled
        #: lockstep: reports made (with the board time they were made at), queued by the next long batch's
        #: _link_work, before any reply, or before the board waits (see _serve_lockstep)
        self._outbox: list[tuple[int, list[Message]]] = []
        self._log_at_us: int | None = None  # frame-log time while _send_outbox queues held reports
        #: lockstep: the link work runs while the native kernel ticks (``$GHOSTSHELL_LOCKSTEP_OVERLAP=1``; by default
        #: after each run of ticks, in this thread: faster here, see the module docstring; same bytes either way)
        self.overlap = os.environ.get(OVERLAP_ENV, "0") not in ("", "0")
        self.clock = RealtimeClock(board.tick_us / 1e6) if not board.cfg.lockstep else None
        if board.cfg.lockstep:  # CAN's ISO-TP timers count board time (protocol/can/isotp_link.py)
            transport.use_board_clock(lambda: board.now_us * 1000)
        if self.clock is not None:
            board._clock_us = self.clock.board_time_us  # fine-grained time for TIME_SYNC

    # --- output ----------------------------------------------------------------------------

    @property
    def backlog(self) -> int:
        return self.transport.backlog

    def _dropped(self, now: float) -> None:
        if self.last_rx is None or now - self.last_rx > NO_HOST_S:
            self.tx_dropped_no_host += 1
        else:
            self.tx_dropped += 1

    def send(self, msgs: list[Message]) -> None:
        if msgs and self._outbox:  # lockstep: reports held back go first, in the order they were made
            self._send_outbox()
        now = time.monotonic()
        tr = self.transport
        for m in msgs:
            periodic = type(m) in PERIODIC_REPORTS
            if periodic and self.clock is not None and tr.tx_busy_s(now) > TELEMETRY_WIRE_BACKLOG_S:
                self._dropped(now)
                continue
            if tr.backlog > (TELEMETRY_BACKLOG if periodic else MAX_BACKLOG):
                self._dropped(now)
                continue
            if isinstance(m, TimeSyncReply) and self.clock is not None:  # transmit timestamp (module doc)
                m = dataclasses.replace(m, t3_board_us=m.t3_board_us + int(tr.tx_busy_s(now) * 1e6))
            if tr.queue(m, self.tx_seq, now):  # (not when it replaced a waiting report: BoardTransport.queue)
                self.tx_seq = (self.tx_seq + 1) & 0xFFFF

    def _tick(self) -> None:
        """One control tick; its reports go out (and the object poses into the objects log)."""
        out = self.board.tick()
        if self.objects_log is not None:
            self.objects_log.record(out)
        self.send(out)

    def _flush_tx(self) -> None:
        self.transport.flush(time.monotonic())

    # --- input -----------------------------------------------------------------------------

    def _t(self) -> float:
        if self._log_at_us is not None:
            return self._log_at_us / 1e6
        return self.board.board_time_us() / 1e6

    def _deliver(self, read: bool = False) -> None:
        items = self.transport.receive(time.monotonic(), read=read)
        if not items:
            return
        if self.clock is None:  # lockstep: messages take effect in stream order, see _serve_lockstep
            self.inbox.extend(items)
            return
        for item in items:
            self._process(item)

    def _process(self, item: Frame | DecodeError) -> None:
        """Count one received item if bad, else hand it to the board and send the replies."""
        if isinstance(item, DecodeError):
            item = answerable(item)  # a well-formed CONFIG with an unknown key is answered (NACK BAD_VALUE)
        if isinstance(item, DecodeError):
            self.board.on_link_error()
            print(f"board: link error {item.kind.value}: {item.detail}", file=self.err, flush=True)
            return
        self.last_rx = time.monotonic()
        try:
            replies = self.board.handle(item.msg, item.seq)
        except Exception as e:  # a bug must not take the board down: report and go on
            print(f"board: error handling {item.msg_type.name}: {e!r}", file=self.err, flush=True)
            return
        self.send(replies)

    # --- loops -----------------------------------------------------------------------------

    def _wait(self, timeout: float | None) -> bool:
        """Wait up to ``timeout`` s for input (or writability while bytes wait); True if there may be input."""
        fd = self.transport.fileno()
        if fd is None:  # no selectable fd (some pyserial URLs): poll
            time.sleep(0.0005 if timeout is None else max(0.0, min(timeout, 0.0005)))
            return True
        try:
            r, _, _ = select.select([fd], [fd] if self.transport.wants_write else [], [], timeout)
        except InterruptedError:
            return False
        return bool(r)

    def _next_io_time(self) -> float | None:
        return self.transport.next_io_time()

    def stop(self) -> None:
        self.running = False

    def serve(self) -> None:
        """Run until :meth:`stop` (or an exception such as KeyboardInterrupt). A lockstep board stopped
        with messages still queued (received and logged, not yet due) counts their sequence numbers
        (:meth:`Board.count_unhandled`) and its bad frames, and handles none of them."""
        try:
            if self.clock is None:
                self._serve_lockstep()
            else:
                self._serve_realtime()
        finally:
            while self.inbox:
                item = self.inbox.popleft()
                if isinstance(item, Frame):
                    self.board.count_unhandled(item.msg, item.seq)
                else:
                    self.board.on_link_error()  # logged as a bad frame: counted as one, as _process would
            self._send_outbox()  # made before the stop: queued (and logged) as they would have been
            # a lockstep board renders captures in this thread: free its GL contexts here, the thread
            # that made them (a board served in a thread would otherwise free them from another one)
            self.board.camera.close()
            if self.board.native is not None:
                self.board.native.close()  # the kernel's thread (NativeTick.run_during), if one started

    def _serve_realtime(self) -> None:
        clock = self.clock
        assert clock is not None
        clock.start = time.monotonic()
        while self.running:
            now = time.monotonic()
            timeout = clock.deadline() - now
            io_t = self._next_io_time()
            if io_t is not None:
                timeout = min(timeout, io_t - now)
            if self.transport.wants_write:
                timeout = min(timeout, 0.001)
            self._deliver(read=self._wait(max(0.0, timeout)))
            while self.running and clock.deadline() <= time.monotonic():
                before = clock.next_tick
                _, overran = clock.begin_tick()
                skipped = clock.next_tick - before - 1
                self._tick()
                if self.board.watchdog_events:
                    self._report_watchdog()
                if skipped:
                    self.board.skip(skipped)
                if overran:
                    self.board.note_overrun()
                self._sync_viewer()
                if clock.deadline() <= time.monotonic():
                    # another tick is due at once: serve the link first. A board behind real time (a
                    # loaded machine, a guest VM) that read and wrote only once caught up went silent for
                    # as long as it stayed behind, with no bound when every tick costs more than a period
                    # (re-anchoring does not end the catch-up then): longer than ISO-TP's 200 ms
                    # flow-control wait or a reply timeout
                    self._flush_tx()
                    self._deliver(read=self._wait(0.0))
                else:
                    self._deliver()
            self._flush_tx()

    def _serve_lockstep(self) -> None:
        """Virtual time. Each received message takes effect at the board time the messages
        before it have covered: the board handles the next message only when it cannot tick.
        So the same byte stream gives the same telemetry, however the bytes were chunked. Ticks run
        through :meth:`Board.run` (the ticks up to the next report, the quiet ones in one C call);
        the backlog is checked before each such run, and a run sends at most one tick's reports."""
        # reports made while the next ticks run (not with an objects log: it reads the model as the reports are made)
        self.board.defer_reports = self.overlap and self.objects_log is None
        try:
            self._serve_lockstep_loop()
        finally:
            self.board.defer_reports = False

    def _serve_lockstep_loop(self) -> None:
        while self.running:
            ran = 0
            flushed = 0
            while (self.running and self.board.can_tick() and self.backlog < LOCKSTEP_BACKLOG and ran < 256
                   and self._line_has_room()):
                # up to the next tick with reports, several per C call; the link work of the reports before
                # (encode, write) and of what arrives (read, decode) runs while the C ticks (_link_work)
                n, out = self.board.run(256 - ran, during=self._link_work if self.overlap else None)
                if out:
                    if self.objects_log is not None:
                        self.objects_log.record(out)
                    if self.overlap:  # logged at the board time they were made (a split run ticks on past its report)
                        last = out[-1]
                        self._outbox.append((last.now_us if isinstance(last, DeferredReports) else self.board.board_time_us(), out))
                    else:
                        self.send(out)
                if self.board.watchdog_events:
                    self._report_watchdog()
                ran += n
                if not self.overlap and ran - flushed >= 16:
                    self._flush_tx()
                    flushed = ran
            self._sync_viewer()
            handled = 0
            while self.inbox and not self.board.can_tick() and handled < 256:
                self._process(self.inbox.popleft())  # (its replies go after the held reports: send)
                handled += 1
            if not (self.board.can_tick() and self.backlog < LOCKSTEP_BACKLOG and self._line_has_room()):
                self._send_outbox()  # the board waits now: nothing it made is held back meanwhile
            self._flush_tx()
            blocked = ((not self.board.can_tick() and not self.inbox) or self.backlog >= LOCKSTEP_BACKLOG
                       or not self._line_has_room())
            timeout: float = 0.5 if blocked else 0.0
            io_t = self._next_io_time()
            if io_t is not None:
                timeout = min(timeout, max(0.0, io_t - time.monotonic()))
            if self.transport.wants_write:
                timeout = min(timeout, 0.001)
            readable = False
            if len(self.inbox) < INBOX_LIMIT:
                # not waiting: read at once (a non-blocking read is one system call, a select first two)
                readable = True if timeout <= 0.0 and self.transport.fileno() is not None else self._wait(timeout)
            elif timeout:
                time.sleep(min(timeout, 0.001))
            self._deliver(read=readable)

    def _send_outbox(self) -> None:
        """Queue the reports held back since they were made (see :meth:`_link_work`), each frame-logged at
        the board time it was made, as if queued at once."""
        if self._outbox:
            out, self._outbox = self._outbox, []
            for t_us, msgs in out:
                self._log_at_us = t_us
                try:
                    self.send([m for x in msgs for m in (x.messages() if isinstance(x, DeferredReports) else (x,))])
                finally:
                    self._log_at_us = None

    def _link_work(self, n_ticks: int) -> None:
        """Lockstep, once per batch of ``n_ticks`` ticks: in a long one (``OVERLAP_MIN_TICKS`` or more), while
        the native kernel runs it on its own thread, queue the held reports (encode, frame log), write what
        the OS takes, read and decode what came (into :attr:`inbox`; it takes effect only when the board
        cannot tick, as ever). A short batch runs in this thread: nothing then (the loop reads and writes
        right after it) unless ``OUTBOX_HOLD`` batches' reports wait. Nothing here touches the board (its
        MjData and arrays are the ticks' own meanwhile)."""
        if n_ticks < OVERLAP_MIN_TICKS:  # a short batch runs in this thread: the loop reads and writes after it
            if len(self._outbox) >= OUTBOX_HOLD:
                self._send_outbox()
            return
        self._send_outbox()
        self._flush_tx()
        if len(self.inbox) < INBOX_LIMIT:
            self._deliver(read=True)

    def _line_has_room(self) -> bool:
        """False while a modelled line (``--baud``) has more than ``TELEMETRY_WIRE_BACKLOG_S`` of wire time
        queued: a lockstep board then waits for it instead of dropping its reports, so it runs no faster
        than the line carries them, and lockstep at a given baud loses no report that realtime would keep."""
        return self.transport.tx_busy_s(time.monotonic()) <= TELEMETRY_WIRE_BACKLOG_S

    def _report_watchdog(self) -> None:
        """One stderr line per watchdog transition and ESTOP (the runner and the fault tests read them)."""
        while self.board.watchdog_events:
            t, mode, fed = self.board.watchdog_events.popleft()
            if mode == "estop":
                print(f"board: estop in effect at board time {t / 1e6:.6f} s, {(t - fed) / 1e6:.6f} s after it arrived",
                      file=self.err, flush=True)
                continue
            if mode == "resume":
                print(f"board: watchdog resume at board time {t / 1e6:.6f} s, a valid message ended the hold after "
                      f"{(t - fed) / 1e6:.6f} s", file=self.err, flush=True)
                continue
            print(f"board: watchdog {mode} at board time {t / 1e6:.6f} s, {(t - fed) / 1e6:.6f} s after the last "
                  f"valid message" + ("; fault latched until ESTOP_CLEAR" if mode != "hold" else ""),
                  file=self.err, flush=True)

    def _sync_viewer(self) -> None:
        v = self.viewer
        if v is not None and self.board.ticks % 8 == 0:
            v.sync()  # type: ignore[attr-defined]
