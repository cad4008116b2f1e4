"""A realtime board's priority request (firmware_sim.priority), in a child process each (nice values stick)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CODE = "from firmware_sim.priority import raise_priority; print(raise_priority())"


def _run(value: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "GHOSTSHELL_BOARD_NICE"}
    if value is not None:
        env["GHOSTSHELL_BOARD_NICE"] = value
    out = subprocess.run([sys.executable, "-c", CODE], env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_a_value_that_is_not_an_integer_or_zero_changes_nothing() -> None:
    assert _run("fast") == "priority unchanged: $GHOSTSHELL_BOARD_NICE='fast' is not an integer"
    assert _run("0").startswith("priority unchanged ($GHOSTSHELL_BOARD_NICE=0), nice ")


def test_a_permitted_increment_is_applied_and_said() -> None:
    line = _run("3")  # lowering the priority is always permitted
    before = os.nice(0)
    assert line == f"priority: nice {before} -> {min(19, before + 3)} ($GHOSTSHELL_BOARD_NICE)"


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
