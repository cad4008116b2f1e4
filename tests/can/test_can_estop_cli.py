"""The clear command printed after an e-stop on a CAN link runs as printed (copy and paste).

A real lockstep board serves ``can:slcan:pty?node=2&fd=1`` (a subprocess, an SLCAN adapter on a
pty); ``ghostshell estop`` stops it, ``ghostshell run`` is refused; both print the command that
clears the estop, and that exact text, run by a POSIX shell, clears it. The spec's ``&`` would
end the command in a shell if it were not quoted; a ``(node 2)`` decoration would be no spec.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from host.link.board_process import start_board

pytestmark = pytest.mark.timeout(150)


def _ghostshell(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host.cli", *args], capture_output=True, text=True, timeout=100)


def _clear_command(text: str) -> str:
    found = re.findall(r"`(ghostshell estop [^`]*--clear)`", text)
    assert len(found) == 1, text
    return found[0]


def test_the_printed_clear_command_works_as_printed(tmp_path: Path) -> None:
    board = start_board(["--lockstep"], tmp_path / "board.stderr", link="can:slcan:pty?node=2&fd=1")
    try:
        link = str(board.spec)
        assert link.startswith("can:slcan:/dev/") and "node=2" in link and "fd=1" in link
        on = _ghostshell("estop", "--link", link)
        assert on.returncode == 0 and "ESTOP acknowledged" in on.stdout, on.stdout + on.stderr
        refused = _ghostshell("run", "--task", "2", "--lockstep", "--no-live", "--link", link,
                              "--out", str(tmp_path / "run"))
        assert refused.returncode == 1 and "is in ESTOP" in refused.stderr, refused.stdout + refused.stderr
        command = _clear_command(refused.stderr)
        assert command == _clear_command(on.stdout)  # one way to say it
        assert "(node" not in command
        env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
        off = subprocess.run(["sh", "-c", command], capture_output=True, text=True, timeout=100, env=env)
        assert off.returncode == 0 and "ESTOP_CLEAR acknowledged" in off.stdout, command + "\n" + off.stdout + off.stderr
    finally:
        board.stop()
