"""Board clocks: the realtime pacer (absolute deadlines, catch-up, lateness statistics).

Lockstep needs no clock object: the board core keeps virtual time itself
(:attr:`firmware_sim.board.Board.now_us`) and the server only ticks when the host
has covered the next tick.
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np

__all__ = ["LatenessStats", "RealtimeClock"]


class LatenessStats:
    """Tick lateness (how far after its deadline a tick started), last ``window`` ticks kept."""

    def __init__(self, window: int = 60_000) -> None:
        self._samples: deque[float] = deque(maxlen=window)
        self.count = 0
        self.max_s = 0.0
        self.overruns = 0  # ticks started more than one period late

    def add(self, lateness_s: float, period_s: float) -> None:
        self._samples.append(lateness_s)
        self.count += 1
        self.max_s = max(self.max_s, lateness_s)
        if lateness_s > period_s:
            self.overruns += 1

    def percentiles(self, *qs: float) -> list[float]:
        """Lateness percentiles in seconds over the kept window (zeros if empty)."""
        if not self._samples:
            return [0.0 for _ in qs]
        a = np.fromiter(self._samples, dtype=float)
        return [float(v) for v in np.percentile(a, qs)]

    def summary(self) -> str:
        p50, p99 = self.percentiles(50, 99)
        return (
            f"ticks={self.count} lateness p50={p50 * 1e6:.0f}us p99={p99 * 1e6:.0f}us "
            f"max={self.max_s * 1e6:.0f}us overruns={self.overruns}"
        )


class RealtimeClock:
    """Paces ticks to ``time.monotonic`` with absolute deadlines.

    Tick ``k`` is due at ``start + k * period``. A late tick runs at once (catch-up,
    no sleeping) so the average rate holds; if the loop falls more than
    ``max_behind_s`` behind, the schedule is re-anchored (ticks skipped, counted in
    ``resyncs``) instead of bursting forever.
    """

    def __init__(self, period_s: float, max_behind_s: float = 0.1) -> None:
        self.period_s = period_s
        self.max_behind_s = max_behind_s
        self.start = time.monotonic()
        self.next_tick = 0
        self.resyncs = 0
        self.stats = LatenessStats()

    def board_time_us(self) -> int:
        """Fine-grained board clock (us since start)."""
        return int((time.monotonic() - self.start) * 1e6)

    def deadline(self) -> float:
        """Monotonic time at which the next tick is due."""
        return self.start + self.next_tick * self.period_s

    def time_to_deadline(self) -> float:
        return self.deadline() - time.monotonic()

    def begin_tick(self) -> tuple[int, bool]:
        """Call when the deadline has passed: returns (tick index, overran) and advances the schedule."""
        late = time.monotonic() - self.deadline()
        overran = late > self.period_s
        self.stats.add(max(0.0, late), self.period_s)
        k = self.next_tick
        self.next_tick += 1
        if late > self.max_behind_s:
            skip = int(late / self.period_s)
            self.next_tick += skip
            self.resyncs += 1
        return k, overran
