"""Link specs that parse but can never work: every command refuses them the same way.

One line on stderr naming the spec and what to do, no library text passed through raw, exit
status 2 (a usage/configuration error) in ``run``, ``demo``, ``pose``, ``estop`` and ``tour``
alike. The commands run in-process through :func:`host.cli.main` (what the console script runs, through host.cli.entry);
the CAN buses are opened with python-can's own drivers, the emulated board is a real subprocess.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from host.cli import main as cli_main

pytestmark = pytest.mark.timeout(120)


def _commands(out: Path) -> dict[str, list[str]]:
    return {
        "run": ["run", "--task", "2", "--lockstep", "--no-live", "--out", str(out)],
        "run --emulate-board": ["run", "--task", "2", "--lockstep", "--no-live", "--emulate-board", "--out", str(out)],
        "demo": ["demo", "--no-video", "--lockstep", "--no-live", "--out", str(out)],
        "pose": ["pose", "--pose", "sit"],
        "estop": ["estop"],
        "estop --clear": ["estop", "--clear"],
        "tour": ["tour", "--lockstep", "--out", str(out)],
        "tour --emulate-board": ["tour", "--lockstep", "--emulate-board", "--out", str(out)],
    }


COMMANDS = list(_commands(Path("x")))


def _one_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("command", COMMANDS)
def test_a_virtual_bus_is_refused_at_once(command: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert cli_main([*_commands(out)[command], "--link", "can:virtual:bus0"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "can:virtual:bus0" in line and "virtual bus" in line and "in-process" in line
    assert "can:slcan:pty" in line  # what to use instead
    assert not (out / "board.stderr").exists() and not (out / "host_frames.log").exists()  # nothing was started


# (spec, what the one line must say); each fails when python-can opens the bus, on any machine
BAD_BUSES = [
    ("can:slcan:/dev/nonexistent", "no device '/dev/nonexistent'"),
    ("can:pcan:x", "'pcan' interface cannot be used on this machine"),
    ("can:nosuchiface:x", "python-can has no interface 'nosuchiface'"),
    ("can:socketcan:nosuch0", "can:socketcan:nosuch0: "),  # no SocketCAN here, or no such interface
    ("can:slcan:/dev/null", "'/dev/null' is not a serial device"),
]


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize(("spec", "says"), BAD_BUSES, ids=[s for s, _ in BAD_BUSES])
def test_a_bus_that_cannot_open_is_a_usage_error_everywhere(command: str, spec: str, says: str, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main([*_commands(tmp_path / "out")[command], "--link", spec]) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"cannot open CAN bus {spec}: " in line and says in line, line
    assert "Errno" not in line and "Traceback" not in line, line  # no raw OS / library text


def test_options_the_driver_refuses_are_named(tmp_path: Path) -> None:
    # can:slcan:pty starts the emulated board (a subprocess); python-can's slcan then refuses the options
    r = subprocess.run([sys.executable, "-m", "host.cli", "run", "--task", "2", "--lockstep", "--no-live",
                        "--out", str(tmp_path), "--link", "can:slcan:pty?bitrate=123&tty_baudrate=abc"],
                       capture_output=True, text=True, timeout=100)
    assert r.returncode == 2, r.stdout + r.stderr
    line = _one_line(r.stderr)
    assert "cannot open CAN bus can:slcan:/dev/" in line  # the board's pty the host tried
    assert "python-can's 'slcan' interface refused bitrate=123&tty_baudrate=abc" in line, line
    assert line.endswith("fix those option values (python-can's documentation of the 'slcan' interface lists them)")


def test_the_cause_is_kept(tmp_path: Path) -> None:
    import anyio

    from host.link import BoardClient, LinkConfigError

    async def connect() -> None:
        await BoardClient.connect("can:slcan:/dev/nonexistent", reconnect=False)

    with pytest.raises(LinkConfigError) as info:
        anyio.run(connect, backend="asyncio")
    import can

    assert isinstance(info.value.__cause__, can.CanInitializationError)  # python-can's own error, for debugging
    assert "No such file or directory" in str(info.value.__cause__)
