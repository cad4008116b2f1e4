"""The session's background work: telemetry pump, silence watchdog, realtime top-up, LLM chunk timing.

Everything here runs inside a :class:`~host.run.robot_session.RobotSession`'s task group
(or wraps the chunk stream of one turn).
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from collections.abc import AsyncIterable, AsyncIterator, Callable, Sequence
from typing import Any

import anyio
import numpy as np

from host.link import BoardClient
from host.link.errors import LinkError
from host.link.faultcheck import DETAIL_WAIT_S, ServoFaulted, clear_command, servo_fault_named
from host.motion.driver import SETTLE_CHECKPOINTS as SETTLE_CHECKPOINTS  # re-exported (host.run.runner)
from host.motion.driver import drive
from host.motion.driver import settle as settle  # re-exported (tests)
from host.motion.driver import realtime_topper as driver_topper
from host.runtime.robot_runtime import RobotRuntime
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
        #: whether the pump is waiting for the board's next report (False while it reacts to one: the
        #: host's own time, which the silence watchdog does not count as the board's silence)
        self.waiting = True

    def add(self, client: BoardClient, tel: Any) -> None:
        self.t.append(tel.board_time_us * 1e-6)
        self.q.append(tel.positions)
        s = client.latest_sim_state
        if s is not None:
            self.base.append((s.board_time_us * 1e-6, s.base_pos, s.base_quat))
            if self.base_z0 is None:
                self.base_z0 = float(s.base_pos[2])
            self.max_tilt = max(self.max_tilt, artefacts.tilt_deg(s.base_quat))


#: wall seconds without telemetry after which a run fails (the board died or the link hung)
TELEMETRY_SILENCE_S = 10.0
#: lockstep over a link that has lost nothing: wall seconds of silence (counted from the host's last top-up,
#: while this process runs) before a lost message is assumed all the same and the pump's recovery
#: (:func:`lockstep_recover`) runs. A healthy lockstep board answers a top-up within milliseconds; the
#: host's own stalls do not count (the pump is not waiting then). Before 2026-12-07 it was 0.5 s and
#: ADVANCEd the board past the frames the host was about to send (issue 41).
LOCKSTEP_LOST_S = 2.0
#: wall seconds the silence watchdog may oversleep before it takes the gap as its own process not running
#: (a starved or suspended host: a User-Mode Linux guest on an overloaded machine stood still for ~10 s),
#: which is not the board's silence: the gap is not counted
STALL_S = 1.0
#: the same once the link has shown losses (decode errors, re-sent requests): a lost report, not a
#: slow board, is then the likely reason for the silence
LOSSY_NUDGE_S = 0.05
#: how long a lockstep recovery waits for the TIME_SYNC reply that says whether the board reached the
#: last frame sent (no reply in time: the next recovery asks again)
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
    """Telemetry -> confirmations, top-ups and the history, through :func:`host.motion.driver.drive`.

    A latched watchdog fault (the link was cut for longer than watchdog + crouch delay) ends the
    run with :class:`LinkError` and one message (:func:`watchdog_fault_message`): the board
    crouched on its own, and resuming motion after that is the user's decision, not the host's.
    A shorter cut (the board only held) resumes by itself: the next frame ends the hold.

    In lockstep each report is handled in order and the board is advanced only
    from that report's time, after everything the report woke has reacted
    (:func:`host.motion.driver.react`), so board time steps with the host instead of running ahead
    of it. ``rec.waiting`` is False from a report's arrival until its top-up went out: the silence
    watchdog counts only the time the host waited for the board (a host stalled in its reaction is
    not a silent board).
    """

    fault_seen: list[tuple[float, int]] = []  # when (wall s, board us) the SERVO_FAULT flag was first seen

    def on_report(tel: Any) -> bool:
        rec.last_rx, rec.waiting = time.monotonic(), False
        rec.add(client, tel)
        for listener in listeners:  # e.g. the session's event monitor (host.run.events)
            listener(tel)
        if tel.faults & FaultFlags.WATCHDOG_FAULT:
            raise LinkError(watchdog_fault_message(client, tel.board_time_us))
        if tel.faults & FaultFlags.SERVO_FAULT:  # a servo on the board's bus failed
            # the report may overtake the NACK that names the servo: wait for it a little (the frames the
            # run keeps sending are refused naming it too); the flag alone names no servo and no cause
            if not fault_seen:
                fault_seen.append((time.monotonic(), tel.board_time_us))
            if servo_fault_named(client) or time.monotonic() - fault_seen[0][0] >= DETAIL_WAIT_S:
                raise ServoFaulted(client, fault_seen[0][1])
        return False

    streamer = runtime.streamer
    reports = _stamped(client.telemetry(maxsize=1024), rec)
    await drive(streamer, reports, lockstep=client.lockstep, on_report=on_report,
                pending_replies=lambda: len(client.requests.pending))


async def _stamped(reports: AsyncIterator[Any], rec: Recorder) -> AsyncIterator[Any]:
    """``reports``; when the consumer asks for the next one (its top-up is out), the pump waits for the
    board again: ``rec.waiting`` is set and ``rec.last_rx`` restarts the silence from now."""
    async for tel in reports:
        rec.waiting = False
        yield tel
        rec.last_rx, rec.waiting = time.monotonic(), True


async def silence_watchdog(runtime: RobotRuntime, rec: Recorder, client: BoardClient | None = None,
                           clock: Callable[[], float] = time.monotonic) -> None:
    """Fail the run when the board stops reporting (it died, or the link hung), or when the host
    stops streaming frames to it (a stalled streamer must end the run, not hang it).

    Silence is counted only while this process runs: a gap in which the watchdog itself did not
    run (``STALL_S``) is the host's stall, not the board's silence.

    Lockstep: a healthy lockstep run sends nothing on wall-clock time (what the host sends, and at
    which board time it arrives, must depend only on the host's input and the board's reports).
    Silence is evidence of a lost message only once the link has lost something (decode errors,
    re-sent requests: after ``LOSSY_NUDGE_S``) or after ``LOCKSTEP_LOST_S``, counted only while the pump
    waits for the board (``rec.waiting``: not while it reacts to a report, however long a stall of the
    host makes that); then :func:`lockstep_recover` lets the board reach the last frame sent, and sends
    more frames once it is there, never an ADVANCE past a frame the host has not sent. (Before, a
    nudge after 0.5 s of wall silence ADVANCEd one report period past the last frame sent: a host
    stalled ~1 s on mesh work had the board run past the frames due next, with a stale target.)

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
        # held (waiting for the LLM), busy, or (lockstep) waiting for the board's answer to a request, which
        # the driver waits for before it tops up: silent on purpose
        streamer = runtime.streamer
        reacting = (streamer.held or streamer.reacting
                    or (lockstep and client is not None and bool(client.requests.pending)))
        if runtime.streamer.frames_sent != sent or reacting:
            sent, since = runtime.streamer.frames_sent, now
        silent = now - rec.last_rx
        if reacting or not rec.waiting:  # a held lockstep board, or one waiting for the host's reaction
            rec.last_rx = now  # (the pump handling a report, however long: the host's time) is silent on purpose
        elif silent > TELEMETRY_SILENCE_S:
            raise LinkError(f"no telemetry from the board for {TELEMETRY_SILENCE_S:g} s; giving up the run")
        elif now - since > TELEMETRY_SILENCE_S:
            raise LinkError(f"the host sent no servo frame for {TELEMETRY_SILENCE_S:g} s "
                            f"(board clock estimate {streamer.board_now_us()} us, next frame "
                            f"{streamer.first_free_us} us, link latency p99 {streamer.link.latency_us(0) / 1000:.1f} ms, "
                            f"lead limit {streamer.max_lead_us / 1000:.0f} ms); giving up the run")
        elif client is not None and lockstep:
            lossy = client.link_lossy()
            wait = LOSSY_NUDGE_S if lossy else LOCKSTEP_LOST_S
            if silent > wait and now - nudged_at > wait:
                nudged_at = now
                with contextlib.suppress(LinkError):
                    await lockstep_recover(client, runtime)


async def lockstep_recover(client: BoardClient, runtime: RobotRuntime) -> int:
    """A silent lockstep board after a loss: let it reach the last frame sent, or, once it is there (its
    reports, or the frames that would have brought them, were lost), send the frames of one lookahead
    from there. Board time never passes a frame the host has not sent. Returns the board time (µs) the
    board was let run to (an ADVANCE to the tick after the last frame sent, a lost frame's gap
    included) or topped up from.

    Whether the board is there is known from its reports or asked with one TIME_SYNC
    (:meth:`~host.link.telemetry_waits.TelemetryWaits.board_reached`, waiting up to ``LOCKSTEP_PROBE_S``).
    """
    streamer = runtime.streamer
    last = streamer.next_us - streamer.period_us  # the last frame sent
    if await client.board_reached(last, LOCKSTEP_PROBE_S):
        await streamer.top_up(last)
    else:
        await client.advance(last + 1)  # ticks up to and including the last frame's run, lost frames or not
    return last


async def realtime_topper(runtime: RobotRuntime) -> None:
    """Realtime: top up every frame period (:func:`host.motion.driver.realtime_topper`)."""
    await driver_topper(runtime.streamer)


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
