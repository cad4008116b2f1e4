"""``ghostshell robots calibrate`` as a real subprocess: every argument error, a built-in or read-only
package and a port that cannot be opened are one line on stderr and exit status 2, before any servo is
touched; nothing is written. (The procedure itself: tests/cli/test_calibrate.py.)"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from robots.hardware import CALIBRATION_FILE
from robots.registry import BUILTIN_DIR
from support.robot_samples import cli, one_line_error

PREFIX = "ghostshell robots calibrate: error: "


@pytest.fixture
def user_arm(tmp_path: Path) -> Path:
    d = tmp_path / "robots"
    shutil.copytree(BUILTIN_DIR / "arm", d / "arm", ignore=shutil.ignore_patterns("__pycache__"))
    return d


def _calibrate(tmp_path: Path, *args: str) -> str:
    return one_line_error(cli("robots", "calibrate", *args, data_home=tmp_path, timeout=120))


def test_the_servo_bus_is_required(tmp_path: Path, user_arm: Path) -> None:
    line = _calibrate(tmp_path, "arm", "--robots-dir", str(user_arm))
    assert line.startswith(PREFIX) and "--servo-bus" in line, line


@pytest.mark.parametrize("spec, why", [
    ("/dev/ttyUSB0:300", "baud 300 is outside 9600..4500000"),
    (":1000000", "no port"),
])
def test_a_bad_servo_bus_spec(tmp_path: Path, user_arm: Path, spec: str, why: str) -> None:
    line = _calibrate(tmp_path, "arm", "--servo-bus", spec, "--robots-dir", str(user_arm))
    assert line.startswith(PREFIX + "argument --servo-bus") and why in line, line


def test_a_bad_protocol(tmp_path: Path, user_arm: Path) -> None:
    line = _calibrate(tmp_path, "arm", "--servo-bus", "/dev/null", "--bus-protocol", "dxl1", "--robots-dir", str(user_arm))
    assert line.startswith(PREFIX + "argument --bus-protocol: invalid choice: 'dxl1'"), line


def test_a_missing_robots_dir(tmp_path: Path) -> None:
    line = _calibrate(tmp_path, "arm", "--servo-bus", "/dev/null", "--robots-dir", str(tmp_path / "nope"))
    assert line.startswith(PREFIX + "argument --robots-dir") and "no such folder" in line, line


def test_an_unknown_robot(tmp_path: Path, user_arm: Path) -> None:
    line = _calibrate(tmp_path, "nosuchrobot", "--servo-bus", "/dev/null", "--robots-dir", str(user_arm))
    assert line.startswith("ghostshell robots: ") and "nosuchrobot" in line, line


def test_a_built_in_robot_is_refused_with_the_copy_to_make(tmp_path: Path) -> None:
    line = _calibrate(tmp_path, "arm", "--servo-bus", "/dev/null")
    user_dir = tmp_path / "ghostshell" / "robots"
    assert line == (f"ghostshell robots: arm is a built-in robot ({BUILTIN_DIR / 'arm'}), shared and replaced on "
                    f"upgrade: calibrate your own copy of it, found first under the same name: "
                    f"cp -r {BUILTIN_DIR / 'arm'} {user_dir}/"), line
    assert not (BUILTIN_DIR / "arm" / CALIBRATION_FILE).exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write a read-only folder")
def test_a_read_only_package_is_refused(tmp_path: Path, user_arm: Path) -> None:
    folder = user_arm / "arm"
    folder.chmod(0o555)
    try:
        line = _calibrate(tmp_path, "arm", "--servo-bus", "/dev/null", "--robots-dir", str(user_arm))
    finally:
        folder.chmod(0o755)
    assert line == f"ghostshell robots: {folder / CALIBRATION_FILE}: not writable (calibration.toml is written into the robot's folder)"


def test_a_port_that_cannot_be_opened(tmp_path: Path, user_arm: Path) -> None:
    port = tmp_path / "ttyUSB9"
    line = _calibrate(tmp_path, "arm", "--servo-bus", f"{port}:1000000", "--robots-dir", str(user_arm))
    assert line.startswith(f"ghostshell robots: {port}: cannot open the servo bus"), line
    assert not (user_arm / "arm" / CALIBRATION_FILE).exists()


def test_a_protocol_that_contradicts_hardware_toml(tmp_path: Path, user_arm: Path) -> None:
    hw = user_arm / "arm" / "hardware.toml"
    hw.write_text('protocol = "sts"\n')
    line = _calibrate(tmp_path, "arm", "--servo-bus", "/dev/null", "--bus-protocol", "dxl2", "--robots-dir", str(user_arm))
    assert line == (f"ghostshell robots: {hw} says protocol = 'sts', --bus-protocol dxl2: fix hardware.toml or drop "
                    "--bus-protocol"), line


def test_a_broken_hardware_toml(tmp_path: Path, user_arm: Path) -> None:
    hw = user_arm / "arm" / "hardware.toml"
    hw.write_text('protocol = "can"\n')
    line = _calibrate(tmp_path, "arm", "--servo-bus", "/dev/null", "--robots-dir", str(user_arm))
    assert line.startswith(f"ghostshell robots: {hw}: protocol must be one of sts, dxl2"), line


def test_a_read_only_package_is_refused_even_for_root(tmp_path: Path, user_arm: Path,
                                                      monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """In-process, with the folder reported read-only (root writes a chmod 555 folder anyway)."""
    import host.cli
    import host.commands.calibrate as calibrate

    folder = (user_arm / "arm").resolve()
    monkeypatch.setattr(calibrate.os, "access", lambda path, mode: Path(path) != folder)
    status = host.cli.main(["robots", "calibrate", "arm", "--servo-bus", "/dev/null", "--robots-dir", str(user_arm)])
    err = capsys.readouterr().err.splitlines()
    assert status == 2 and err == [f"ghostshell robots: {folder / CALIBRATION_FILE}: not writable "
                                   "(calibration.toml is written into the robot's folder)"], err
