"""``python -m firmware_sim.plant --protocol dxl2 --baud 57600 --lockstep ...`` as a separate process: it
prints ``plant: servo bus on /dev/pts/N``, ROBOTIS's SDK finds the servos there (the injected
conditions from the command line applied), and SIGTERM ends it cleanly with its bus summary."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from dynamixel_sdk import COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler, PortHandler

from firmware_sim.plant.dxl_table import ADDR, MODEL_XL330, MODEL_XM430
from firmware_sim.plant.server import main

ROOT = Path(__file__).resolve().parents[2]


def test_plant_command_line_serves_dynamixels_with_conditions() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim.plant", "--protocol", "dxl2", "--baud", "57600", "--lockstep",
         "--missing", "2", "--model", "3=1020", "--offset", "4=100", "--error", "5=overheat@0"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "MUJOCO_GL": "egl"})
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("plant: servo bus on /dev/pts/"), line
        port = PortHandler(line.split(" on ", 1)[1].strip())
        assert port.openPort() and port.setBaudRate(57600)
        ph = PacketHandler(2.0)
        assert ph.ping(port, 1)[1:] == (COMM_SUCCESS, 0)
        assert ph.ping(port, 2)[1] == COMM_RX_TIMEOUT
        assert ph.ping(port, 3)[0] == MODEL_XM430
        assert ph.read4ByteTxRx(port, 4, ADDR.PRESENT_POSITION)[0] - ph.read4ByteTxRx(port, 6, ADDR.PRESENT_POSITION)[0] \
            in range(95, 106)  # both at neutral (CoCo's hips and knees): only the offset differs, +-rounding
        value, result, error = ph.read1ByteTxRx(port, 5, ADDR.HARDWARE_ERROR)
        assert result == COMM_SUCCESS and value == 0x04 and error & 0x80
        port.closePort()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "plant: servo bus:" in err


@pytest.mark.parametrize("argv, says", [
    (["--protocol", "dxl3"], "invalid choice"),
    (["--error", "3=melted@1"], "expected ID=overload|overheat|voltage@SECONDS"),
    (["--offset", "x=1"], "expected ID=NUMBER"),
])
def test_bad_command_lines_are_refused(argv: list[str], says: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2 and says in capsys.readouterr().err


def test_a_bad_probability_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--corrupt", "1.5"]) == 2
    assert "corrupt must be a probability" in capsys.readouterr().err


def test_protocol_baud_and_models_default_to_the_robots_hardware_toml(tmp_path: Path) -> None:
    """A robot whose ``hardware.toml`` says Dynamixel at 57 600 with XM430s and one XL330: the plant
    serves exactly that without ``--protocol`` or ``--baud``."""
    shutil.copytree(ROOT / "robots" / "arm", tmp_path / "myarm", ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "myarm" / "hardware.toml").write_text(
        'protocol = "dxl2"\nbaud = 57600\nmodel = 1020\n[models]\ngripper = 1200\n')
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim.plant", "--robot", "myarm", "--robots-dir", str(tmp_path),
                             "--lockstep"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "MUJOCO_GL": "egl"})
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("plant: servo bus on /dev/pts/"), (line, proc.stderr.read() if proc.poll() is not None else "")
        port = PortHandler(line.split(" on ", 1)[1].strip())
        assert port.openPort() and port.setBaudRate(57600)
        ph = PacketHandler(2.0)
        assert ph.ping(port, 1)[:2] == (MODEL_XM430, COMM_SUCCESS)
        assert ph.ping(port, 6)[:2] == (MODEL_XL330, COMM_SUCCESS)  # the gripper
        port.closePort()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
