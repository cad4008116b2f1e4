"""The host CAN transport's send pump: queued frames onto the python-can bus, never blocking the loop.

Part of :class:`host.link.transports.can.CanLinkTransport` (the receive side is
:mod:`host.link.transports.can_rx`, opening the bus :mod:`host.link.transports.can_bus`).
:class:`CanSender` holds the transmit queue the CAN wire engine
(:class:`protocol.can.engine.CanEngine`: fixed layouts, the rest ISO-TP segmented by can-isotp)
emits frames into, and writes them in order:

* python-can's ``bus.send(msg, timeout=0)``: a refused write (SocketCAN's ENOBUFS on a full tx
  queue, python-can issue #2004) keeps the frame at the head and retries after
  :data:`BACKOFF_MIN_S` doubling to :data:`BACKOFF_MAX_S` (``tx_retries`` counts them); a vanished
  interface (ENODEV, ENXIO, ENETDOWN) or any other python-can error is a lost link;
* on SLCAN the lines go out through :class:`~host.link.transports.slcan_tx.SlcanWriter` instead of
  python-can's ``send`` (which spins in pyserial's write on a full port, freezing the event loop, and
  loses the rest of a line the port took in part): at most :data:`SLCAN_CHUNK` bytes of whole lines
  are handed to the port at a time, and the loop's writer callback (``add_writer``) continues when
  the port has room again (``tx_retries`` counts the waits).

Every frame handed to the bus (or to the SLCAN writer) goes to ``log_sent`` (the frame log) in
order. The transport refuses sends with more than :data:`MAX_TX_FRAMES` waiting (the bus is not
draining). asyncio stays here (``call_later`` for the retry, ``add_writer`` for SLCAN back-pressure),
as in every transport adapter: see :mod:`host.link.transports` for why.
"""

from __future__ import annotations

import asyncio
import errno
from collections import deque
from collections.abc import Callable

import can

from host.link.transports.slcan_tx import SlcanWriter
from protocol.can.frame import CanFrame
from protocol.can.pycan import to_can_message
from protocol.can.slcan import format_frame

__all__ = ["BACKOFF_MAX_S", "BACKOFF_MIN_S", "FRAME_COST", "MAX_TX_FRAMES", "SLCAN_CHUNK", "CanSender"]

MAX_TX_FRAMES = 4096
BACKOFF_MIN_S = 0.001
BACKOFF_MAX_S = 0.02
FRAME_COST = 16  # bytes a queued frame counts for in the transport's backlog
SLCAN_CHUNK = 1024  # bytes of SLCAN lines handed to the port at a time (the rest waits as frames)


class CanSender:
    """The send side of one CAN transport, across its connections (see the module docstring).

    ``queue`` is the transmit queue (the engine's ``emit`` appends to it); ``log_sent(frame)`` is called
    for every frame written, ``on_error(reason, generation)`` when the bus refuses for good.
    """

    def __init__(self, log_sent: Callable[[CanFrame], None], on_error: Callable[[str, int], None]) -> None:
        self._log_sent = log_sent
        self._on_error = on_error
        self.queue: deque[CanFrame] = deque()
        self._bus: can.BusABC | None = None
        self._generation = 0
        self._slcan: SlcanWriter | None = None  # SLCAN: our own non-blocking line output
        self._writer_fd: int | None = None  # the fd the loop watches for room (SLCAN)
        self._retry: asyncio.TimerHandle | None = None
        self._backoff = BACKOFF_MIN_S
        self.tx_retries = 0
        self.tx_frames = 0

    @property
    def backlog(self) -> int:
        """Encoded frame bytes waiting: :data:`FRAME_COST` per queued frame plus the SLCAN bytes not yet written."""
        return FRAME_COST * len(self.queue) + (len(self._slcan.pending) if self._slcan is not None else 0)

    def attach(self, bus: can.BusABC, fd: int, generation: int) -> None:
        """Write to ``bus`` (connection ``generation``) from now on, with an empty queue; a SLCAN bus with
        a file descriptor ``fd`` is written through :class:`SlcanWriter`."""
        from can.interfaces.slcan import slcanBus

        self.queue.clear()
        self._bus, self._generation = bus, generation
        self._slcan = SlcanWriter(fd) if isinstance(bus, slcanBus) and fd >= 0 else None

    def cancel_retry(self) -> None:
        if self._retry is not None:
            self._retry.cancel()
        self._retry = None

    def detach(self) -> None:
        """Stop writing (the retry is cancelled, the loop no longer waits for room; idempotent)."""
        self.cancel_retry()
        self._stop_waiting_writable()
        self._slcan = None
        self._bus = None

    def pump(self) -> None:
        """Write queued frames as far as the bus takes them now (never blocks)."""
        bus = self._bus
        if bus is None or self._retry is not None:
            return
        if self._slcan is not None:
            self._pump_slcan(self._slcan)
            return
        while self.queue:
            frame = self.queue[0]
            try:
                bus.send(to_can_message(frame), timeout=0.0)
            except can.CanOperationError as e:
                # ENOBUFS (python-can #2004) or a full serial port: keep it, retry with backoff
                self.tx_retries += 1
                code = getattr(e, "error_code", None)
                if code not in (None, errno.ENOBUFS, errno.EAGAIN) and code in (errno.ENODEV, errno.ENXIO, errno.ENETDOWN):
                    self._on_error(f"CAN send failed: {e}", self._generation)
                    return
                self._retry = asyncio.get_running_loop().call_later(self._backoff, self._retry_now)
                self._backoff = min(self._backoff * 2, BACKOFF_MAX_S)
                return
            except can.CanError as e:
                self._on_error(f"CAN send failed: {e}", self._generation)
                return
            self.queue.popleft()
            self.tx_frames += 1
            self._backoff = BACKOFF_MIN_S
            self._log_sent(frame)

    def _retry_now(self) -> None:
        self._retry = None
        self.pump()

    def _pump_slcan(self, out: SlcanWriter) -> None:
        """Whole SLCAN lines to the port as far as it takes them; the rest waits for the loop's
        writer callback (never blocks, never splits a line)."""
        while True:
            try:
                done = out.write()
            except OSError as e:
                self._on_error(f"CAN send failed: SLCAN port write: {e}", self._generation)
                return
            if not done:
                self.tx_retries += 1
                self._wait_writable(out.fd)
                return
            if not self.queue:
                self._stop_waiting_writable()
                return
            while self.queue and len(out.pending) < SLCAN_CHUNK:
                frame = self.queue.popleft()
                out.push(format_frame(frame))
                self.tx_frames += 1
                self._log_sent(frame)

    def _wait_writable(self, fd: int) -> None:
        if self._writer_fd is None:
            asyncio.get_running_loop().add_writer(fd, self._on_writable, self._generation)
            self._writer_fd = fd

    def _stop_waiting_writable(self) -> None:
        if self._writer_fd is not None:
            try:
                asyncio.get_running_loop().remove_writer(self._writer_fd)
            except (RuntimeError, ValueError, OSError):
                pass
            self._writer_fd = None

    def _on_writable(self, generation: int) -> None:
        if generation == self._generation:
            self.pump()
