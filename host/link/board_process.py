"""The emulated board as a subprocess: how the host starts a board, as a user would.

The host never imports ``firmware_sim``; it runs ``python -m firmware_sim --link SPEC ...``
and reads the first stdout line, ``board: listening on X``. For links the board creates
(``pty``, ``can:slcan:pty``) X is the new pty and the host connects to the spec with that
port (:meth:`protocol.linkspec.LinkSpec.with_port`); for every other link the host connects
to the spec as given.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
from pathlib import Path
from typing import IO

from protocol.linkspec import LinkSpec, parse_link_spec

__all__ = ["BoardProcess", "start_board"]


class BoardProcess:
    """A board subprocess; ``port`` is what it announced, ``spec`` the link spec to connect to."""

    def __init__(self, proc: subprocess.Popen[str], port: str, stderr: IO[str], spec: LinkSpec | None = None) -> None:
        self.proc, self.port, self._stderr = proc, port, stderr
        self.spec: LinkSpec = spec if spec is not None else parse_link_spec(port)

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


def start_board(
    args: list[str],
    stderr_path: Path | None = None,
    timeout: float = 30.0,
    *,
    link: LinkSpec | str = "pty",
) -> BoardProcess:
    """Start ``python -m firmware_sim --link LINK ARGS`` and parse ``board: listening on X``.

    Raises :class:`protocol.linkspec.LinkSpecError` for a bad ``link`` and ``RuntimeError``
    (with the board's stderr file named) when the board does not announce itself in ``timeout`` s.
    """
    spec = parse_link_spec(link)
    err: IO[str] = open(stderr_path, "w") if stderr_path else open(os.devnull, "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", str(spec), *args],
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
        raise RuntimeError(f"the board did not start on {spec}: expected {prefix!r}..., got {line!r}{hint}")
    port = line[len(prefix):]
    connect = spec.with_port(port) if spec.implies_emulated_board else spec
    return BoardProcess(proc, port, err, connect)
