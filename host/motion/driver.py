"""The one loop that drives a :class:`~host.motion.streamer.FrameStreamer` from the board's reports.

Both a run's telemetry pump (:func:`host.run.pump.pump`) and a whole-body move outside a run
(:func:`host.motion.moves.move_to`) use it: each report is confirmed (:meth:`FrameStreamer.on_telemetry`),
handed to the caller (``on_report``: history, listeners, fault checks; it may end the drive), and then
the frames are topped up. On a realtime board :func:`realtime_topper` also tops up every period,
whatever telemetry does.

Lockstep: board time moves only as far as the frames sent reach, so *when* frames go out decides what
the board does with everything else it was sent. The rule that makes a lockstep run a function of its
input: the frames that extend board time past a report go out only after everything that report woke
has reacted (:func:`react`): every task it made ready has run until it waits again
(:func:`settle`), and no control work marked :meth:`FrameStreamer.busy` is still under way. The
horizon is the report's own board time plus the lookahead, never a wall-clock estimate.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterable, Callable, Sized

import anyio
import anyio.lowlevel
import sniffio

from host.motion.stalls import STALLS, maybe_stall
from host.motion.streamer import FrameStreamer
from protocol.messages import Telemetry

__all__ = ["SETTLE_CHECKPOINTS", "drive", "react", "realtime_topper", "settle"]

#: at most this many checkpoints :func:`settle` yields per round; on asyncio it stops as soon as no other
#: task is ready to run
SETTLE_CHECKPOINTS = 32
#: lockstep: how often :func:`react` looks whether the board answered the requests in flight (s), and
#: the longest it waits for them (s; a request's own retries give up well before)
REPLY_POLL_S = 0.001
REPLY_WAIT_S = 30.0


async def drive(streamer: FrameStreamer, reports: AsyncIterable[Telemetry], *, lockstep: bool,
                on_report: Callable[[Telemetry], bool | None],
                pending_replies: Callable[[], int] | None = None) -> Telemetry | None:
    """Telemetry -> :meth:`FrameStreamer.on_telemetry` -> ``on_report`` -> top-up, one report at a time.

    ``on_report(tel)`` runs after the streamer confirmed the report (segment and board-time waiters
    are woken, not yet run); it may raise (a fault ends the drive) or return True to stop: the drive
    then returns that report without topping up. Returns None when ``reports`` ends.

    Lockstep: the top-up is from the report's board time (µs), after :func:`react` (``pending_replies``:
    how many requests to the board await their answer, e.g. ``len(client.requests.pending)``);
    realtime: from the link's board clock estimate.
    """
    async for tel in reports:
        streamer.on_telemetry(tel)
        if on_report(tel):
            return tel
        if STALLS is not None:
            await maybe_stall("driver")
        if lockstep:
            await react(streamer, pending_replies)
            await streamer.top_up(tel.board_time_us)
        else:
            await streamer.top_up()
    return None


async def react(streamer: FrameStreamer, pending_replies: Callable[[], int] | None = None) -> None:
    """Lockstep: return once everything the last report woke has reacted: the tasks it made ready have
    run until they wait again (:func:`settle`), no :meth:`FrameStreamer.busy` work is under way, and no
    request to the board awaits its answer
    (``pending_replies() == 0``: a lockstep board answers while it waits for frames; the task that
    gets the answer goes on at once, as if the answer had been instant). Checked again after each
    wait: what ended may wake more. Only then may frames extend board time, so a segment, a request
    or a FLUSH that the report led to is in the message stream before them, however long the host
    took. A request still unanswered after ``REPLY_WAIT_S`` (its retries exhausted, or a bookkeeping
    leak) no longer holds the board."""
    waited_from: float | None = None
    while True:
        await settle()
        if streamer.reacting:
            await streamer.wait_not_busy()
            continue
        if pending_replies is None or not pending_replies():
            return
        now = anyio.current_time()
        waited_from = now if waited_from is None else waited_from
        if now - waited_from > REPLY_WAIT_S:
            return
        await anyio.sleep(REPLY_POLL_S)


async def realtime_topper(streamer: FrameStreamer) -> None:
    """Realtime: keep the frames flowing every period, whatever telemetry does (runs until cancelled)."""
    period = streamer.period_us * 1e-6
    while True:
        await streamer.top_up()
        await anyio.sleep(period)


async def settle(limit: int = SETTLE_CHECKPOINTS) -> int:
    """Yield to the event loop until no other task is ready to run, at most ``limit`` times; returns
    the checkpoints taken (>= 1).

    On asyncio "ready" is the loop's queue of callbacks due now (``loop._ready``, private: asyncio has
    no public way to ask; a task woken by an event or a finished future is queued there until it
    runs). A task blocked on I/O, a timer or a thread is not ready, and is not waited for here: control
    work that waits on those marks itself :meth:`FrameStreamer.busy` (:func:`react`). On another backend
    (Trio) all ``limit`` checkpoints are taken. Before, the pump always took 32: ~42 000 idle
    turns of the loop (an ``epoll`` each) in a 26-s lockstep run, a third of its wall time.
    """
    ready = _ready_queue()
    for n in range(1, limit + 1):
        await anyio.lowlevel.checkpoint()
        if ready is not None and not ready:
            return n
    return limit


def _ready_queue() -> Sized | None:
    """The running asyncio loop's ready queue, None on another backend (or another loop class)."""
    if sniffio.current_async_library() != "asyncio":
        return None
    ready = getattr(asyncio.get_running_loop(), "_ready", None)
    return ready if isinstance(ready, Sized) else None
