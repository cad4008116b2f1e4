"""One writer thread that does a run recording's work, off the host's event loop, in the order handed over.

The event loop drives the frame grid, the heartbeats and (in lockstep) the board's ADVANCE; a call on
it that takes long holds all of them. The recording's work does not need that thread: forward
kinematics for ``/tf``, JSON for the channels, the MCAP chunks' zstd compression and, at the first
report, building the robot's scene (compiling its MJCF: 0.15-0.9 s with meshes). A profile of the
per-report work (a TELEMETRY + SIM_STATE pair and two SERVO_FRAMEs sent) on the loop: p50 0.27 ms,
p99 0.75 ms for CoCo; for an arm with ~100 000 mesh triangles the per-vertex ``/scene`` message made
that 0.25-0.3 s every 2 s, and the board's 200 ms watchdog tripped (``bench/bench_recording.py``
prints both sides: the work as it was on the loop, and what the loop pays now).

A :class:`LogWriter` owns one daemon thread and one bounded FIFO (:class:`queue.Queue`):

* :meth:`LogWriter.submit` (any thread; the loop's callbacks) puts ``(fn, args)`` without waiting:
  the call objects are handed over as they are (a ``Telemetry``, a ``SimState``, a ``Message``: frozen
  dataclasses), nothing is copied or encoded on the caller's thread;
* the thread does the calls one at a time in the order submitted (one consumer: the log's order is the
  order of submission);
* with :data:`MAX_QUEUED` calls waiting (the thread cannot keep up, or is stuck), a submit is dropped
  and counted in :attr:`LogWriter.dropped` (never blocks the caller, never grows without bound); the
  run's summary can show it;
* a call that raises is counted in :attr:`LogWriter.errors`, its first error kept in
  :attr:`LogWriter.first_error`; the thread goes on (the caller wraps calls that must stop a recording);
* :meth:`LogWriter.close` lets the thread finish what was submitted before it and waits at most
  ``timeout_s`` wall seconds for it (False when it did not finish: the thread is a daemon, it goes on
  alone and dies with the process).

The threads share the GIL. The thread's pure-Python stretches can hold the loop for up to the
interpreter's switch interval (``sys.getswitchinterval()``, 5 ms); MuJoCo's compile releases the GIL
(a 0.14 s compile of the mesh arm: the other thread's 1 ms sleeps came back within 2.8 ms); the SDK's
``log()`` does not: its encoding and chunk compression hold it for the whole call, which is why a mesh
robot's ``/scene`` (~5 MB) is written once (20-30 ms, quiet machine) and not every few seconds. Measured
with ``bench/bench_recording.py`` (a 1 ms ticker task on the loop, 10 s per mode): the loop's cost per
report p50 0.40 -> 0.04 ms, max 65 -> 0.2 ms (mesh arm), the ticker's p99 lag as with no recording.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

__all__ = ["CLOSE_TIMEOUT_S", "LogWriter", "MAX_QUEUED"]

log = logging.getLogger("host.run")

#: calls waiting for the thread beyond which a submit is dropped (a run reports at 50-100 Hz and sends
#: frames at 100 Hz: ~4 calls per report period, so this is about 10 s of backlog; each call holds a few
#: small frozen messages, a photo at most its path)
MAX_QUEUED = 4096
#: wall seconds :meth:`LogWriter.close` waits for the thread by default
CLOSE_TIMEOUT_S = 10.0

_STOP = object()


class LogWriter:
    """A FIFO of calls done on one thread (see the module docstring); start it with :meth:`start`."""

    def __init__(self, name: str = "ghostshell-recording", max_queued: int = MAX_QUEUED) -> None:
        self.name = name
        self.max_queued = max_queued
        self._queue: queue.Queue[tuple[Any, tuple[Any, ...]]] = queue.Queue(maxsize=max_queued)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._lock = threading.Lock()  # guards the counters and the idle condition
        self._idle = threading.Condition(self._lock)
        self.submitted = 0  # calls accepted
        self.done = 0  # calls the thread finished (raised or not)
        self.dropped = 0  # calls refused because MAX_QUEUED were waiting
        self.errors = 0  # calls that raised
        self.first_error: BaseException | None = None
        self.max_waiting = 0  # the longest the queue was (calls), for reports
        self._closing = False

    def start(self) -> LogWriter:
        self._thread.start()
        return self

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def submit(self, fn: Callable[..., Any], *args: Any) -> bool:
        """Do ``fn(*args)`` on the thread after everything submitted before; False (and counted in
        :attr:`dropped`) when :attr:`max_queued` calls are waiting or the writer is closing."""
        if self._closing:
            with self._lock:
                self.dropped += 1
            return False
        try:
            self._queue.put_nowait((fn, args))
        except queue.Full:
            with self._lock:
                self.dropped += 1
            return False
        with self._lock:
            self.submitted += 1
            waiting = self.submitted - self.done
            if waiting > self.max_waiting:
                self.max_waiting = waiting
        return True

    def waiting(self) -> int:
        """Calls submitted and not yet finished."""
        with self._lock:
            return self.submitted - self.done

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until every call submitted so far is done (False if ``timeout_s`` wall seconds passed first).
        For tests and for the end of a recording; never from the event loop while a run goes on."""
        with self._idle:
            target = self.submitted
            return self._idle.wait_for(lambda: self.done >= target, timeout=timeout_s)

    def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> bool:
        """Stop accepting calls, let the thread do what was submitted, and wait at most ``timeout_s`` wall
        seconds for it to end. True when it ended (or never started). Idempotent."""
        self._closing = True
        if not self._thread.is_alive():  # never started, or already ended
            return True
        try:
            self._queue.put((_STOP, ()), timeout=timeout_s)
        except queue.Full:
            return False
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _run(self) -> None:
        get = self._queue.get
        while True:
            fn, args = get()
            if fn is _STOP:
                return
            try:
                fn(*args)
            except Exception as e:  # noqa: BLE001 (counted and kept; the thread must go on)
                with self._lock:
                    self.errors += 1
                    if self.first_error is None:
                        self.first_error = e
                log.debug("recording call %r failed: %s", fn, e)
            finally:
                with self._idle:
                    self.done += 1
                    self._idle.notify_all()
