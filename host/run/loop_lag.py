"""Control-path lag: how late the host's event loop runs a task that asked to wake at a given time.

Every frame, confirmation and token of a run goes through one asyncio event loop; work that holds it
(recording, plotting, a slow callback) delays all of them. :class:`LagMonitor` measures that delay the
way every timed task feels it: a task sleeps ``period_s`` (default 5 ms) again and again and records
how much longer than asked each sleep took (its *lag*, seconds). The samples are kept in a fixed numpy
ring (the latest :data:`WINDOW` samples, ~8 minutes at 5 ms: nothing grows), the maximum over the
whole window since :meth:`LagMonitor.reset`; :meth:`LagMonitor.stats` gives p50/p99/max in milliseconds.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable
from typing import Any

import anyio
import numpy as np

__all__ = ["LAG_PERIOD_S", "WINDOW", "LagMonitor"]

#: seconds the monitor asks to sleep between two samples
LAG_PERIOD_S = 0.005
#: samples kept (the newest); quantiles are over these, the maximum over everything since the last reset
WINDOW = 100_000


class LagMonitor:
    """Samples the event loop's scheduling delay (see the module docstring).

    ``clock``/``sleep``: the monotonic seconds and the sleep the lag is measured with (tests pass a
    virtual pair). Not thread-safe: run :meth:`run` and read :meth:`stats` on the same event loop.
    """

    def __init__(self, period_s: float = LAG_PERIOD_S, window: int = WINDOW, *,
                 clock: Callable[[], float] = time.perf_counter,
                 sleep: Callable[[float], Awaitable[None]] = anyio.sleep) -> None:
        if not period_s > 0 or window < 1:
            raise ValueError(f"period_s must be > 0 and window >= 1, got {period_s!r} and {window!r}")
        self.period_s, self.clock, self.sleep = period_s, clock, sleep
        self._ring = np.zeros(window, dtype=np.float64)
        self._n = 0  # samples since the last reset (the ring holds the newest min(n, window))
        self._max = 0.0

    def reset(self) -> None:
        """Forget the samples so far (e.g. at a turn's start: its report covers the turn only)."""
        self._n, self._max = 0, 0.0

    def add(self, lag_s: float) -> None:
        """Record one sample of ``lag_s`` seconds (negative: clamped to 0)."""
        lag = max(0.0, float(lag_s))
        self._ring[self._n % len(self._ring)] = lag
        self._n += 1
        self._max = max(self._max, lag)

    @property
    def samples(self) -> int:
        """Samples since the last reset (also those that left the window)."""
        return self._n

    def stats(self) -> dict[str, Any]:
        """``{"p50_ms", "p99_ms", "max_ms", "n", "period_ms"}``: the lag's median and 99th percentile over
        the window, its maximum since the last reset (ms, 3 decimals), the samples taken; the three
        numbers are None before the first sample."""
        held = min(self._n, len(self._ring))
        if held == 0:
            return {"p50_ms": None, "p99_ms": None, "max_ms": None, "n": 0, "period_ms": self.period_s * 1e3}
        p50, p99 = np.quantile(self._ring[:held], [0.5, 0.99])
        return {"p50_ms": round(float(p50) * 1e3, 3), "p99_ms": round(float(p99) * 1e3, 3),
                "max_ms": round(self._max * 1e3, 3), "n": self._n, "period_ms": self.period_s * 1e3}

    async def run(self) -> None:
        """Sample until cancelled."""
        while True:
            before = self.clock()
            await self.sleep(self.period_s)
            self.add(self.clock() - before - self.period_s)
