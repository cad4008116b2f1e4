"""The emulated board as a subprocess: how the host starts a board, as a user would.

The host never imports ``firmware_sim``; it runs ``python -m firmware_sim --link SPEC ...``
and reads the first stdout line, ``board: listening on X``. For links the board creates
(``pty``, ``can:slcan:pty``) X is the new pty and the host connects to the spec with that
port (:meth:`protocol.linkspec.LinkSpec.with_port`); for every other link the host connects
to the spec as given.

The host owns the board's life: the board runs in its own process group, so a Ctrl-C in the
terminal reaches only the host, which then stops the board itself (:meth:`BoardProcess.stop`)
after it has finished with it (the link never looks "lost" because of the user's Ctrl-C); and
its standard input is a pipe from the host (``--stop-on-stdin-eof``), so a host that dies in any
way (SIGKILL included) takes its board with it.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO

from host.link.errors import LinkConfigError, LinkDown
from protocol.linkspec import LinkSpec, parse_link_spec

__all__ = ["BoardProcess", "dead_board_error", "start_board"]

#: how a board started with ``--servo-bus`` words why it cannot use that bus: ``board: servo bus PORT: why``
SERVO_BUS_REFUSAL = "board: servo bus "
USAGE_STATUS = 2  # ``python -m firmware_sim`` exits 2 for a link spec it cannot serve (after one stderr line)


def _last_line(err: IO[str]) -> str:
    """The last non-empty line the board wrote to ``err`` (its stderr file, opened for reading too),
    read at an offset (``os.pread``): the file position, which the board and any child of it (the C
    firmware, QEMU) share and may still write at, does not move."""
    try:
        fd = err.fileno()
        size = os.fstat(fd).st_size
        text = os.pread(fd, 4000, max(0, size - 4000)).decode("utf-8", "replace")
    except (OSError, ValueError):
        return ""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


class BoardProcess:
    """A board subprocess; ``port`` is what it announced, ``spec`` the link spec to connect to,
    ``stderr_path`` the file its stderr goes to (None: a temporary file)."""

    def __init__(self, proc: subprocess.Popen[str], port: str, stderr: IO[str], spec: LinkSpec | None = None,
                 stderr_path: Path | None = None) -> None:
        self.proc, self.port, self._stderr = proc, port, stderr
        self.spec: LinkSpec = spec if spec is not None else parse_link_spec(port)
        self.stderr_path = stderr_path
        self._exit_reason: str | None = None

    def exit_reason(self) -> str | None:
        """None while the board runs; once it has exited, one line (worked out once): its status, the
        last line it wrote to stderr, and where its stderr is."""
        if self._exit_reason is None:
            status = self.proc.poll()
            if status is None:
                return None
            said = _last_line(self._stderr) if not self._stderr.closed else ""
            see = f"; see {self.stderr_path}" if self.stderr_path is not None else ""
            self._exit_reason = f"the emulated board exited (status {status}){f': {said}' if said else ''}{see}"
        return self._exit_reason

    def link_target(self) -> Callable[[], LinkSpec]:
        """What a client connects to (``BoardClient.connect(board.link_target())``): this board's link
        spec while it runs. Once it has exited, every (re)connect fails with :class:`LinkDown` and
        :meth:`exit_reason`: its pty is gone, and the kernel may hand the same pty name to another
        program, even another board, which a reconnecting host must not take over."""

        def target() -> LinkSpec:
            why = self.exit_reason()
            if why is not None:
                raise LinkDown(why)
            return self.spec

        return target

    def stop(self, timeout: float = 10.0) -> int:
        """SIGTERM, wait up to ``timeout`` s (then SIGKILL); returns the exit code (130: the board stopped cleanly
        on the signal, as ``python -m firmware_sim`` does; -9 after SIGKILL). 10 s: a QEMU board's launcher gives
        the firmware 2 s, then drains its log and prints the lateness record; with 5 s a quiet CI once lost that
        record (STM32F4 task 23, realtime, 2026-12-08)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            if pipe is not None:
                try:
                    pipe.close()
                except OSError:
                    pass
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

    Raises :class:`protocol.linkspec.LinkSpecError` for a bad ``link``,
    :class:`host.link.errors.LinkConfigError` (with the board's own one-line reason) when the board
    exits with status 2 because it cannot serve the link (no such interface or device, ...), and
    ``RuntimeError`` (with the board's stderr file named) when it does not announce itself in
    ``timeout`` s otherwise.
    """
    spec = parse_link_spec(link)
    err: IO[str] = open(stderr_path, "w+") if stderr_path else tempfile.TemporaryFile("w+")
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--link", str(spec), "--stop-on-stdin-eof", *args],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"),
        process_group=0,  # the terminal's Ctrl-C reaches the host only; the host stops the board
    )
    assert proc.stdout is not None
    try:
        ready, _, _ = select.select([proc.stdout], [], [], timeout)
        line = proc.stdout.readline().strip() if ready else ""
    except BaseException:  # e.g. KeyboardInterrupt while it starts: the board must not be left behind
        proc.kill()
        proc.wait()
        err.close()
        raise
    prefix = "board: listening on "
    if not line.startswith(prefix):
        proc.kill()
        status = proc.wait()
        assert proc.stdin is not None
        proc.stdin.close()
        why = _last_line(err)
        err.close()
        if status == USAGE_STATUS and why.startswith(SERVO_BUS_REFUSAL) and "--servo-bus" in args:
            # the link was fine: the board could not use the real servo bus it was given (firmware_sim.cli)
            raise LinkConfigError(f"the board cannot use its servo bus {why.removeprefix(SERVO_BUS_REFUSAL)}")
        if status == USAGE_STATUS and why:  # the board refused the link spec (its own one-line reason)
            raise LinkConfigError(f"the emulated board cannot serve {spec}: {why.removeprefix('board: ')}")
        hint = f" (see {stderr_path})" if stderr_path else ""
        said = f"; it said: {why}" if why else ""
        raise RuntimeError(f"the board did not start on {spec}: expected {prefix!r}..., got {line!r}{said}{hint}")
    port = line[len(prefix):]
    connect = spec.with_port(port) if spec.implies_emulated_board else spec
    return BoardProcess(proc, port, err, connect, stderr_path)


def dead_board_error(board: BoardProcess | None, error: LinkConfigError) -> LinkDown | None:
    """Classify ``error``, raised opening the link to ``board`` (the board the host started for it, or None).

    When that board has exited, the link spec was fine: the board died before the host could open its
    link (its pty is gone), which is a lost link (exit 1), not a usage error (exit 2). Returns the
    :class:`LinkDown` to raise then (``raise dead from error``), with :meth:`BoardProcess.exit_reason`
    (exit status, last stderr line, stderr file); None when there is no such board or it still runs (``error`` stands).
    """
    why = board.exit_reason() if board is not None else None
    return None if why is None else LinkDown(f"before the link came up, {why}")
