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
    assert "servo bus torque off" in err and " 0 timeouts, 0 garbled answers" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcomes"] == {"done": 1} or "done" in json.dumps(summary["outcomes"])
