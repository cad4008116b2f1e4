"""A realtime board's priority request (firmware_sim.priority), in a child process each (nice values stick)."""

from __future__ import annotations

import os
import subprocess
import sys

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
