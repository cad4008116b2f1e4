"""Board time as the host knows it: the time-sync estimate (realtime) or the latest board time seen (lockstep).

:class:`BoardTime` is a mixin of :class:`host.link.session.BoardClient`. On a realtime board the
supervisor's TIME_SYNC exchanges feed :class:`host.link.timesync.ClockSync` (offset + drift), and
:meth:`BoardTime.host_to_board` maps host time (:func:`host.link.supervisor.host_now_us`, us) to
board time (us). A lockstep board's clock is virtual: it moves only when the host ADVANCEs it, so
the estimate is the latest board time reported (CAPS, TELEMETRY, TIME_SYNC replies).
"""

from __future__ import annotations

from host.link.errors import LinkError
from host.link.supervisor import Supervisor, host_now_us
from host.link.timesync import ClockEstimate, ClockSync
from protocol.messages import Caps

__all__ = ["BoardTime"]


class BoardTime:
    """Board clock queries over the session's ``clock`` and ``_board_time_seen`` (module docstring)."""

    caps: Caps | None
    clock: ClockSync
    supervisor: Supervisor
    _board_time_seen: int

    @property
    def lockstep(self) -> bool:
        """True when the board's clock is virtual (CAPS says so)."""
        return bool(self.caps and self.caps.lockstep)

    def _saw_board_time(self, board_time_us: int) -> None:
        self._board_time_seen = max(self._board_time_seen, board_time_us)

    async def sync_once(self, timeout: float = 0.5) -> tuple[int, int, int, int]:
        """One TIME_SYNC exchange; returns ``(t1, t2, t3, t4)`` and feeds the estimator (realtime)."""
        return await self.supervisor.sync_once(timeout)

    @property
    def clock_estimate(self) -> ClockEstimate | None:
        """Current offset/drift estimate (None before the first sync or in lockstep)."""
        return self.clock.estimate

    def host_to_board(self, t_host_us: int) -> int:
        """Board time at host time ``t_host_us`` (realtime boards; see :meth:`board_now_estimate`)."""
        if self.lockstep:
            raise LinkError("the board runs in lockstep: its clock is virtual; use board_now_estimate() and advance()")
        est = self.clock.estimate
        if est is None:
            raise LinkError("no time sync yet")
        return est.host_to_board(t_host_us)

    def board_now_estimate(self) -> int:
        """Board time now: the synced estimate (realtime) or the latest board time reported (lockstep)."""
        if self.lockstep:
            return self._board_time_seen
        return self.host_to_board(host_now_us())
