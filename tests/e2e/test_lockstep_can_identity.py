"""Lockstep over CAN is a function of the host's input, however busy the machine is (Python board).

One paper task runs twice as a user runs it, ``ghostshell run --task 1 --link can:slcan:pty --lockstep``:
once quiet, once with a CPU hog per core for the whole run. The board's candump logs must hold the same
CAN frames (identifier and data, timestamps ignored) board->host and host->board, in order. Before the
board held its ticks while an ISO-TP transfer of its own waited for the host's flow control
(:attr:`firmware_sim.transports.can.CanBoardTransport.lockstep_hold`) and answered a host's First Frame
only at its place in the input stream, a periodic SIM_STATE was replaced or sent depending on when the
flow control came in wall-clock time (135 vs 147 SIM_STATEs in two runs), and the board's own flow
control went out between whichever reports were sent when the First Frame came; every later sequence
number and CRC differed.

What says *when*, not *what*, is left out (:mod:`support.can_identity`: wall-clock stamps, the host's
flow controls, the end of the run). The C firmware's test is in tests/socketcan/test_c_firmware_over_socketcan.py.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from support.can_identity import assert_same_frames, can_frames, cpu_hogs

TASK = 1


def _run(out: Path) -> Path:
    """``ghostshell run --task TASK --link can:slcan:pty --lockstep`` into ``out``: the board's frame log."""
    cmd = [sys.executable, "-m", "host.cli", "run", "--task", str(TASK), "--link", "can:slcan:pty", "--lockstep",
           "--out", str(out), "--no-live"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert p.returncode == 0, (p.stdout + p.stderr)[-3000:]
    return out / "board_frames.log"


@pytest.mark.slow  # two task runs, ~15 s
def test_lockstep_can_frames_do_not_depend_on_load(tmp_path: Path) -> None:
    quiet = can_frames(_run(tmp_path / "quiet"))
    with cpu_hogs():
        busy = can_frames(_run(tmp_path / "busy"))
    sim_states = sum(1 for f in quiet["tx"] if f.startswith("681#1"))
    assert sim_states > 50, f"only {sim_states} bulk transfers from the board: the run did not get going"
    assert_same_frames(quiet["tx"], busy["tx"], "board->host")
    assert_same_frames(quiet["rx"], busy["rx"], "host->board")
