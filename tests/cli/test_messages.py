"""Messages that say what happened (issue 16, item 4): each case of the issue with its input.

Real commands in real processes: a board on a pty, a second host on it, an ESTOP and its clear, a
standalone board nobody reads, ``--help`` texts, and the two decoders' layout of a servo mask.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from host.cli import COMMANDS
from support.cliproc import Cli, start, wait_until

pytestmark = pytest.mark.timeout(180)

README = Path(__file__).resolve().parents[2] / "README.md"


def _ghostshell(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host", *args], capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


@pytest.fixture
def board(tmp_path: Path) -> Iterator[tuple[Cli, str]]:
    """``ghostshell board --link pty --lockstep`` as a user starts it; yields it and its pty."""
    cli = start(["board", "--link", "pty", "--lockstep", "--log", str(tmp_path / "board.jsonl")], tmp_path / "board")
    wait_until(lambda: "listening on" in cli.stdout, "the board announces its pty", proc=cli)
    port = cli.stdout.split("listening on ", 1)[1].split()[0]
    try:
        yield cli, port
    finally:
        cli.signal(signal.SIGTERM)
        cli.wait(30)


def test_estop_clear_says_what_it_cleared(board: tuple[Cli, str]) -> None:
    _, port = board
    estop = _ghostshell("estop", "--link", port)
    assert estop.returncode == 0 and "ESTOP acknowledged" in estop.stdout, estop.stderr
    cleared = _ghostshell("estop", "--link", port, "--clear")
    assert cleared.returncode == 0, cleared.stderr
    assert "cleared its estop" in cleared.stdout and "no estop" not in cleared.stdout, cleared.stdout
    again = _ghostshell("estop", "--link", port, "--clear")
    assert again.returncode == 0 and "nothing was latched" in again.stdout, again.stdout


def test_a_second_host_on_a_busy_board_is_told_so(board: tuple[Cli, str], tmp_path: Path) -> None:
    _, port = board
    # the first host: a chat session that holds the link, waiting for the user to type
    first = start(["chat", "--link", port, "--lockstep", "--no-live", "--out", str(tmp_path / "chat")],
                  tmp_path / "chat-logs", stdin_pipe=True)
    try:
        wait_until(lambda: "type a message" in first.stdout, "the first host is connected", proc=first)
        second = _ghostshell("pose", "--link", port, "--pose", "sit")
        line = _one_line(second.stderr)
        assert second.returncode == 2, second.stderr
        assert "another host has it open" in line and port in line, line
        assert "no board" not in line and "multiple access" not in line, line
    finally:
        assert first.proc.stdin is not None
        first.proc.stdin.close()  # Ctrl-D: the chat ends
        first.wait(60)


def test_serial_port_read_by_another_program_is_named() -> None:
    """pyserial's own exception for a readable port that returned nothing (another reader took the bytes)."""
    import serial

    from host.link.transports.serial import _read_failed

    e = serial.SerialException("device reports readiness to read but returned no data "
                               "(device disconnected or multiple access on port?)")
    assert "another program is reading /dev/pts/0" in _read_failed("/dev/pts/0", e)
    assert _read_failed("/dev/pts/0", OSError(5, "Input/output error")).startswith("read failed:")


@pytest.mark.realtime
def test_a_standalone_board_nobody_reads_does_not_blame_the_link(tmp_path: Path) -> None:
    # 9600 baud of modelled wire cannot carry 50 Hz reports: from the second report on they are dropped
    log = tmp_path / "board.jsonl"
    cli = start(["board", "--link", "pty", "--realtime", "--baud", "9600", "--log", str(log)], tmp_path / "b")
    # a report that left after the modelled wire freed up: board time passed reports that were dropped
    wait_until(lambda: any('"TELEMETRY"' in ln and float(ln.split('"t":', 1)[1].split(",", 1)[0]) >= 0.3
                           for ln in (log.read_text().splitlines() if log.exists() else [])),
               "the board has reported past 0.3 s", proc=cli)
    cli.signal(signal.SIGTERM)
    assert cli.wait(30) == 130  # stopped by a signal: "interrupted", after its clean shutdown
    err = cli.stderr
    assert re.search(r"board: \d+ report\(s\) not sent while no host was talking to the board", err), err
    assert "link too slow" not in err, err


def test_board_help_names_the_command_the_user_typed() -> None:
    r = _ghostshell("board", "--help")
    assert r.returncode == 0 and r.stdout.startswith("usage: ghostshell board"), r.stdout[:200]
    assert "python -m firmware_sim" not in r.stdout.splitlines()[0]


def test_top_level_help_is_text_for_a_user() -> None:
    r = _ghostshell("--help")
    assert r.returncode == 0
    assert ":mod:" not in r.stdout and "``" not in r.stdout, r.stdout
    assert "exit status: 0 success" in " ".join(r.stdout.split())


def test_readme_lists_each_command_once_or_twice() -> None:
    text = README.read_text(encoding="utf-8")
    block = text.split("## Commands", 1)[1].split("```sh", 1)[1].split("```", 1)[0]
    counts = {name: len(re.findall(rf"^ghostshell {name}\b", block, re.M)) for name in COMMANDS}
    assert all(counts.values()), counts  # every command is there
    assert counts["skills"] == 1 and counts["chat"] <= 2, counts  # the issue: chat three times, skills twice


def test_serial_and_can_decoders_print_the_mask_alike(tmp_path: Path) -> None:
    import can

    from protocol import framelog
    from protocol.can.codec import encode_fixed
    from protocol.framing import Frame, encode_frame
    from protocol.messages import MsgType, ServoFrame

    msg = ServoFrame(apply_at_us=30_000, mask=0x0FFF, targets=(0.0,) * 12)
    raw = encode_frame(msg, 7)
    jsonl = tmp_path / "host_frames.jsonl"
    jsonl.write_text(framelog.to_line(framelog.record("tx", 1.0, raw, Frame(7, MsgType.SERVO_FRAME, msg, raw))) + "\n")
    candump = tmp_path / "host_frames.log"
    with can.CanutilsLogWriter(str(candump), channel="vcan0") as w:
        for f in encode_fixed(msg, 7, 1, False, "host"):
            w.on_message_received(can.Message(timestamp=1.0, arbitration_id=f.arbitration_id, data=f.data,
                                              is_extended_id=False))
    serial_out = _ghostshell("log", "decode", str(jsonl))
    can_out = _ghostshell("log", "decode", str(candump))
    assert serial_out.returncode == 0 and can_out.returncode == 0, serial_out.stderr + can_out.stderr
    assert "mask=0x0fff" in serial_out.stdout, serial_out.stdout
    assert "mask=0x0fff" in can_out.stdout and "mask=4095" not in can_out.stdout, can_out.stdout
