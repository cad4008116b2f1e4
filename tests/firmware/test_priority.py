"""A realtime board's priority request (firmware_sim.priority), in a child process each (nice values stick)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from support.realtime_lock import _may_lower_nice_to, background_possible

CODE = "from firmware_sim.priority import raise_priority; print(raise_priority())"


def _run(value: str | None, start_nice: int | None = None) -> str:
    """``raise_priority()``'s line in a child; ``start_nice``: the child's nice value before it (needs the
    right to set it, e.g. to come back from the suite's nice 19 in background mode)."""
    env = {k: v for k, v in os.environ.items() if k != "GHOSTSHELL_BOARD_NICE"}
    if value is not None:
        env["GHOSTSHELL_BOARD_NICE"] = value
    code = CODE if start_nice is None else f"import os; os.setpriority(os.PRIO_PROCESS, 0, {start_nice}); {CODE}"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_a_value_that_is_not_an_integer_or_zero_changes_nothing() -> None:
    assert _run("fast") == "priority unchanged: $GHOSTSHELL_BOARD_NICE='fast' is not an integer"
    assert _run("0").startswith("priority unchanged ($GHOSTSHELL_BOARD_NICE=0), nice ")


def test_a_permitted_increment_is_applied_and_said() -> None:
    before = os.nice(0)
    if before + 3 > 19:  # e.g. a suite worker in background mode (tests/support/realtime_lock.py)
        if not background_possible({}) and not _may_lower_nice_to(10):
            pytest.skip(f"this process runs at nice {before} and may not come back below 17")
        before = 10
        line = _run("3", start_nice=before)
    else:
        line = _run("3")  # raising a nice value (lowering the priority) is always permitted
    assert line == f"priority: nice {before} -> {before + 3} ($GHOSTSHELL_BOARD_NICE)"


SLACK = ("from firmware_sim.priority import tighten_timer_slack; line = tighten_timer_slack({ns}); "
         "print(line); print(open('/proc/self/timerslack_ns').read().strip())")


@pytest.mark.skipif(not os.path.exists("/proc/self/timerslack_ns"), reason="Linux's /proc/PID/timerslack_ns (4.6+)")
def test_timer_slack_is_set_and_said() -> None:
    for ns in (1, 7_000):  # the board's 1 ns, and a value the default (50 000) is not
        out = subprocess.run([sys.executable, "-c", SLACK.format(ns=ns)], capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        line, slack = out.stdout.splitlines()
        assert (line, slack) == (f"timer slack {ns} ns (PR_SET_TIMERSLACK)", str(ns))


def test_a_realtime_board_says_both() -> None:
    """The board's start-up line names its priority and its timer slack (``python -m firmware_sim``)."""
    env = dict(os.environ, GHOSTSHELL_BOARD_NICE="0")
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim", "--link", "pty"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stderr is not None
        assert proc.stdout.readline().startswith("board: listening on ")
        lines = [proc.stderr.readline() for _ in range(2)]
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    assert any(ln.startswith("board: priority unchanged ($GHOSTSHELL_BOARD_NICE=0)") and
               ln.rstrip().endswith("; timer slack 1 ns (PR_SET_TIMERSLACK)") for ln in lines), lines
