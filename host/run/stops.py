"""Why a session stops before its work is done: a signal (Ctrl-C, SIGTERM) or a bound it reached.

**Signals** (:class:`StopSignals`, used by ``run``, ``demo`` and ``chat``): the first SIGINT or
SIGTERM is an *interruption*, not an abort: the session's running turn is cancelled through the
shell's lifecycle tree (:meth:`host.shell.Shell.interrupt`, exactly as an external interruption:
moving channels FLUSHed and stopped smoothly, active parents reset), the robot is moved smoothly
to its rest pose (:meth:`host.run.robot_session.RobotSession.go_to_rest`), and every artefact of what ran
is written (summary.json with outcome ``interrupted``, timeline, plots, frame logs); the command
prints one line and exits 130. A second signal exits at once: the work is cancelled, summary.json
and timeline.json of what ran are written (no plots, no rest pose), the emulated board is stopped,
exit 130. A signal while the session is still starting (no turn yet to interrupt) is that second
kind at once, and said so: "interrupted by SIGINT (Ctrl-C) while starting: stopped at once" (one
signal, not two; ``while_starting`` in ``summary.json``'s ``extra.stopped``). ``run``'s guard
also covers the writing of a finished turn's artefacts, which always finishes (a second signal
waits for it too); a signal there exits 130 and the line says the turn had already ended. Signals are taken with AnyIO's :func:`anyio.open_signal_receiver` (the main thread
of the event loop), so they never arrive as a ``KeyboardInterrupt`` in the middle of a task.

The emulated board does not see the terminal's Ctrl-C at all: the host starts it in its own
process group (:func:`host.link.board_process.start_board`), so the host owns the shutdown and the
link never looks "lost" because of the user's Ctrl-C.

**Bounds** (``--max-board-s``, ``--max-log-mb``, :class:`host.run.robot_session.SessionOptions`): a turn
that reaches its board-time bound, or a session whose frame logs reach their size bound, is stopped
the same way as by a first signal (interrupted through the lifecycle tree, rest pose, artefacts),
with outcome ``limit`` and the reason in ``summary.json`` (``extra.stopped``); the command exits 1.
A session whose work makes no progress for :data:`host.run.progress_guard.PROGRESS_LIMIT_S` wall
seconds is stopped the same way with outcome ``stalled`` (kind ``"stall"``), exit 1.

**Deadline** (:data:`STOP_GRACE_S`): whatever stopped it, a session's graceful stop (the turn's end,
the settle, the rest pose) has that many wall seconds from the first stop; what is still running then
is cut (the rest pose is skipped or cut), so the first signal ends a run within ``STOP_GRACE_S`` plus
the teardown (:meth:`host.run.robot_session.RobotSession.request_stop`), whatever the link's speed.
"""

from __future__ import annotations

import asyncio.events
import signal
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from dataclasses import dataclass
from types import FrameType

import anyio
import anyio.abc
import anyio.lowlevel

__all__ = ["DEFAULT_MAX_BOARD_S", "DEFAULT_MAX_LOG_MB", "STOP_GRACE_S", "Interrupted", "StopReason", "StopSignals",
           "signal_stop"]

#: Board seconds one turn (one ``run``, one chat step) may last: a paper task takes at most ~30 s;
#: a reply that would speak or move for longer is cut here (lockstep reaches it in seconds).
DEFAULT_MAX_BOARD_S = 120.0
#: Megabytes the session's frame logs (host and board, both directions) may reach: 50 Hz telemetry
#: and 100 Hz servo frames log ~0.2 MB per board second, so ~40 minutes of a session.
DEFAULT_MAX_LOG_MB = 500.0
#: Wall seconds a session's graceful stop may take from its first stop (a signal, a bound, a stall) until
#: the running turn, its settle and the rest-pose move are cut short (the rest pose gets what is left of
#: it, at most its own 10 s). The link's close (<= 5 s) and the board's stop (<= 5 s, usually < 0.1 s)
#: come after: a first Ctrl-C ends ``ghostshell run`` within ~8 s on a working link, 18 s at worst.
STOP_GRACE_S = 8.0


#: event-loop passes the guard gives a signal that arrived as its body ended: asyncio reads the wakeup
#: pipe in one pass, runs the signal's callback in the next and AnyIO's receiver wakes the watcher in the
#: one after, so 3 are needed (20 of 20 taken with 3, none with 2; tests/run/test_stops_drain.py); 6 to spare
DRAIN_PASSES = 6


def _is_asyncio_runner_handler(handler: object) -> bool:
    """True for the SIGINT handler :class:`asyncio.Runner` installs (a partial of ``Runner._on_sigint``)."""
    func = getattr(handler, "func", None)
    return getattr(func, "__name__", "") == "_on_sigint" and "asyncio" in getattr(func, "__module__", "")


@dataclass(frozen=True)
class StopReason:
    """Why the session stopped early.

    ``kind``: ``"signal"`` (outcome ``interrupted``, exit 130), ``"limit"`` (outcome ``limit``,
    exit 1) or ``"stall"`` (no progress, :mod:`host.run.progress_guard`: outcome ``stalled``, exit 1);
    ``name``: the signal (``"SIGINT"``, ``"SIGTERM"``), the bound (``"max_board_s"``, ``"max_log_mb"``)
    or ``"no_progress"``; ``message``: one line for the user and ``summary.json``.
    """

    kind: str
    name: str
    message: str

    @property
    def outcome(self) -> str:
        return {"signal": "interrupted", "stall": "stalled"}.get(self.kind, "limit")

    @property
    def exit_status(self) -> int:
        return 130 if self.kind == "signal" else 1

    def as_dict(self) -> dict[str, str]:
        return {"by": self.name, "kind": self.kind, "message": self.message}


def signal_stop(signum: int) -> StopReason:
    """The stop a signal asks for."""
    name = signal.Signals(signum).name
    how = "Ctrl-C" if signum == signal.SIGINT else name
    return StopReason("signal", name, f"interrupted by {name} ({how})" if how != name else f"interrupted by {name}")


class Interrupted(Exception):
    """Raised out of a command's work that a signal cancelled at once (a second signal, or one that
    came while the session was still starting: ``while_starting``). ``stop`` is the first signal's
    reason, ``forced_by`` the name of the signal that stopped the work at once (the same signal when
    ``while_starting``); :attr:`how` is what happened, for the user's one line."""

    def __init__(self, stop: StopReason, forced_by: str, while_starting: bool = False) -> None:
        self.stop = stop
        self.forced_by = forced_by
        self.while_starting = while_starting
        super().__init__(self.how)

    @property
    def how(self) -> str:
        """``"interrupted by SIGINT (Ctrl-C) while starting: stopped at once"`` or
        ``"interrupted by SIGINT (Ctrl-C), then SIGTERM again: stopped at once"``."""
        if self.while_starting:
            return f"{self.stop.message} while starting: stopped at once"
        return f"{self.stop.message}, then {self.forced_by} again: stopped at once"

    def stopped_extra(self) -> dict[str, object]:
        """``summary.json``'s ``extra.stopped`` (without ``rest_pose``)."""
        extra: dict[str, object] = {**self.stop.as_dict(), "forced_by": self.forced_by}
        if self.while_starting:
            extra["while_starting"] = True
        return extra


class StopSignals:
    """SIGINT/SIGTERM handling for one command (see the module docstring).

    ``on_first(stop) -> bool`` is called with the first signal; it returns True when it took the
    graceful road (a turn will end interrupted), False when there is nothing to interrupt yet, and
    the guarded work is then cancelled at once. A second signal always cancels it at once. After
    :meth:`guard` exits, ``first`` is the first signal's :class:`StopReason` (or None),
    ``forced`` the name of the signal that cancelled the work (or None) and ``while_starting``
    whether that was the first signal itself (nothing to interrupt yet); :meth:`interrupted` is the
    :class:`Interrupted` that describes a forced stop.
    """

    def __init__(self, on_first: Callable[[StopReason], bool], on_forced: Callable[[], None] | None = None) -> None:
        self.on_first = on_first
        #: called when a signal forces the stop, as the body is cancelled (e.g. the session's
        #: ``abort_cleanups``: shielded cleanups would otherwise outlive the cancellation)
        self.on_forced = on_forced
        self.first: StopReason | None = None
        self.forced: str | None = None
        self.while_starting = False
        #: a SIGINT after the guard, before the command returned (see :meth:`_late_sigint`)
        self.late: StopReason | None = None
        self._body: anyio.CancelScope | None = None

    def reported(self, stop: StopReason | None) -> StopReason | None:
        """The stop a command reports, given its session's first reason ``stop``: that one, unless it was
        a bound (or none) and a signal came as well, during the guarded work (``first``) or after it
        (``late``): the user interrupted, so the command exits 130."""
        for signalled in (self.first, self.late):
            if signalled is not None and (stop is None or stop.kind != "signal"):
                return signalled
        return stop

    def interrupted(self) -> Interrupted:
        """The forced stop as an :class:`Interrupted` (call only when ``forced`` is set)."""
        assert self.forced is not None
        stop = self.first or StopReason("signal", self.forced, f"interrupted by {self.forced}")
        return Interrupted(stop, self.forced, self.while_starting)

    async def _watch(self, *, task_status: anyio.abc.TaskStatus[None] = anyio.TASK_STATUS_IGNORED) -> None:
        # asyncio resets a handler it removes to the default (SIGTERM: terminate at once), not to the one
        # before it: put those back, so a signal after the guarded work (e.g. while a video renders) is
        # handled as the command handles it elsewhere
        previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            with anyio.open_signal_receiver(signal.SIGINT, signal.SIGTERM) as signals:
                task_status.started()
                async for signum in signals:
                    stop = signal_stop(signum)
                    if self.first is None:
                        self.first = stop
                        if self.on_first(stop):
                            continue
                        self.while_starting = True
                    self.forced = stop.name
                    if self._body is not None:
                        self._body.cancel()
                    if self.on_forced is not None:
                        self.on_forced()
        finally:
            for sig, handler in previous.items():
                if sig == signal.SIGINT and _is_asyncio_runner_handler(handler):
                    handler = self._late_sigint
                signal.signal(sig, handler if handler is not None else signal.SIG_DFL)

    def _late_sigint(self, signum: int, frame: FrameType | None) -> None:
        """SIGINT after the guard, while the command finishes inside the event loop. asyncio's runner
        would cancel the main task, and a task with no await left returns as if nothing came: the
        signal was lost (status 0). The first is recorded in ``late`` for the command to report; a
        second, or one once the event loop has returned (the command reads ``late`` no more), raises
        KeyboardInterrupt, as Python's own handler does."""
        if self.late is None and asyncio.events._get_running_loop() is not None:
            self.late = signal_stop(signum)
            return
        raise KeyboardInterrupt

    @asynccontextmanager
    async def guard(self) -> AsyncIterator[StopSignals]:
        """Watch for signals while the body runs; a forced stop cancels the body (and is swallowed
        here: check ``forced`` afterwards)."""
        try:
            async with anyio.create_task_group() as tg:
                await tg.start(self._watch)  # the handlers are installed before the body runs
                try:
                    with anyio.CancelScope() as body:
                        self._body = body
                        yield self
                finally:
                    self._body = None
                    # a signal that came while the body ended in blocking work (stopping the board: a
                    # SIGTERM and a wait) is in the loop's wakeup pipe, not yet with the watcher: let the
                    # loop hand it over (read the pipe, run the handler, wake the watcher) before the
                    # watcher goes, or it was lost (status 0, no word)
                    with anyio.CancelScope(shield=True):
                        for _ in range(DRAIN_PASSES):
                            await anyio.lowlevel.checkpoint()
                    tg.cancel_scope.cancel()
        except BaseExceptionGroup as group:  # the body's own error, not a group: the watcher never fails
            if len(group.exceptions) == 1 and not isinstance(group.exceptions[0], BaseExceptionGroup):
                raise group.exceptions[0] from None
            raise
