"""What the machine itself lets a wall-clock process do: timer wake-up lateness and CPU steal.

A realtime board ticks every 2 ms and the host answers a token within milliseconds, so a benchmark of
their latency can be no better than the machine's own scheduling. Two figures put a run's numbers in
that light:

* :func:`wakeup_lateness_ms`: how late a ``time.sleep(period)`` returns, in this process at its
  priority (after ``--nice``, beside ``--load``'s hogs if any): the same wake-up the board's ``select``
  and the host's event loop wait on, Python's own overhead included (~0.05 ms);
* :func:`cpu_steal_s`: the ``steal`` column of ``/proc/stat`` (proc(5)): time the hypervisor ran
  something else while this guest's virtual CPUs wanted to run. No priority inside the guest gets
  that time back; on a bare-metal machine it stays 0.

Measured on the 2-core development VM, quiet (``nice -n -10`` / ``chrt -f 50`` around a C loop of
10 000 ``nanosleep`` calls of 2 ms): late by p50 0.12 / 0.06 ms, p99 0.9-2.3 / 1.3-1.4 ms, max ~9 /
~6.7 ms, with steal rising ~0.3-1.7 s per 20-40 s meanwhile; so one wake-up already costs about a
millisecond at the p99 there, and a token -> servo path has several in series.
"""

from __future__ import annotations

import os
import time

import numpy as np

__all__ = ["cpu_steal_s", "wakeup_lateness_ms"]

#: the steal column's index in /proc/stat's ``cpu`` line (user nice system idle iowait irq softirq steal ...)
_STEAL_FIELD = 8


def cpu_steal_s(stat_path: str = "/proc/stat") -> float | None:
    """Total CPU steal of all CPUs since boot (s), or None where ``/proc/stat`` has none (not Linux)."""
    try:
        with open(stat_path, encoding="ascii") as f:
            fields = f.readline().split()
    except OSError:
        return None
    if len(fields) <= _STEAL_FIELD or fields[0] != "cpu":
        return None
    return int(fields[_STEAL_FIELD]) / os.sysconf("SC_CLK_TCK")


def wakeup_lateness_ms(n: int, period_s: float = 0.002) -> np.ndarray:
    """Lateness (ms, >= ~0) of ``n`` consecutive ``time.sleep(period_s)`` calls in this process.

    Takes about ``n * period_s`` seconds. Raises ValueError for ``n < 1`` or a period that is not > 0."""
    if n < 1 or not period_s > 0:
        raise ValueError(f"need n >= 1 and period > 0, got n={n}, period={period_s}")
    late = np.empty(n)
    clock = time.perf_counter
    for i in range(n):
        t = clock()
        time.sleep(period_s)
        late[i] = clock() - t - period_s
    return late * 1e3
