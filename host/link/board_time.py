"""Board time as the host knows it: the time-sync estimate (realtime) or the latest board time seen (lockstep).

A :class:`BoardClock` is one part of a :class:`host.link.client.BoardClient`. On a realtime board the
supervisor's TIME_SYNC exchanges feed its :class:`host.link.timesync.ClockSync` (``sync``: offset +
drift), and :meth:`BoardClock.host_to_board` maps host time (:func:`host.link.timesync.host_now_us`,
µs) to board time (µs). A lockstep board's clock is virtual: it moves only when the host ADVANCEs it,
so the estimate is the latest board time reported (``seen_us``: CAPS, TELEMETRY, TIME_SYNC replies).
It reads the handshake's CAPS through :class:`BoardInfo` (the session's ``caps``); no I/O of its own.
"""

from __future__ import annotations

from typing import Protocol

from host.link.errors import LinkError
from host.link.timesync import ClockEstimate, ClockSync, host_now_us
from protocol.messages import Caps

__all__ = ["BoardClock", "BoardInfo"]


class BoardInfo(Protocol):
    """What the board said of itself at the handshake (:class:`host.link.core.LinkSession` is one)."""

    @property
    def caps(self) -> Caps | None: ...


class BoardClock:
    """Board clock queries (module docstring): ``sync`` is the realtime estimator, ``seen_us`` the latest
    board time reported (µs, never goes back until the next handshake)."""

    def __init__(self, board: BoardInfo) -> None:
        self.board = board
        #: the TIME_SYNC estimator (offset + drift; realtime boards)
        self.sync = ClockSync()
        #: the latest board time (µs) a message reported: CAPS, TELEMETRY, TIME_SYNC replies
        self.seen_us = 0

    def restart(self, caps: Caps) -> None:
        """A handshake answered with ``caps``: the board's clock starts afresh at its CAPS' time."""
        self.seen_us = caps.board_time_us
        self.sync.clear()

    def saw(self, board_time_us: int) -> None:
        """A message reported board time ``board_time_us`` (µs)."""
        self.seen_us = max(self.seen_us, board_time_us)

    @property
    def lockstep(self) -> bool:
        """True when the board's clock is virtual (CAPS says so)."""
        caps = self.board.caps
        return bool(caps and caps.lockstep)

    @property
    def estimate(self) -> ClockEstimate | None:
        """Current offset/drift estimate (None before the first sync or in lockstep)."""
        return self.sync.estimate

    def host_to_board(self, t_host_us: int) -> int:
        """Board time at host time ``t_host_us`` (realtime boards; see :meth:`board_now_estimate`)."""
        if self.lockstep:
            raise LinkError("the board runs in lockstep: its clock is virtual; use board_now_estimate() and advance()")
        est = self.sync.estimate
        if est is None:
            raise LinkError("no time sync yet")
        return est.host_to_board(t_host_us)

    def board_now_estimate(self) -> int:
        """Board time now (µs): the synced estimate (realtime) or the latest board time reported (lockstep)."""
        if self.lockstep:
            return self.seen_us
        return self.host_to_board(host_now_us())
