"""The command line on CAN links: the issue's acceptance command, and clear refusals."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(180)


def _run(*args: str, timeout: float = 150) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host.cli", *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_task_26_over_slcan_lockstep(tmp_path: Path) -> None:
    r = _run("run", "--task", "26", "--link", "can:slcan:pty", "--lockstep", "--out", str(tmp_path))
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    s = json.loads((tmp_path / "summary.json").read_text())
    why = json.dumps(s)[:3000] + r.stdout[-1500:]
    assert s["outcome"] == "done" and s["outcomes"]["done"] == 11, why
    assert s["extra"]["link"]["decode_errors"] == 0, why
    assert s["base_end"][0] - s["base_start"][0] > 0.05, why  # the two strides happened (8 cm over the pty too)
    d = _run("log", "decode", str(tmp_path / "host_frames.log"), "--type", "SERVO_FRAME", timeout=60)
    assert d.returncode == 0, d.stderr[-500:]
    assert d.stdout.count("SERVO_FRAME") == s["extra"]["link"]["frames_sent"], d.stderr[-500:]


def test_virtual_bus_is_refused_for_a_board_process(tmp_path: Path) -> None:
    r = _run("run", "--task", "26", "--link", "can:virtual:x", "--emulate-board", "--lockstep", "--out", str(tmp_path))
    assert r.returncode != 0 and "virtual bus" in (r.stdout + r.stderr)
    b = subprocess.run([sys.executable, "-m", "firmware_sim", "--link", "can:virtual:x", "--lockstep"],
                       capture_output=True, text=True, timeout=60)
    assert b.returncode == 2 and "in-process virtual bus" in b.stderr
