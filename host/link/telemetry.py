"""Telemetry fan-out and fault edges: the session's TELEMETRY listener (python-can's Listener model).

:class:`TelemetryFanout` is handed every TELEMETRY report the session receives
(:meth:`TelemetryFanout.on_telemetry`) and keeps what the rest of the host reads: the latest
report, the fault bits of :data:`FAULT_BITS` and their edges (:class:`FaultEvent`, the last 256
kept, ``on_fault`` callbacks and one log line each), bounded drop-oldest subscriber queues, and
the replies (:class:`host.link.waiting.Reply`) of whoever waits for a report satisfying a predicate.
No I/O and no sending: the waits themselves, which may move a lockstep board's clock
(``BoardClient.wait_for(..., nudge=True)``), are :class:`host.link.telemetry_waits.TelemetryWaits`.
Subscribers read anyio memory object streams; the fan-out holds both ends of each, so a full stream
loses its oldest report (``receive_nowait``) rather than blocking the receive path.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass

import anyio
from anyio.streams.memory import MemoryObjectReceiveStream, MemoryObjectSendStream

from host.link.waiting import Reply
from protocol.messages import FaultFlags, Telemetry

__all__ = ["FAULT_BITS", "FaultEvent", "TelemetryFanout", "flag_names"]

log = logging.getLogger("host.link")
#: telemetry bits that are reported as fault edges
FAULT_BITS = FaultFlags.ESTOP | FaultFlags.WATCHDOG_HOLD | FaultFlags.WATCHDOG_FAULT | FaultFlags.SERVO_FAULT
#: fault edges kept (oldest dropped)
MAX_FAULT_EVENTS = 256


@dataclass(frozen=True)
class FaultEvent:
    """A change of the telemetry fault bits in :data:`FAULT_BITS`."""

    board_time_us: int
    host_time: float
    before: FaultFlags
    after: FaultFlags

    @property
    def raised(self) -> FaultFlags:
        return FaultFlags(self.after & ~self.before)

    @property
    def cleared(self) -> FaultFlags:
        return FaultFlags(self.before & ~self.after)


def flag_names(f: FaultFlags | int) -> str:
    """``"ESTOP|WATCHDOG_HOLD"`` for the bits set in ``f`` (``"NONE"`` when none)."""
    return "|".join(e.name or "" for e in FaultFlags if e.value and f & e) or "NONE"


Waiter = tuple[Callable[[Telemetry], bool], Reply[Telemetry]]
Subscriber = tuple[MemoryObjectSendStream[Telemetry], MemoryObjectReceiveStream[Telemetry]]


class TelemetryFanout:
    """Latest report, fault edges, subscribers and waiters (module docstring); ``queue_size`` bounds
    each subscriber's queue (a slow consumer loses the oldest report)."""

    def __init__(self, queue_size: int = 64) -> None:
        self.queue_size = queue_size
        self.latest: Telemetry | None = None
        self.faults = FaultFlags.NONE
        self.fault_events: deque[FaultEvent] = deque(maxlen=MAX_FAULT_EVENTS)
        #: WATCHDOG_HOLD edges raised (the board held its servos after a silent link), since this fan-out began
        self.watchdog_holds = 0
        self.on_fault: list[Callable[[FaultEvent], None]] = []
        self._subs: list[Subscriber] = []
        self._waiters: list[Waiter] = []

    def on_telemetry(self, t: Telemetry) -> None:
        """One report: fault edges first (callbacks may raise into the caller), then subscribers and waiters."""
        self.latest = t
        now_faults = FaultFlags(t.faults & FAULT_BITS)
        if now_faults != self.faults:
            ev = FaultEvent(t.board_time_us, time.monotonic(), self.faults, now_faults)
            self.faults = now_faults
            self.fault_events.append(ev)
            if ev.raised & FaultFlags.WATCHDOG_HOLD:
                self.watchdog_holds += 1
            if ev.raised:
                # info, not warning: the application reports faults (on_fault); a run ends with one message
                log.info("board fault raised: %s (board time %.3f s)", flag_names(ev.raised), t.board_time_us / 1e6)
            if ev.cleared:
                log.info("board fault cleared: %s (board time %.3f s)", flag_names(ev.cleared), t.board_time_us / 1e6)
            for cb in list(self.on_fault):
                cb(ev)
        for send, receive in self._subs:
            if send.statistics().current_buffer_used >= send.statistics().max_buffer_size:
                receive.receive_nowait()  # drop the oldest
            send.send_nowait(t)
        if self._waiters:
            keep = []
            for pred, fut in self._waiters:
                if fut.done():
                    continue
                if pred(t):
                    fut.set_result(t)
                else:
                    keep.append((pred, fut))
            self._waiters = keep

    async def subscribe(self, maxsize: int | None = None) -> AsyncIterator[Telemetry]:
        """Every report from now on, through a bounded drop-oldest queue."""
        sub: Subscriber = anyio.create_memory_object_stream[Telemetry](maxsize or self.queue_size)
        self._subs.append(sub)
        send, receive = sub
        try:
            with send, receive:
                while True:
                    yield await receive.receive()
        finally:
            self._subs = [s for s in self._subs if s is not sub]

    def waiter(self, predicate: Callable[[Telemetry], bool]) -> Reply[Telemetry]:
        """A reply set with the next report satisfying ``predicate`` (drop it with :meth:`forget`)."""
        fut: Reply[Telemetry] = Reply()
        self._waiters.append((predicate, fut))
        return fut

    def forget(self, fut: Reply[Telemetry]) -> None:
        """Stop feeding ``fut`` (a wait that ended)."""
        self._waiters = [(p, f) for p, f in self._waiters if f is not fut]
