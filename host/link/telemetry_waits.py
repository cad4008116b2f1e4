"""Telemetry views and waits of the session: ``latest_telemetry``, fault bits and edges, ``wait_for`` (with
the lockstep nudge), ``next_telemetry``, ``telemetry()``.

:class:`TelemetryWaits` is a part of :class:`host.link.client.BoardClient`: it reads the
:class:`host.link.telemetry.TelemetryFanout` it is given (``fanout``) and the board clock
(:class:`host.link.board_time.BoardClock`) and, for a lockstep board whose clock only runs when the
host ADVANCEs it, sends ADVANCE through the session, which it holds as :class:`WaitLink`. Waiting is
anyio (:meth:`host.link.waiting.Reply.wait`, a deadline on :func:`anyio.current_time`).
"""

from __future__ import annotations

import contextlib
from collections import deque
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Protocol

import anyio

from host.link.board_time import BoardClock
from host.link.errors import LinkError, LinkTimeout
from host.link.receive import LinkStats
from host.link.telemetry import TelemetryFanout, flag_names
from protocol.messages import Advance, Caps, Message, Telemetry

__all__ = ["NudgeTarget", "TelemetryWaits", "WaitLink"]


class NudgeTarget:
    """The board time (µs) a lockstep nudge ADVANCEs to, held until it may move on.

    A lockstep board reports only while its clock runs; a nudge ADVANCEs a silent one a report period
    further. Moving the target on every nudge pushes a board that is merely slow past the frames the
    host sends next, and the board refuses those as LATE: so the target moves on (:meth:`raise_to`)
    only once it was :meth:`reached` (a report met it; the run's silence watchdog,
    :func:`host.run.pump.silence_watchdog`, also asks the board's clock:
    :meth:`TelemetryWaits.board_reached`) or, in :meth:`TelemetryWaits.wait_for`, once :meth:`due`
    (no report for a while), and is otherwise repeated (a lost ADVANCE costs nothing more). Times are
    wall seconds on the caller's one clock."""

    def __init__(self) -> None:
        #: the board time (us) ADVANCEd to; 0 before the first nudge
        self.target = 0
        #: when (wall s) the target was last moved
        self.raised_at = 0.0

    def reached(self, seen_us: int) -> bool:
        """Whether the target may move on because it was met: no target yet, or the board time known now
        (``seen_us``, µs) is at or past it."""
        return self.target == 0 or seen_us >= self.target

    def due(self, seen_us: int, now: float, raise_after_s: float) -> bool:
        """Whether the target may move on: :meth:`reached`, or no report came for ``raise_after_s``
        (taken as lost; :meth:`TelemetryWaits.nudge_raise_s`)."""
        return self.reached(seen_us) or now - self.raised_at >= raise_after_s

    def raise_to(self, target_us: int, now: float) -> int:
        """Move the target to ``target_us`` (never back) at ``now``; returns the target."""
        self.target, self.raised_at = max(self.target, int(target_us)), now
        return self.target


class WaitLink(Protocol):
    """What the telemetry waits need of the session: the board's CAPS (report and tick rates), the
    loss counters, and a send that works before the handshake completed (a nudge's ADVANCE)."""

    @property
    def caps(self) -> Caps | None: ...
    @property
    def stats(self) -> LinkStats: ...
    def transmit(self, msg: Message) -> int: ...


class TelemetryWaits:
    """Waits on the telemetry listener ``fanout`` and the board clock ``clock``; ``sync_once(timeout)`` is
    one TIME_SYNC exchange (:meth:`host.link.supervisor.Supervisor.sync_once`)."""

    def __init__(self, link: WaitLink, fanout: TelemetryFanout, clock: BoardClock,
                 sync_once: Callable[[float], Awaitable[object]]) -> None:
        self.link, self.fanout, self.clock = link, fanout, clock
        self._sync_once = sync_once
        #: the latest 16 report latencies (s) :meth:`nudge_raise_s` works from (emptied on every handshake)
        self.report_latencies: deque[float] = deque(maxlen=16)

    #: wall seconds between the ADVANCEs of :meth:`wait_for` with ``nudge`` (a lockstep board answers in ~1 ms)
    NUDGE_S = 0.1
    #: the longest a nudge waits for a report before it moves its ADVANCE target further (a report lost
    #: on a lossy link); until then it repeats the target (it was pushed 5 periods ahead of a slow QEMU
    #: board in 0.5 s, whose next frames then arrived LATE). The wait itself is :meth:`nudge_raise_s`.
    NUDGE_RAISE_S = 1.0
    #: a nudge's target is raised after this many times the slowest recent report (see nudge_raise_s)
    NUDGE_RAISE_FACTOR = 4

    def restart(self, caps: Caps) -> None:
        """A handshake completed: the latencies of :meth:`nudge_raise_s` are measured anew (``caps`` unused)."""
        self.report_latencies.clear()

    def nudge_raise_s(self) -> float:
        """Wall seconds a nudge waits for the report its ADVANCE asked for before it takes the report as
        lost and moves the target on: ``NUDGE_RAISE_FACTOR`` × the slowest of the last 16 such reports
        (from the ADVANCE to a target to the report that met it, when that report can only have come
        from that ADVANCE and the previous target's report was lost, not late: see :meth:`wait_for`; the
        slowest, so a report already on its way does not lower it), between ``2 × NUDGE_S``
        and ``NUDGE_RAISE_S``; ``NUDGE_RAISE_S`` before any was measured. A native board reports in
        ~2 ms, so a lost report costs 0.2 s instead of 1 s; a slow board (QEMU) keeps up to 1 s."""
        lat = self.report_latencies
        if not lat:
            return self.NUDGE_RAISE_S
        return min(self.NUDGE_RAISE_S, max(2 * self.NUDGE_S, self.NUDGE_RAISE_FACTOR * max(lat)))

    #: lockstep, a link that has lost nothing: wall seconds :meth:`wait_for` waits for the report its
    #: ADVANCE asked for before it takes the ADVANCE or the report as lost all the same and repeats it
    #: (or moves the target on). A healthy board answers in milliseconds; a repeat is one more message
    #: in the board's stream, sent at a wall-clock moment, so it is kept for real silence.
    QUIET_LOST_S = 2.0

    def link_lossy(self) -> bool:
        """Whether the link has shown a loss: a frame that failed to decode, or a request re-sent for want
        of its ACK. Lockstep nudges (:meth:`wait_for`, :func:`host.run.pump.silence_watchdog`) act on
        wall-clock silence quickly only then."""
        stats = self.link.stats
        return stats.decode_errors > 0 or stats.retries > 0

    def _report_latency(self, seconds: float) -> None:
        self.report_latencies.append(max(0.0, seconds))

    async def board_reached(self, t_us: int, timeout: float) -> bool:
        """Whether the board's clock has reached ``t_us`` (board µs): known from its reports, or else asked
        with one TIME_SYNC, whose reply carries the board time it was sent at (a lockstep board's too:
        an ADVANCE target's report that was lost, not late, shows as a board already there). False
        when the board is behind, or when no reply came within ``timeout`` s (a slow board, or a lost
        message: ask again later)."""
        if self.clock.board_now_estimate() >= t_us:
            return True
        with contextlib.suppress(LinkError):  # LinkTimeout or LinkDown: not known to be there
            await self._sync_once(timeout)
        return self.clock.board_now_estimate() >= t_us

    async def telemetry(self, maxsize: int | None = None) -> AsyncIterator[Telemetry]:
        """Every telemetry report from now on; a slow consumer loses the oldest (bounded stream)."""
        async for t in self.fanout.subscribe(maxsize):
            yield t

    async def wait_for(self, predicate: Callable[[Telemetry], bool], timeout: float, *, nudge: bool = False) -> Telemetry:
        """The first telemetry (latest included) satisfying ``predicate``; :class:`LinkTimeout` after ``timeout`` s.

        ``nudge`` (lockstep boards; ignored in realtime): a lockstep board only reports while its
        clock runs, so ADVANCE it one report period past the latest board time known. On a link that
        has lost something (:meth:`link_lossy`: a lost ADVANCE or a lost report, likely on a lossy CAN
        link, where a report is 17 frames) the ADVANCE is repeated every :attr:`NUDGE_S` s while no
        report satisfies ``predicate``; the target repeats until a report reaches it or
        :meth:`nudge_raise_s` passes, so a slow board is not pushed ahead. On a link that has lost
        nothing, the message stream must not depend on wall time (a lockstep run is a function of its
        input): the target moves on only once a report from it came (later than the board time it was
        set from), and a repeat comes only after :attr:`QUIET_LOST_S` without one. The ADVANCEs are not awaited: the report is the
        acknowledgement that matters.
        """
        t = self.fanout.latest
        if t is not None and predicate(t):
            return t
        nudging = nudge and self.clock.lockstep
        goal = NudgeTarget()
        raised_from = 0  # the board time seen when the target was set
        # A report later than both raised_from and this wait's previous target (``floor``) can only have
        # come from the ADVANCE to the current one (the board runs no further than it was told): its
        # wait is a report latency. Before, only the first target's report counted, so on a lossy link
        # (CAN's 17-frame report: ~58 % lost at drop=0.05) the 1-s default lasted for several reports.
        # Not when the previous target's report came after all (``late``: it was slow, not lost): the
        # board was busy since that ADVANCE, so the wait from the raise would understate its latency.
        floor = 0
        late = False
        sent_at = 0.0  # when (anyio time) the last ADVANCE went out

        def watch(t: Telemetry) -> bool:
            nonlocal late
            if floor and raised_from < t.board_time_us <= floor:
                late = True
            return predicate(t)

        fut = self.fanout.waiter(watch if nudging else predicate)
        deadline = anyio.current_time() + timeout
        try:
            while True:
                if nudging:
                    now = anyio.current_time()
                    seen = self.clock.board_now_estimate()
                    lossy = self.link_lossy()
                    quiet = now - sent_at >= self.QUIET_LOST_S
                    # healthy link: a report from the current target (later than the time it was set from)
                    # is the evidence that the board ran to it
                    moved_on = seen > raised_from or quiet
                    if goal.reached(seen) or (goal.due(seen, now, self.nudge_raise_s()) if lossy else moved_on):
                        # first nudge; a report reached the target without satisfying the predicate; or
                        # none for nudge_raise_s() (lost): move the target one report period on. Otherwise the same
                        # target again (a lost ADVANCE): a slow board (QEMU on a loaded machine) must
                        # not be pushed ahead of the frames the host is about to time from its report
                        floor, late = goal.target, False
                        goal.raise_to(max(goal.target, seen) + self.report_period_us(), now)
                        raised_from = seen
                        resend = True
                    else:
                        resend = lossy or quiet
                    if resend:
                        sent_at = now
                        with contextlib.suppress(LinkError):
                            self.link.transmit(Advance(goal.target))
                left = deadline - anyio.current_time()
                if left <= 0:
                    break
                if await fut.wait(min(left, self.NUDGE_S) if nudging else left):
                    got = fut.result()
                    if nudging and not late and got.board_time_us > max(raised_from, floor):  # the current target's
                        self._report_latency(anyio.current_time() - goal.raised_at)
                    return got
                if not nudging:
                    break
            last = self.fanout.latest
            where = (f"; last telemetry at board time {last.board_time_us / 1e6:.3f} s, faults {flag_names(last.faults)}"
                     if last else "; no telemetry received")
            raise LinkTimeout(f"telemetry condition not met within {timeout} s{where}")
        finally:
            fut.cancel()
            self.fanout.forget(fut)

    def report_period_us(self) -> int:
        """One telemetry period plus one control tick (us): an ADVANCE this far always yields a report."""
        caps = self.link.caps
        rate = caps.telemetry_rate_hz if caps is not None and caps.telemetry_rate_hz > 0 else 50
        tick = caps.control_rate_hz if caps is not None and caps.control_rate_hz > 0 else 500
        return 1_000_000 // rate + 1_000_000 // tick

    async def next_telemetry(self, timeout: float) -> Telemetry:
        """The next telemetry report received after this call."""
        fut = self.fanout.waiter(lambda _t: True)
        try:
            return await fut.get(timeout)
        except TimeoutError:
            raise LinkTimeout(f"no telemetry within {timeout} s") from None
        finally:
            self.fanout.forget(fut)
