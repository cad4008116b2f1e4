"""``kill -INT`` interrupts a command that a script started in the background (issue 45, item 3).

bash starts a non-interactive script's background job (``ghostshell demo & ...; kill -INT $pid``)
with SIGINT ignored; the process inherits that and Python then installs no KeyboardInterrupt
handler, so only ``run``'s own signal handling saw the signal and every other phase (rendering a
video, a tour, a pose's handshake) went on as if nothing had happened. :func:`host.cli.main` puts
Python's default handler back when it finds SIGINT ignored. Here the command is started exactly so
(SIGINT ignored before exec) and held in its handshake with a board that never answers: a
pseudo-terminal this test holds, read until the host's HELLO has been sent (no sleep).
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
import tty
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(120)


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # what bash does for `cmd &` in a script


@pytest.mark.parametrize("argv", [["pose", "--pose", "stand"], ["estop"]], ids=["pose", "estop"])
def test_sigint_ignored_by_the_parent_still_interrupts(argv: list[str], tmp_path: Path) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    err = tmp_path / "stderr"
    with open(err, "wb") as err_file:
        proc = subprocess.Popen([sys.executable, "-m", "host", *argv, "--link", os.ttyname(slave)],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err_file,
                                start_new_session=True, preexec_fn=_ignore_sigint)
    try:
        got = bytearray()
        deadline = time.monotonic() + 60
        while b"\x00" not in got[1:]:  # a whole COBS frame: HELLO, the host now waits for the board's CAPS
            assert proc.poll() is None, err.read_text()
            assert time.monotonic() < deadline, "the host sends no HELLO"
            if select.select([master], [], [], 0.05)[0]:
                got.extend(os.read(master, 4096))
        os.close(slave)  # the command holds its own descriptor (closed earlier, the master reads EIO)
        slave = -1
        proc.send_signal(signal.SIGINT)  # `kill -INT $pid`
        rc = proc.wait(60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
        if slave >= 0:
            os.close(slave)
    lines = err.read_text().strip().splitlines()
    assert rc == 130, err.read_text()
    assert lines == [f"ghostshell {argv[0]}: interrupted by SIGINT (Ctrl-C)"], lines
