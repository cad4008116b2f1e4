"""The session's background work: telemetry pump, silence watchdog, realtime top-up, LLM chunk timing.

Everything here runs inside a :class:`~host.run.session.RobotSession`'s task group
(or wraps the chunk stream of one turn).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections import deque
from collections.abc import AsyncIterable, AsyncIterator, Callable, Sequence, Sized
from typing import Any

import anyio
import anyio.lowlevel
import numpy as np
import sniffio

from host.link import BoardClient
from host.link.errors import BoardFaulted, LinkError
from host.link.faultcheck import clear_command, servo_fault_message
from host.link.telemetry_waits import NudgeTarget
from host.robot.runtime import RobotRuntime
from host.run import artefacts
from protocol.messages import FaultFlags
from robots.motion import transition

HISTORY = 360_000  # telemetry samples kept for the plots (2 h at 50 Hz); older ones are dropped


class Recorder:
    """Bounded telemetry/ground-truth history for plots and the summary."""

    def __init__(self) -> None:
        self.t: deque[float] = deque(maxlen=HISTORY)
        self.q: deque[tuple[float, ...]] = deque(maxlen=HISTORY)
        self.base: deque[tuple[float, tuple[float, float, float], tuple[float, float, float, float]]] = deque(maxlen=HISTORY)
        self.max_tilt = 0.0
        #: the base's height (m) in the first ground-truth report: what "fell" is measured against
        self.base_z0: float | None = None
        self.last_rx = time.monotonic()  # wall time of the last report (for the silence watchdog)

    def add(self, client: BoardClient, tel: Any) -> None:
        self.t.append(tel.board_time_us * 1e-6)
        self.q.append(tel.positions)
        s = client.latest_sim_state
        if s is not None:
            self.base.append((s.board_time_us * 1e-6, s.base_pos, s.base_quat))
            if self.base_z0 is None:
                self.base_z0 = float(s.base_pos[2])
            self.max_tilt = max(self.max_tilt, artefacts.tilt_deg(s.base_quat))


#: at most this many checkpoints the lockstep pump yields before topping up, so that everything the
#: last telemetry woke (token pacing, dispatch, new segments) is placed before board time moves on;
#: on asyncio it stops as soon as no other task is ready to run (:func:`settle`)
SETTLE_CHECKPOINTS = 32
#: wall seconds without telemetry after which a run fails (the board died or the link hung)
TELEMETRY_SILENCE_S = 10.0
LOCKSTEP_NUDGE_S = 0.5  # lockstep: wall seconds without telemetry before the host ADVANCEs the board
#: wall seconds the silence watchdog may oversleep before it takes the gap as its own process not running
#: (a starved or suspended host: a User-Mode Linux guest on an overloaded machine stood still for ~10 s),
#: which is not the board's silence: the gap is not counted
STALL_S = 1.0
#: the same once the link has shown losses (decode errors, re-sent requests): a lost report, not a
#: slow board, is then the likely reason for the silence
LOSSY_NUDGE_S = 0.05
#: how long a lockstep nudge waits for the TIME_SYNC reply that says whether the board reached its
#: target (no reply in time: the target is repeated, and the next nudge asks again)
LOCKSTEP_PROBE_S = 0.5


def watchdog_fault_message(client: BoardClient, board_time_us: int) -> str:
    """The one message a run ends with when the board latched its watchdog fault."""
    hold = next((e.board_time_us for e in reversed(client.fault_events)
                 if e.raised & FaultFlags.WATCHDOG_HOLD), None)
    held = f"held from board time {hold / 1e6:.3f} s, " if hold is not None else ""
    return (f"link lost: the board heard nothing for longer than its watchdog, {held}crouched and latched its "
            f"watchdog fault (reported at board time {board_time_us / 1e6:.3f} s); the run ends here. "
            f"A board that outlives the run keeps the fault latched until cleared: `{clear_command(client.link_spec)}`")


async def pump(client: BoardClient, runtime: RobotRuntime, rec: Recorder,
               listeners: Sequence[Callable[[Any], None]] = ()) -> None:
    """Telemetry -> confirmations, top-ups and the history.

    A latched watchdog fault (the link was cut for longer than watchdog + crouch delay) ends the
    run with :class:`LinkError` and one message (:func:`watchdog_fault_message`): the board
    crouched on its own, and resuming motion after that is the user's decision, not the host's.
    A shorter cut (the board only held) resumes by itself: the next frame ends the hold.

    In lockstep each report is handled in order and the board is advanced only
    from that report's time, after the host has reacted to it, so board time
    steps with the host instead of running ahead of it.
    """
    lockstep = client.lockstep
    async for tel in client.telemetry(maxsize=1024):
        rec.last_rx = time.monotonic()
        runtime.streamer.on_telemetry(tel)
        rec.add(client, tel)
        for listener in listeners:  # e.g. the session's event monitor (host.run.events)
            listener(tel)
        if tel.faults & FaultFlags.WATCHDOG_FAULT:
            raise LinkError(watchdog_fault_message(client, tel.board_time_us))
        if tel.faults & FaultFlags.SERVO_FAULT:  # a servo stopped answering on the board's bus (C firmware)
            raise BoardFaulted(servo_fault_message(client, tel.board_time_us))
        if lockstep:
            await settle()
            await runtime.streamer.top_up(tel.board_time_us)
        else:
            await runtime.streamer.top_up()


async def settle(limit: int = SETTLE_CHECKPOINTS) -> int:
    """Yield to the event loop until no other task is ready to run, at most ``limit`` times; returns
    the checkpoints taken (>= 1).

    On asyncio "ready" is the loop's queue of callbacks due now (``loop._ready``, private: asyncio has
    no public way to ask; a task woken by an event or a finished future is queued there until it
    runs). A task blocked on I/O, a timer or a thread is not ready, and is not waited for: bytes still
    on their way (a CAN notifier thread's ``call_soon_threadsafe``) were not waited for before either
    (32 turns take well under a millisecond). On another backend (Trio) all ``limit`` checkpoints are
    taken. Before, the pump always took 32: ~42 000 idle
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


async def silence_watchdog(runtime: RobotRuntime, rec: Recorder, client: BoardClient | None = None,
                           clock: Callable[[], float] = time.monotonic) -> None:
    """Fail the run when the board stops reporting (it died, or the link hung), or when the host
    stops streaming frames to it (a stalled streamer must end the run, not hang it).

    Silence is counted only while this process runs: a gap in which the watchdog itself did not
    run (``STALL_S``) is the host's stall, not the board's silence.

    Lockstep over a lossy link: when the frame that would have let the board reach its next report
    (or that report itself) was lost, both ends wait for each other. After ``LOCKSTEP_NUDGE_S`` of
    silence (``LOSSY_NUDGE_S`` once the link has lost something) the host ADVANCEs the board one
    report period plus a tick past the end of the frames it has sent, which is where a board whose
    reports were lost stands, so one nudge brings the next report (frames due in that gap are late
    or missing, as they would be after any loss). A further nudge reaches one period further only
    once a report reached the target, or the board answers a TIME_SYNC with a time at or past it (its
    report was lost: :meth:`~host.link.telemetry_waits.TelemetryWaits.board_reached`); otherwise it
    repeats the target (:class:`~host.link.telemetry_waits.NudgeTarget`). A QEMU board starved for over
    a second on a loaded CI machine made the host re-send a FLUSH (so the link counted as lossy) and was
    pushed one period further every 50 ms meanwhile; the frames sent after the FLUSH's ACK arrived LATE.
    No timer can tell such a board from a lost report; the board's own clock can.

    ``clock``: wall seconds, the clock ``rec.last_rx`` is kept on; a caller that passes another (tests:
    a virtual one) sets ``rec.last_rx`` on it too.
    """
    sent, since = runtime.streamer.frames_sent, clock()
    # silence counts from now, not from when the Recorder was made: before the session's first report
    # the board was still starting (seconds, ~12 s inside User-Mode Linux on a loaded machine), which
    # ended every such run at the first check with "no telemetry for 10 s"
    rec.last_rx = max(rec.last_rx, since)
    lockstep = client is not None and client.lockstep
    nudged_at = 0.0
    goal = NudgeTarget()
    step = 0.02 if lockstep else 0.25
    woke = since
    while True:
        await anyio.sleep(step)
        now = clock()
        stalled = now - woke - step
        woke = now
        if stalled > STALL_S:  # this process did not run (an overloaded machine, a blocked loop): not silence
            rec.last_rx += stalled
            since += stalled
        if runtime.streamer.frames_sent != sent or runtime.streamer.held:
            sent, since = runtime.streamer.frames_sent, now
        silent = now - rec.last_rx
        if runtime.streamer.held:  # a held lockstep board is silent on purpose (waiting for the LLM)
            rec.last_rx = now
        elif silent > TELEMETRY_SILENCE_S:
            raise LinkError(f"no telemetry from the board for {TELEMETRY_SILENCE_S:g} s; giving up the run")
        elif now - since > TELEMETRY_SILENCE_S:
            streamer = runtime.streamer
            raise LinkError(f"the host sent no servo frame for {TELEMETRY_SILENCE_S:g} s "
                            f"(board clock estimate {streamer.board_now_us()} us, next frame "
                            f"{streamer.first_free_us} us, link latency p99 {streamer.link.latency_us(0) / 1000:.1f} ms, "
                            f"lead limit {streamer.max_lead_us / 1000:.0f} ms); giving up the run")
        elif client is not None and lockstep:
            lossy = client.stats.decode_errors > 0 or client.stats.retries > 0
            wait = LOSSY_NUDGE_S if lossy else LOCKSTEP_NUDGE_S
            if silent > wait and now - nudged_at > wait:
                nudged_at = now
                # move on once a report met the target, or the board says it is there (its report was
                # lost); a board that is behind (slow, or its answer is) gets the same target again
                if (goal.reached(client.board_now_estimate())
                        or await client.board_reached(goal.target, LOCKSTEP_PROBE_S)):
                    goal.raise_to(lockstep_nudge_target(client, runtime, goal.target), clock())
                with contextlib.suppress(LinkError):
                    await client.advance(goal.target)


def lockstep_nudge_target(client: BoardClient, runtime: RobotRuntime, previous: int) -> int:
    """Board time (us) a lockstep nudge ADVANCEs to: one report period and one tick past the last
    frame sent (or past the previous nudge, or the link's estimate, whichever is latest)."""
    covered = runtime.streamer.next_us - runtime.streamer.period_us
    return max(client.board_now_estimate(), covered, previous) + client.report_period_us()


async def realtime_topper(runtime: RobotRuntime) -> None:
    period = runtime.streamer.period_us * 1e-6
    while True:
        await runtime.streamer.top_up()
        await anyio.sleep(period)


async def timed_chunks(stream: AsyncIterable[str], clock: Callable[[], float], log_to: list[tuple[float, str]],
                        hold: Callable[[], contextlib.AbstractAsyncContextManager[None]] | None = None,
                        ) -> AsyncIterator[str]:
    """The LLM's chunks, each logged with its board arrival time.

    With ``hold`` (a real LLM on a lockstep board) the board clock stands still
    while the host waits for the next chunk, so network latency does not turn
    into board time.
    """
    it = stream.__aiter__()
    try:
        while True:
            try:
                if hold is None:
                    chunk = await anext(it)
                else:
                    async with hold():
                        chunk = await anext(it)
            except StopAsyncIteration:
                return
            log_to.append((clock(), chunk))
            yield chunk
    finally:  # an interrupted turn cancels the LLM stream at once (the backend drops the connection)
        aclose = getattr(it, "aclose", None)
        if aclose is not None:
            with anyio.CancelScope(shield=True):
                await aclose()


async def buffered(stream: AsyncIterable[str]) -> AsyncIterator[str]:
    """The whole response at once, after the last chunk arrived (no streaming execution)."""
    yield "".join([chunk async for chunk in stream])


class BoardPacer:
    """A sleep for the scripted LLM on the board clock, against absolute deadlines.

    Board time is observed in telemetry steps (20 ms at 50 Hz); sleeping each gap
    from "now" would round every gap up and slow the token rate, so the gaps are
    summed from the first call and each wait targets the running deadline.
    """

    def __init__(self, runtime: RobotRuntime) -> None:
        self.runtime = runtime
        self.deadline_us: int | None = None

    async def __call__(self, seconds: float) -> None:
        streamer = self.runtime.streamer
        if self.deadline_us is None:
            self.deadline_us = streamer.board_now_us()
        self.deadline_us += int(round(seconds * 1e6))
        await streamer.wait_board_time(self.deadline_us)


async def go_to_pose(runtime: RobotRuntime, pose: str) -> None:
    """Move every servo smoothly to the robot's named pose before the program starts."""
    target = np.asarray(runtime.robot.pose(pose))
    start = runtime.streamer.planned_targets()
    servos = tuple(range(len(target)))
    seg = runtime.streamer.add(transition(start, target, servos, runtime.limits), label=f"prepare:{pose}")
    await runtime.streamer.wait_ended(seg)
