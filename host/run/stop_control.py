"""A session's stop: its first reason, its deadline, and the work that deadline cuts.

:class:`StopControl` is the state machine behind :meth:`host.run.robot_session.RobotSession.request_stop`:
the first :class:`~host.run.stops.StopReason` is kept and starts a deadline of ``grace_s`` wall
seconds (``SessionOptions.stop_grace_s``); each piece of the session's work runs inside
:meth:`StopControl.work` (named by its phase, which the no-progress guard shows), and at the
deadline the work still running is cut (its cleanups aborted first) and :attr:`StopControl.overdue`
is set, so later waits are cut at once. A stop while the session is still starting (``up`` False)
cuts the start-pose move at once. :func:`session_guard` builds the session's no-progress guard
(:mod:`host.run.progress_guard`) over board time, frames and calls.

Nothing here knows the link or the robot: the session hands in getters (the shell) and callbacks
(interrupt, abort cleanups, a task group to run the deadline in).
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

import anyio
import anyio.abc

from host.run.progress_guard import ProgressGuard, Stall
from host.run.stops import StopReason

if TYPE_CHECKING:
    from host.runtime.robot_runtime import RobotRuntime
    from host.shell import Shell

log = logging.getLogger("host.run")

__all__ = ["StopControl", "session_guard"]


class StopControl:
    """One session's stop (see the module docstring).

    ``interrupt()`` interrupts the running turn gracefully (through the shell's lifecycle tree), or
    returns False when no turn runs; ``abort_cleanups()`` cuts the resets still running."""

    def __init__(self, grace_s: float, interrupt: Callable[[], object], abort_cleanups: Callable[[], None]) -> None:
        self.grace_s = grace_s
        self._interrupt, self._abort_cleanups = interrupt, abort_cleanups
        #: why the session stops early (a signal, a bound, a stall), once :meth:`request` was called
        self.reason: StopReason | None = None
        #: the stop's deadline passed: what remains of the graceful stop is cut or skipped
        self.overdue = False
        #: the session finished starting (the start pose reached or cut)
        self.up = False
        #: what the session's work is doing now, for the progress guard (None: nothing to guard)
        self.phase: str | None = None
        self._work_scope: anyio.CancelScope | None = None  # the work the deadline cuts
        self._wall: float | None = None  # time.monotonic() of the first stop
        self._deadline_scope: anyio.CancelScope | None = None  # the running deadline's

    def request(self, stop: StopReason, tg: anyio.abc.TaskGroup | None) -> bool:
        """Keep the first reason and start its deadline in ``tg``; interrupt the running turn. Returns
        False while the session is still starting (the start-pose move is cut at once), else True."""
        if self.reason is None:
            self.reason = stop
            self._wall = time.monotonic()
            if tg is not None:
                tg.start_soon(self._deadline)
        if not self.up:
            if self._work_scope is not None:
                self._work_scope.cancel()
            return False
        self._interrupt()
        return True

    def left_s(self) -> float:
        """Wall seconds left until the stop's deadline (``inf`` while no stop was requested, 0 once it passed)."""
        if self._wall is None:
            return math.inf
        return max(0.0, self.grace_s - (time.monotonic() - self._wall))

    async def _deadline(self) -> None:
        """At the deadline, cut what still runs (its cleanups aborted first); :meth:`clear` cancels it."""
        with anyio.CancelScope() as scope:
            self._deadline_scope = scope
            await anyio.sleep(self.left_s())
        if scope.cancel_called:
            return
        self._deadline_scope = None
        self.overdue = True
        if self._work_scope is not None:
            log.warning("the stop did not end the work within %g s (%s): cutting it", self.grace_s,
                        self.phase or "ending")
            self._abort_cleanups()
            self._work_scope.cancel()

    @contextlib.contextmanager
    def work(self, phase: str) -> Iterator[anyio.CancelScope]:
        """The scope of one piece of the session's work (``phase`` names it for the progress guard) that
        the deadline cuts; cut at once when the deadline has passed or a stop came while starting."""
        with anyio.CancelScope() as scope:
            self._work_scope, self.phase = scope, phase
            if self.overdue or (self.reason is not None and not self.up):
                scope.cancel()
            try:
                yield scope
            finally:
                self._work_scope, self.phase = None, None

    def clear(self) -> bool:
        """Forget the stop and cancel its deadline; returns True when the deadline had passed (its
        cleanups were aborted: the caller re-arms them)."""
        was_overdue = self.overdue
        self.reason, self._wall, self.overdue = None, None, False
        if self._deadline_scope is not None:
            self._deadline_scope.cancel()
            self._deadline_scope = None
        return was_overdue


def session_guard(limit_s: float, stops: StopControl, request_stop: Callable[[StopReason], object],
                  board_time: Callable[[], float | None], frames: Callable[[], int],
                  shell: Callable[[], Shell | None], runtime: Callable[[], RobotRuntime | None]) -> ProgressGuard:
    """The no-progress guard of a session (:mod:`host.run.progress_guard`): board time (s), frames sent
    and the running turn's calls must move within ``limit_s`` while work runs (``stops.phase``); a stall
    calls ``request_stop`` with ``stall/no_progress`` and the guard's one line."""

    def call_states() -> tuple[int, int, int]:
        """(calls, started, ended) of the running turn (zeros when none runs)."""
        sh = shell()
        tl = sh.timeline if sh is not None else None
        if tl is None:
            return (0, 0, 0)
        records = list(tl)
        return (len(records), sum(r.start is not None for r in records), sum(r.end is not None for r in records))

    def waiting_for() -> str:
        """What the session's work waits for now, for the stall's one line."""
        rt, sh = runtime(), shell()
        if rt is not None and rt.streamer.held:
            return "the LLM's next chunk (the board held still)"
        tl = sh.timeline if sh is not None else None
        if tl is not None:
            running = [r.path for r in tl if r.start is not None and r.end is None]
            queued = [r.path for r in tl if r.start is None and r.end is None]
            if running or queued:
                shown = ", ".join(running[:3]) + (" ..." if len(running) > 3 else "")
                return (f"{len(running)} running call(s) to end ({shown})" if running
                        else f"{len(queued)} queued call(s) to start")
        if rt is not None:
            return f"board time and the motion's end (next frame at board time {rt.streamer.first_free_us / 1e6:.3f} s)"
        return "the board"

    def on_stall(stall: Stall) -> None:
        log.warning("%s", stall.message)
        request_stop(StopReason("stall", "no_progress", stall.message))

    return ProgressGuard({"board time": board_time, "frames sent": frames, "calls started/ended": call_states},
                         lambda: stops.phase, waiting_for, on_stall, limit_s=limit_s)
