"""Link I/O around the board core: decode received bytes, run the clock, send replies and telemetry.

One thread, one ``select`` loop. Realtime: ticks are paced by
:class:`firmware_sim.clock.RealtimeClock`; received frames are handled between
ticks. Lockstep: the board ticks as fast as it can while the host has covered
the next tick, and waits on the link otherwise; it also waits while the
outgoing backlog is large, so a slow reader never loses telemetry.
Outgoing bytes are bounded: telemetry is dropped (counted in ``tx_dropped``) when the
backlog passes ``TELEMETRY_BACKLOG`` or, with a modelled baud rate, when the wire is
already busy for more than 20 ms (so replies never queue behind telemetry the line
cannot carry); replies are dropped only past ``MAX_BACKLOG``.
"""

from __future__ import annotations

import select
from collections import deque
import sys
import time
from typing import IO

from firmware_sim.board import Board
from firmware_sim.clock import RealtimeClock
from firmware_sim.link import Link, WireModel
from protocol import framelog
from protocol.framing import DecodeError, Frame, FrameDecoder, encode_frame
from protocol.codec import msg_type_of
from protocol.messages import Message, SimState, Telemetry

__all__ = ["BoardServer"]

TELEMETRY_BACKLOG = 16 * 1024
TELEMETRY_WIRE_BACKLOG_S = 0.02  # with --baud: drop telemetry rather than queue > 20 ms of wire time
LOCKSTEP_BACKLOG = 8 * 1024
MAX_BACKLOG = 4 * 1024 * 1024
INBOX_LIMIT = 4096  # lockstep: stop reading (the pty buffers, the host blocks) beyond this


class BoardServer:
    """Serves one :class:`Board` over one :class:`Link` until :meth:`stop` or a signal."""

    def __init__(
        self,
        board: Board,
        link: Link,
        baud: int | None = None,
        log: IO[str] | None = None,
        viewer: object | None = None,
        err: IO[str] = sys.stderr,
    ) -> None:
        self.board = board
        self.link = link
        self.decoder = FrameDecoder()
        self.rx_wire = WireModel(baud)
        self.tx_wire = WireModel(baud)
        self.tx_pending = bytearray()
        self.tx_seq = 0
        self.tx_dropped = 0
        self.log = log
        self.viewer = viewer
        self.err = err
        self.running = True
        self.inbox: deque[Frame | DecodeError] = deque()  # lockstep: decoded, not yet handled
        self.clock = RealtimeClock(board.tick_us / 1e6) if not board.cfg.lockstep else None
        if self.clock is not None:
            board._clock_us = self.clock.board_time_us  # fine-grained time for TIME_SYNC

    # --- output ----------------------------------------------------------------------------

    @property
    def backlog(self) -> int:
        return self.tx_wire.bytes_queued + len(self.tx_pending)

    def send(self, msgs: list[Message]) -> None:
        now = time.monotonic()
        for m in msgs:
            periodic = isinstance(m, (Telemetry, SimState))
            wire_busy = self.tx_wire.byte_time and self.tx_wire.free_at - now > TELEMETRY_WIRE_BACKLOG_S
            if self.backlog > (TELEMETRY_BACKLOG if periodic else MAX_BACKLOG) or (periodic and wire_busy):
                self.tx_dropped += 1
                continue
            raw = encode_frame(m, self.tx_seq)
            if self.log is not None:
                item = Frame(self.tx_seq & 0xFFFF, msg_type_of(m), m, raw)
                self.log.write(framelog.to_line(framelog.record("tx", self._t(), raw, item)) + "\n")
            self.tx_seq = (self.tx_seq + 1) & 0xFFFF
            self.tx_wire.push(now, raw)

    def _flush_tx(self) -> None:
        self.tx_pending += self.tx_wire.pop_ready(time.monotonic())
        if self.tx_pending:
            n = self.link.write(bytes(self.tx_pending))
            del self.tx_pending[:n]

    # --- input -----------------------------------------------------------------------------

    def _t(self) -> float:
        return self.board.board_time_us() / 1e6

    def _read(self) -> None:
        data = self.link.read()
        if data:
            self.rx_wire.push(time.monotonic(), data)

    def _deliver(self) -> None:
        data = self.rx_wire.pop_ready(time.monotonic())
        if not data:
            return
        items = self.decoder.feed(data)
        if self.clock is None:  # lockstep: messages take effect in stream order, see _serve_lockstep
            self.inbox.extend(items)
            return
        for item in items:
            self._process(item)

    def _process(self, item: Frame | DecodeError) -> None:
        """Log one received item, count it if bad, else hand it to the board and send the replies."""
        if self.log is not None:
            self.log.write(framelog.to_line(framelog.record("rx", self._t(), item.raw, item)) + "\n")
        if isinstance(item, DecodeError):
            self.board.on_link_error()
            print(f"board: link error {item.kind.value}: {item.detail}", file=self.err, flush=True)
            return
        try:
            replies = self.board.handle(item.msg, item.seq)
        except Exception as e:  # a bug must not take the board down: report and go on
            print(f"board: error handling {item.msg_type.name}: {e!r}", file=self.err, flush=True)
            return
        self.send(replies)

    # --- loops -----------------------------------------------------------------------------

    def _wait(self, timeout: float | None) -> None:
        fd = self.link.fileno()
        wants_write = bool(self.tx_pending)
        if fd is None:  # no selectable fd (some pyserial URLs): poll
            time.sleep(0.0005 if timeout is None else max(0.0, min(timeout, 0.0005)))
            self._read()
            return
        try:
            r, _, _ = select.select([fd], [fd] if wants_write else [], [], timeout)
        except InterruptedError:
            return
        if r:
            self._read()

    def _next_io_time(self) -> float | None:
        times = [t for t in (self.rx_wire.next_release(), self.tx_wire.next_release()) if t is not None]
        return min(times) if times else None

    def stop(self) -> None:
        self.running = False

    def serve(self) -> None:
        """Run until :meth:`stop` (or an exception such as KeyboardInterrupt)."""
        if self.clock is None:
            self._serve_lockstep()
        else:
            self._serve_realtime()

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
            if self.tx_pending:
                timeout = min(timeout, 0.001)
            self._wait(max(0.0, timeout))
            self._deliver()
            while clock.deadline() <= time.monotonic():
                before = clock.next_tick
                _, overran = clock.begin_tick()
                skipped = clock.next_tick - before - 1
                self.send(self.board.tick())
                if skipped:
                    self.board.skip(skipped)
                if overran:
                    self.board.note_overrun()
                self._sync_viewer()
                self._deliver()
            self._flush_tx()

    def _serve_lockstep(self) -> None:
        """Virtual time. Each received message takes effect at the board time the messages
        before it have covered: the board handles the next message only when it cannot tick.
        So the same byte stream gives the same telemetry, however the bytes were chunked."""
        while self.running:
            ran = 0
            while self.running and self.board.can_tick() and self.backlog < LOCKSTEP_BACKLOG and ran < 256:
                self.send(self.board.tick())
                ran += 1
                if ran % 16 == 0:
                    self._flush_tx()
            self._sync_viewer()
            handled = 0
            while self.inbox and not self.board.can_tick() and handled < 256:
                self._process(self.inbox.popleft())
                handled += 1
            self._flush_tx()
            blocked = (not self.board.can_tick() and not self.inbox) or self.backlog >= LOCKSTEP_BACKLOG
            timeout: float = 0.5 if blocked else 0.0
            io_t = self._next_io_time()
            if io_t is not None:
                timeout = min(timeout, max(0.0, io_t - time.monotonic()))
            if self.tx_pending:
                timeout = min(timeout, 0.001)
            if len(self.inbox) < INBOX_LIMIT:
                self._wait(timeout)
            elif timeout:
                time.sleep(min(timeout, 0.001))
            self._deliver()

    def _sync_viewer(self) -> None:
        v = self.viewer
        if v is not None and self.board.ticks % 8 == 0:
            v.sync()  # type: ignore[attr-defined]
