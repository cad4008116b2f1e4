"""What the machine itself lets a wall-clock process do: timer wake-up lateness and CPU steal.

A realtime board ticks every 2 ms and the host answers a token within milliseconds, so a benchmark of
their latency can be no better than the machine's own scheduling. Two figures put a run's numbers in
that light:

* :func:`wakeup_lateness_ms`: how late a ``time.sleep(period)`` returns, in this process at its
  priority (after ``--nice``, beside ``--load``'s hogs if any): the kind of wait the board's ``select``
  does between ticks. About 0.05 ms of it is the kernel's timer slack (``/proc/self/timerslack_ns``,
  50 µs by default for a normal-priority task, 0 for SCHED_FIFO/RR; prctl(2) ``PR_SET_TIMERSLACK``).
  The host's asyncio timers wait differently: epoll takes whole milliseconds and Python rounds a
  timeout up, so a ``call_later`` can return up to ~1 ms late; the host's token path is woken by I/O,
  not by a timer.
* :func:`cpu_steal_s`: the ``steal`` column of ``/proc/stat`` (proc(5); USER_HZ ticks summed over all
  CPUs): time the hypervisor ran something else while this guest's virtual CPUs wanted to run. No
  priority inside the guest gets that time back; on a bare-metal machine it stays 0.

:func:`steal_line` and :func:`floor_line` are the lines ``bench/bench_latency.py`` prints.
"""

from __future__ import annotations

import os
import time
from typing import Any

import numpy as np

__all__ = ["MAX_FLOOR_N", "MIN_FLOOR_N", "cpu_steal_s", "floor_line", "floor_stats", "steal_line", "wakeup_lateness_ms"]

#: the steal column's index in /proc/stat's ``cpu`` line (user nice system idle iowait irq softirq steal ...)
_STEAL_FIELD = 8
#: the fewest wake-ups a floor is measured from: fewer and its p99 is just its largest
MIN_FLOOR_N = 100
#: the most (200 s of 2-ms sleeps; the lateness array is 8 bytes each)
MAX_FLOOR_N = 100_000


def cpu_steal_s(stat_path: str = "/proc/stat") -> float | None:
    """Total CPU steal of all CPUs since boot (CPU-seconds), or None where ``/proc/stat`` has none (not Linux)."""
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


def floor_stats(late_ms: np.ndarray) -> dict[str, Any]:
    """n, p50, p99 and max (ms, 3 decimals: a floor's p50 is ~0.05-0.1 ms) of :func:`wakeup_lateness_ms`."""
    return {"n": int(late_ms.size), "p50": round(float(np.percentile(late_ms, 50)), 3),
            "p99": round(float(np.percentile(late_ms, 99)), 3), "max": round(float(late_ms.max()), 3)}


def floor_line(when: str, s: dict[str, Any]) -> str:
    """``machine floor (start): a 2 ms sleep wakes late by p50 0.071, p99 0.254, max 1.930 ms (n=2000)``."""
    return (f"machine floor ({when}): a 2 ms sleep wakes late by p50 {s['p50']:.3f}, p99 {s['p99']:.3f}, "
            f"max {s['max']:.3f} ms (n={s['n']})")


def steal_line(steal_cpu_s: float, wall_s: float, cpus: int) -> str:
    """The steal of a run as CPU-seconds and as a share of what ``cpus`` CPUs had in ``wall_s``."""
    share = 100 * steal_cpu_s / (wall_s * cpus) if wall_s > 0 and cpus > 0 else 0.0
    return (f"CPU steal during the runs: {steal_cpu_s:.2f} CPU-s over {wall_s:.0f} s on {cpus} CPUs "
            f"({share:.1f} % of their time; /proc/stat: the hypervisor ran something else while they wanted to run)")
