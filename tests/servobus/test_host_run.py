"""``ghostshell run --servo-bus PTY --bus-protocol P --estop-torque E``: the options reach the board the run
starts, which drives the plant's servos; the run completes and the board ends with torque off."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.servobus.helpers import ROOT, Plant


@pytest.mark.parametrize(("protocol", "estop"), [("sts", "hold"), ("dxl2", "limp")])
def test_run_drives_the_servo_bus(tmp_path: Path, protocol: str, estop: str) -> None:
    out = tmp_path / "run"
    with Plant(protocol=protocol) as plant:
        proc = subprocess.run(
            [sys.executable, "-m", "host.cli", "run", "--robot", "arm", "--lockstep", "--task", "1", "--no-plots",
             "--out", str(out), "--servo-bus", plant.pty, "--bus-protocol", protocol, "--estop-torque", estop],
            cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    err = (out / "board.stderr").read_text()
    assert f"({protocol}, 1000000 baud" in err and "6 servos answer, torque on" in err, err
    assert f"ESTOP {estop}s" in err
    assert "servo bus torque off" in err and " 0 garbled answers" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcomes"] == {"done": 1} or "done" in json.dumps(summary["outcomes"])
    # real servos were driven: summary.json records which and how it went (the board's exit line)
    bus = summary["extra"]["servo_bus"]
    assert {k: bus[k] for k in ("port", "protocol", "baud", "servos")} == {
        "port": plant.pty, "protocol": protocol, "baud": 1_000_000, "servos": 6}
    # a healthy bus: no fault, no garbled answer; a machine loaded by other work may stall the plant past
    # the lockstep board's 200 ms answer wait now and then (a whole sync read), never three reads in a row
    assert bus["checksum_errors"] == 0 and bus["faults"] == 0, bus
    assert bus["timeouts"] <= bus["reads"] * bus["servos"] // 100, bus
    assert bus["bus_period_ticks"] >= 1 and bus["bus_period_ms"] == 2.0 * bus["bus_period_ticks"]
    assert bus["goal_writes"] > 0


def test_run_says_the_servo_bus_is_the_problem_not_the_link(tmp_path: Path) -> None:
    """A servo bus the board cannot use (Dynamixel pings to Feetech servos): ``ghostshell run``'s one line
    names the servo bus (not "cannot serve pty", a --link problem) and says nothing answers in that protocol."""
    with Plant(protocol="sts") as plant:
        proc = subprocess.run(
            [sys.executable, "-m", "host.cli", "run", "--robot", "arm", "--lockstep", "--task", "1", "--no-plots",
             "--out", str(tmp_path / "run"), "--servo-bus", plant.pty, "--bus-protocol", "dxl2"],
            cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"ghostshell run: the board cannot use its servo bus {plant.pty}: no servo answers a "
                               "ping (6 servos, ids 1, 2, 3, 4, 5, 6)"), lines
    assert "in dxl2 at 1000000 baud: check the protocol" in lines[0] and "cannot serve" not in lines[0]
