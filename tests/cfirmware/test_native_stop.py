"""A native C board asked to stop (SIGTERM) stops at once, even while it waits on a silent servo bus.

Found in the e2e runs on the C firmware: when the host stopped the board, the launcher (the plant)
stopped answering the bus and the firmware, mid-way through a batch of lockstep ticks, waited out
its bus reads (1 s each in lockstep) tick after tick: ~4 s of exit in about one run in three. The
stop now ends every bus wait and the tick batch (firmware_sim/c/core/gs_bus.c, gs_app.c).

Here the bus is a pty this test holds and never answers: the board's boot pings its 12 servos, the
IMU and the probe, 1 s each in lockstep, so a firmware that waited them out would take ~14 s to
exit; the bound below is a third of that. Nor is a stop a missing servo: no SERVO_FAULT is latched.
"""

from __future__ import annotations

import select
import signal
import subprocess
from pathlib import Path

from firmware_sim.cfirmware.build import build
from firmware_sim.transports.ports import PtyPort

PING_SERVO_1 = bytes([0xFF, 0xFF, 0x01, 0x02, 0x01])  # the boot's first instruction: PING id 1 (no checksum)
EXIT_BOUND_S = 5.0  # liveness bound (14 s without the fix), not a speed target


def _wait_readable(fd: int, timeout: float) -> bool:
    return bool(select.select([fd], [], [], timeout)[0])


def test_sigterm_during_bus_waits_ends_the_board_at_once(coco, tmp_path: Path) -> None:
    exe = build("native", coco)
    bus = PtyPort()
    proc = subprocess.Popen([str(exe), "--bus", bus.name, "--host", "pty", "--lockstep"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        seen = b""
        while PING_SERVO_1 not in seen:  # the boot is now waiting for servo 1's answer
            assert _wait_readable(bus.master, 10.0), f"no PING on the bus; got {seen.hex()}"
            seen += bus.read()
        proc.send_signal(signal.SIGTERM)
        try:
            rc = proc.wait(EXIT_BOUND_S)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"the firmware still ran {EXIT_BOUND_S} s after SIGTERM "
                                 "(waiting out its bus timeouts?)") from None
        assert proc.stderr is not None
        err = proc.stderr.read().decode(errors="replace")
        assert rc == 0, err
        assert "stopped answering" not in err and "fault" not in err.lower(), err  # a stop is no missing servo
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        bus.close()


def _children(pid: int) -> list[int]:
    try:
        return [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _pending_signals(pid: int) -> int:
    """The signals pending for ``pid`` (thread and process sets ORed; /proc/PID/status SigPnd, ShdPnd)."""
    fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    return int(fields["SigPnd"], 16) | int(fields["ShdPnd"], 16)


def _state(pid: int) -> str:
    """The process state letter of ``pid`` (/proc/PID/stat, field 3: R, S, T stopped, Z ...)."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


def test_a_second_ctrl_c_during_the_shutdown_does_not_cut_it_short(tmp_path: Path) -> None:
    """Ctrl-C, then Ctrl-C again while the launcher waits for the firmware to stop: still the clean shutdown and 130
    (it printed 'board: interrupted while starting' and skipped its summary lines: the second signal hit the default
    handler the cleanup had restored). The firmware is held stopped (SIGSTOP) so the second signal lands inside that
    wait, which is known to have begun when the launcher's SIGTERM is pending at the firmware."""
    import os
    import sys
    import time

    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim", "--link", "pty", "--firmware", "c", "--lockstep"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stderr is not None and proc.stdout is not None
    try:
        out = b""
        while b"listening on" not in out:  # its announcement (stdout)
            assert _wait_readable(proc.stdout.fileno(), 120.0), out
            chunk = os.read(proc.stdout.fileno(), 65536)
            assert chunk, out
            out += chunk
        (fw,) = _children(proc.pid)
        os.kill(fw, signal.SIGSTOP)
        deadline = time.monotonic() + 30
        while _state(fw) != "T":  # stopped: a SIGTERM pending with the SIGSTOP would be taken first (lower number)
            assert time.monotonic() < deadline, "the firmware did not stop"
            _wait_readable(proc.stdout.fileno(), 0.01)  # a 10 ms poll interval, not a synchronisation
        proc.send_signal(signal.SIGINT)
        while not _pending_signals(fw) & (1 << (signal.SIGTERM - 1)):  # the launcher's stop reached the firmware
            assert time.monotonic() < deadline, "the launcher never asked the firmware to stop"
            _wait_readable(proc.stdout.fileno(), 0.01)  # a 10 ms poll interval, not a synchronisation
        proc.send_signal(signal.SIGINT)  # the second Ctrl-C, inside the shutdown
        os.kill(fw, signal.SIGCONT)
        rc = proc.wait(60)
        text = proc.stderr.read().decode(errors="replace")
        assert rc == 130, text
        assert "interrupted while starting" not in text, text
        assert "board: servo bus:" in text, text  # the shutdown's summary line was written
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
