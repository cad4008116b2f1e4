"""A realtime run raises the host's own CPU priority: its event loop is the control path.

On a realtime link the host's event loop is what keeps the board fed (the frame grid, heartbeats,
telemetry intake). On a loaded machine a nice-0 host competes with every other nice-0 process for the
cores: with a busy loop per core, a realtime C board at nice -10 saw its host stall 2.4 s
(``bench/bench_realtime_load.py``, control-path lag max 2 361 ms) and its watchdog crouch the robot.
So once a session knows its board runs realtime, the host lowers its nice value to
``$GHOSTSHELL_HOST_NICE`` (default -10, the value the emulated board asks for itself: Linux CFS gives a
nice -10 task ~10x the share of a nice 0 one) and asks for a timer slack of 1 ns (prctl(2)
``PR_SET_TIMERSLACK``: the loop's timed waits end on time instead of up to 50 µs late).

Every thread of the process is lowered, not only the event loop's (:func:`_threads`). The nice value is a
target, not an increment: a host already at or below it is left as it is (so a
second session in one process, or ``bench/bench_latency.py`` that lowered it before, changes nothing),
and a board started after this inherits the host's value and lowers its own from there
(``firmware_sim.priority``; sessions start their board before this runs). Where lowering it is not
permitted (not root, no ``CAP_SYS_NICE``, beyond ``RLIMIT_NICE``) the host keeps its priority: the
run's summary shows the nice value it ran at (``extra.timing.host_nice``). Not a real-time scheduling
class (SCHED_FIFO/RR): a host stuck in a loop at such a priority could starve a 2-core machine.

The board's own module does the same for the board (``firmware_sim.priority``); the host cannot import
it (host and firmware_sim never import each other), and a shared helper would be the only non-codec
code in ``protocol/``, so the few lines are the host's own.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Mapping

__all__ = ["DEFAULT_HOST_NICE", "HOST_NICE_ENV", "raise_host_priority"]

#: the environment variable naming the nice value a realtime host runs at
HOST_NICE_ENV = "GHOSTSHELL_HOST_NICE"
DEFAULT_HOST_NICE = -10
_PR_SET_TIMERSLACK = 29  # linux/prctl.h


def raise_host_priority(env: Mapping[str, str] | None = None) -> int:
    """Lower this process's nice value to ``$GHOSTSHELL_HOST_NICE`` (default -10) where permitted and
    set its timer slack to 1 ns (Linux); returns the nice value the process runs at afterwards.

    Never raises: a refusal (``PermissionError``), an unusable value (not an integer: the default is
    used) or a platform without prctl leaves that part unchanged."""
    text = (os.environ if env is None else env).get(HOST_NICE_ENV, "").strip()
    try:
        target = int(text) if text else DEFAULT_HOST_NICE
    except ValueError:
        target = DEFAULT_HOST_NICE
    now = os.nice(0)
    if target < now:
        for tid in _threads():
            try:
                os.setpriority(os.PRIO_PROCESS, tid, target)
            except (PermissionError, ProcessLookupError):
                pass
        now = os.nice(0)
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(1), 0, 0, 0)
    return now


def _threads() -> list[int]:
    """Every thread of this process (Linux: ``/proc/self/task``), else this process's id.

    On Linux a nice value belongs to a thread (setpriority(2) with a thread id; ``os.nice`` changes only
    the caller's), and a thread inherits its creator's. The recording's writer thread and the worker
    threads already started would stay at nice 0: one of them preempted by a hog while it holds the GIL
    stalls the event loop all the same (a nice -10 loop thread of a realtime C run stood 2.3 s)."""
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [os.getpid()]
