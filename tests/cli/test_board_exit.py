"""The board alone exits 130 when a signal stops it (reported: ``ghostshell board --link pty`` exited 0
on Ctrl-C), after its clean shutdown; the host's own way to end a board it started (closing the
board's standard input, ``--stop-on-stdin-eof``) is a normal end, exit 0. Real processes, real
signals; each waits for the board's "listening on" line before signalling.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from support.cliproc import Cli, start, wait_until

pytestmark = pytest.mark.timeout(240)


def _listening(cli: Cli) -> None:
    wait_until(lambda: "listening on" in cli.stdout, "the board announces its link", timeout=180, proc=cli)


@pytest.mark.parametrize(("firmware", "sig", "whole_group"), [
    ("python", signal.SIGINT, True),  # Ctrl-C in the terminal
    ("python", signal.SIGTERM, False),  # kill PID
    ("c", signal.SIGINT, True),  # the C firmware's launcher; its firmware process sees the Ctrl-C too
])
def test_a_signal_stops_the_board_with_status_130(tmp_path: Path, firmware: str, sig: signal.Signals,
                                                  whole_group: bool) -> None:
    cli = start(["board", "--link", "pty", "--lockstep", "--firmware", firmware], tmp_path / "logs")
    _listening(cli)
    cli.ctrl_c(sig) if whole_group else cli.signal(sig)
    assert cli.wait(60) == 130, cli.stderr[-2000:]
    assert "Traceback" not in cli.stderr and "exited with status" not in cli.stderr, cli.stderr[-2000:]
    assert "board: servo bus:" in cli.stderr if firmware == "c" else "board: coco" in cli.stderr  # shut down cleanly


def test_python_m_firmware_sim_too_and_stdin_eof_is_a_normal_end(tmp_path: Path) -> None:
    env = dict(os.environ)
    for stop in ("sigint", "stdin"):
        log = tmp_path / f"{stop}.jsonl"
        extra = ["--stop-on-stdin-eof"] if stop == "stdin" else []
        proc = subprocess.Popen([sys.executable, "-m", "firmware_sim", "--link", "pty", "--lockstep", "--log", str(log),
                                 *extra], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=env, start_new_session=True)
        try:
            assert proc.stdout is not None and proc.stdin is not None
            assert proc.stdout.readline().startswith("board: listening on ")  # blocks until it is up
            if stop == "sigint":
                os.killpg(proc.pid, signal.SIGINT)
            # communicate closes the board's stdin: its owner's normal end with --stop-on-stdin-eof
            _, err = proc.communicate(input="", timeout=60)
            assert proc.returncode == (130 if stop == "sigint" else 0), err
            assert "Traceback" not in err
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
