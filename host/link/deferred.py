"""Work noted from a link callback and done from the event loop, in order, in slices.

A link's read callback and its send path must stay short: a token chunk, a frame to send or a
report waits behind whatever runs on the loop. Their bookkeeping (the frame log's JSON lines, the
run's MCAP) does not need to be done at that moment, only in order and completely. A
:class:`DeferredWork` takes ``(fn, args)`` from those callbacks and runs them from the loop:

* the first note arms one ``call_soon``; the loop then runs the noted calls in the order noted for
  about ``slice_s`` wall seconds and, if some are left, comes back on its next pass, after what
  became ready meanwhile (so the loop is never held much longer than one slice plus one call);
* with no running loop (a caller outside the session), or once ``max_deferred`` calls wait (a loop
  that never comes round), the calls are done at once: the backlog is bounded;
* :meth:`drain` does what is left now (before a close, at a turn's end). Nothing is dropped.

Loop thread only (not thread-safe): a thread hands its callbacks to the loop first
(``call_soon_threadsafe``, as the serial transport's reader thread does). Exceptions from a call
propagate to whoever runs it (the loop's exception handler from a slice): wrap ``fn`` when a failure
must not escape (``host.run.recording.Recording`` does).

Why: with the host's frame log written inside the send, a sent frame cost p50 0.36 ms and p99
2.2 ms on the loop (JSON of the decoded frame, a line-buffered write); the MCAP recorder's chunk
compression took 4-5 ms inside one call (``bench/bench_latency.py``, a probe around the calls).
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable
from typing import Any

__all__ = ["DeferredWork"]


class DeferredWork:
    """A FIFO of calls done from the event loop in slices of ``slice_s`` (module docstring)."""

    def __init__(self, *, slice_s: float = 0.0005, max_deferred: int = 4096) -> None:
        self.slice_s = slice_s
        self.max_deferred = max_deferred
        self._noted: deque[tuple[Callable[..., Any], tuple[Any, ...]]] = deque()
        self._armed_on: asyncio.AbstractEventLoop | None = None  # the loop a slice is scheduled on

    def __len__(self) -> int:
        """Calls noted and not yet done."""
        return len(self._noted)

    def note(self, fn: Callable[..., Any], *args: Any) -> None:
        """Do ``fn(*args)`` from the loop soon, after everything noted before it."""
        self._noted.append((fn, args))
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # no loop running: at once
            self.drain()
            return
        if self._armed_on is loop:  # a slice is on its way
            if len(self._noted) >= self.max_deferred:
                self.drain()
            return
        loop.call_soon(self._slice)  # (armed on a loop that has stopped: a new one is scheduled here)
        self._armed_on = loop

    def drain(self) -> None:
        """Do every noted call now, in order."""
        noted = self._noted
        while noted:
            fn, args = noted.popleft()
            fn(*args)

    def _slice(self) -> None:
        self._armed_on = None
        noted = self._noted
        until = time.perf_counter() + self.slice_s
        while noted:
            fn, args = noted.popleft()
            try:
                fn(*args)
            except BaseException:
                if noted:  # the rest still gets done, on the next pass
                    self._rearm()
                raise
            if noted and time.perf_counter() >= until and self._rearm():
                return

    def _rearm(self) -> bool:
        """Schedule the next slice on the running loop; False when there is none (go on here)."""
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            return False
        loop.call_soon(self._slice)
        self._armed_on = loop
        return True
