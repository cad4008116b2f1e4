"""A realtime board raises its own CPU priority (a real board is a microcontroller nobody preempts).

On a shared or loaded host the emulated board's control loop competes with everything else for the
cores; a tick that starts late delays every frame it applies (the token -> servo tail of
``bench/bench_latency.py``) and a long stall trips the watchdog. So a realtime board lowers its nice
value (``os.nice``; Linux CFS gives a nice -10 process ~10x the CPU share of a nice 0 one under
contention) where it is permitted: as root or with ``CAP_SYS_NICE``, or within ``RLIMIT_NICE``. Where
it is not, the board says so in one line and runs at its current priority; nothing else changes.
A lockstep board runs on virtual time and is left alone.

A realtime board also asks for a timer slack of 1 ns (:func:`tighten_timer_slack`, prctl(2)
``PR_SET_TIMERSLACK``; permitted to any process for itself). Linux lets a normal-priority task's timed
waits end up to its slack late, 50 µs by default, so the kernel can batch wake-ups; the board's
``select`` until the next tick is such a wait. Measured with ``bench/bench_board.py --realtime-only
--seconds 8`` (and 12) under ``nice -n -10``, quiet, the board's own tick lateness, interleaved runs:
p50 129-138 µs with the default slack and 79-102 µs with 1 ns (n = 5 runs each, ~4 000-6 000 ticks a
run); the p99 moved with the machine (166-1 481 µs against 272-585 µs).

``$GHOSTSHELL_BOARD_NICE`` sets the nice increment (default ``-10``; ``0`` leaves the priority
alone; a value that is not an integer is refused with one line and ignored). Not a real-time
scheduling class (``SCHED_FIFO``/``SCHED_RR``): a board stuck in a loop at such a priority could
starve a 2-core machine's other work, while a nice value only weights the share.
"""

from __future__ import annotations

import ctypes
import os
import sys

#: the environment variable naming the nice increment a realtime board asks for
NICE_ENV = "GHOSTSHELL_BOARD_NICE"
DEFAULT_NICE = -10


def lower_nice(inc: int) -> tuple[int, int]:
    """Apply the nice increment ``inc`` (negative raises the priority) to this process; returns
    ``(before, after)``. Raises ``PermissionError`` where that is not permitted (not root, no
    ``CAP_SYS_NICE``, beyond ``RLIMIT_NICE``); the priority is then unchanged."""
    before = os.nice(0)
    return before, os.nice(inc)


def raise_priority(env: dict[str, str] | None = None) -> str:
    """Apply ``$GHOSTSHELL_BOARD_NICE`` (default -10) to this process; returns the one line to print.

    Never raises: a refusal (``PermissionError``: not root, no ``CAP_SYS_NICE``) or an unusable value
    is reported in the returned line and the process keeps its priority.
    """
    text = (os.environ if env is None else env).get(NICE_ENV, str(DEFAULT_NICE)).strip()
    try:
        inc = int(text)
    except ValueError:
        return f"priority unchanged: ${NICE_ENV}={text!r} is not an integer"
    if inc == 0:
        return f"priority unchanged (${NICE_ENV}=0), nice {os.nice(0)}"
    try:
        before, after = lower_nice(inc)
    except PermissionError:
        return (f"priority unchanged at nice {os.nice(0)}: raising it by {inc} is not permitted "
                f"(needs root or CAP_SYS_NICE; set ${NICE_ENV}=0 to silence this)")
    return f"priority: nice {before} -> {after} (${NICE_ENV})"


#: prctl(2) option: set the calling thread's timer slack (ns); linux/prctl.h
PR_SET_TIMERSLACK = 29
#: what a realtime board asks for (1 ns: the smallest; 0 would mean "the default" again)
BOARD_TIMER_SLACK_NS = 1


def tighten_timer_slack(ns: int = BOARD_TIMER_SLACK_NS) -> str:
    """Set this thread's timer slack to ``ns`` (Linux; threads started later inherit it); returns the
    one line to print. Never raises: elsewhere, or where prctl refuses, the line says so."""
    if not sys.platform.startswith("linux"):
        return f"timer slack unchanged: prctl(PR_SET_TIMERSLACK) is Linux-only ({sys.platform})"
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(ns), 0, 0, 0) != 0:
        return f"timer slack unchanged: prctl(PR_SET_TIMERSLACK, {ns}) failed: {os.strerror(ctypes.get_errno())}"
    return f"timer slack {ns} ns (PR_SET_TIMERSLACK)"
