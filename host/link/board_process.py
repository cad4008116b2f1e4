"""The emulated board as a subprocess on a pty: how the host starts a board, as a user would.

The host never imports ``firmware_sim``; it runs ``python -m firmware_sim --link pty``
and reads the pty path from the board's first stdout line.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
from pathlib import Path
from typing import IO

__all__ = ["BoardProcess", "start_board"]


class BoardProcess:
    """A board subprocess on a pty; ``port`` is the pty it announced."""

    def __init__(self, proc: subprocess.Popen[str], port: str, stderr: IO[str]) -> None:
        self.proc, self.port, self._stderr = proc, port, stderr

    def stop(self, timeout: float = 5.0) -> int:
        """SIGTERM, wait (then SIGKILL); returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()
        self._stderr.close()
        return int(self.proc.returncode)


def start_board(args: list[str], stderr_path: Path | None = None, timeout: float = 30.0) -> BoardProcess:
    """Start ``python -m firmware_sim --link pty ARGS`` and parse ``board: listening on PATH``."""
    err: IO[str] = open(stderr_path, "w") if stderr_path else open(os.devnull, "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", "pty", *args],
        stdout=subprocess.PIPE, stderr=err, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"),
    )
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    line = proc.stdout.readline().strip() if ready else ""
    prefix = "board: listening on "
    if not line.startswith(prefix):
        proc.kill()
        proc.wait()
        err.close()
        hint = f" (see {stderr_path})" if stderr_path else ""
        raise RuntimeError(f"the board did not start: expected {prefix!r}..., got {line!r}{hint}")
    return BoardProcess(proc, line[len(prefix):], err)
