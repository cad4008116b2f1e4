"""The Python board drives the plant's emulated servos over a real pty as it would drive real ones
(``python -m firmware_sim --servo-bus PTY``): a joint follows a frame, telemetry shows the measured
angle, the start-up begins at the measured pose (no jump), no goal outside the calibrated step limits
reaches the bus, Feetech STS at 1 Mbaud and Dynamixel Protocol 2.0 at 57 600 and 1 Mbaud, lockstep
and realtime. Waits are on board time (lockstep) or telemetry, never sleeps."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pytest

from protocol.messages import FaultFlags, Telemetry
from robots.registry import load_robot
from tests.servobus.helpers import ARM, N, STEP, Plant, board, plant_thread, run_to, stream

PAN = ARM.servos[0]  # shoulder_pan, id 1


@pytest.mark.parametrize(("protocol", "baud"), [("sts", 1_000_000), ("dxl2", 57_600), ("dxl2", 1_000_000)])
def test_a_joint_follows_and_telemetry_shows_the_measured_angle(tmp_path: Path, protocol: str, baud: int) -> None:
    with Plant(protocol=protocol, baud=baud) as plant:
        w = board(f"{plant.pty}:{baud}", tmp_path, "--bus-protocol", protocol)
        try:
            q = [0.0] * N
            q[PAN.index] = 0.5
            stream(w, q, 0, 1_000_000)
            tel = run_to(w, 1_000_000)
        finally:
            assert w.close() == 130
    last = tel[-1]
    assert abs(last.positions[PAN.index] - 0.5) < math.radians(1.5), last.positions
    assert abs(tel[0].positions[PAN.index]) < math.radians(1)  # the plant started at neutral
    # ramped at the servo table's speed (plus the plant's lag), never a jump
    v = PAN.max_speed
    for a, b in zip(tel, tel[1:]):
        dt = (b.board_time_us - a.board_time_us) / 1e6
        assert abs(b.positions[PAN.index] - a.positions[PAN.index]) <= v * dt * 1.2 + 3 * STEP
    err = (tmp_path / "board.stderr").read_text()
    assert f"({protocol}, {baud} baud" in err and f"{N} servos answer, torque on" in err
    if protocol == "dxl2":
        assert "one sync read through indirect addresses" in err  # hardware error status in the same read
    assert "servo bus torque off" in err


def test_start_up_begins_at_the_measured_pose(tmp_path: Path) -> None:
    """The plant's shoulder_pan reads 300 steps (26 deg) off neutral: the board's first goal is that
    position, and a frame to 0 rad is reached at the servo table's speed from there."""
    from firmware_sim.plant.conditions import Conditions

    with plant_thread(conditions=Conditions(offsets={PAN.id: 300})) as (world, plant, pty, goals):
        w = board(pty, tmp_path)
        try:
            tel = run_to(w, 40_000)  # no frames yet: holds where it is
            assert abs(tel[0].positions[PAN.index] - PAN.direction * 300 * STEP) < 2 * STEP
            stream(w, [0.0] * N, 40_000, 1_000_000)
            tel = run_to(w, 1_000_000)
        finally:
            assert w.close() == 130
    first = goals[0]
    assert abs(first[PAN.index] - (2048 + 300)) <= 1, first  # the measured pose, no jump
    max_step = PAN.max_speed * 0.002 / STEP
    for a, b in zip(goals, goals[1:]):
        assert abs(b[PAN.index] - a[PAN.index]) <= max_step + 1, (a, b)
    assert abs(tel[-1].positions[PAN.index]) < math.radians(1.5)


def test_no_goal_outside_the_calibrated_range_reaches_the_bus(tmp_path: Path) -> None:
    """calibration.toml narrows shoulder_pan to steps 1700..2400 (the joint allows 796..3300): frames far
    beyond the joint range on both sides; every goal register the plant got stays inside 1700..2400."""
    folder = tmp_path / "arm"
    shutil.copytree(ARM.root, folder, ignore=shutil.ignore_patterns("__pycache__"))
    (folder / "calibration.toml").write_text(
        "[servo.shoulder_pan]\nid = 1\noffset_steps = 0\ndirection = 1\nmin_steps = 1700\nmax_steps = 2400\n")
    robot = load_robot(str(folder))
    with plant_thread(robot) as (world, plant, pty, goals):
        w = board(pty, tmp_path, "--robot", str(folder))
        try:
            q = [0.0] * N
            for k, target in enumerate((3.0, -3.0, 3.0)):
                q[PAN.index] = target
                stream(w, q, k * 600_000, (k + 1) * 600_000)
            tel = run_to(w, 1_800_000)
        finally:
            assert w.close() == 130
    pan = [g[PAN.index] for g in goals]
    assert min(pan) == 1700 and max(pan) == 2400, (min(pan), max(pan))
    assert any(t.faults & FaultFlags.CLAMPED for t in tel)
    assert tel[-1].positions[PAN.index] == pytest.approx((2400 - 2048) * STEP, abs=math.radians(1.5))


def test_realtime_board_on_a_realtime_plant(tmp_path: Path) -> None:
    with Plant(lockstep=False) as plant:
        w = board(plant.pty, tmp_path, "--realtime", "--watchdog-ms", "10000")
        try:
            w.wait(lambda: bool(w.of(Telemetry)), what="the first telemetry")
            t0 = w.of(Telemetry)[-1].board_time_us
            q = [0.0] * N
            q[PAN.index] = -0.4
            stream(w, q, t0 + 100_000, t0 + 600_000)
            w.wait(lambda: w.of(Telemetry)[-1].board_time_us > t0 + 1_200_000, what="1.2 s of board time")
        finally:
            assert w.close() == 130
    assert abs(w.of(Telemetry)[-1].positions[PAN.index] + 0.4) < math.radians(2)


def test_the_calibration_maps_angles_to_the_servos_raw_steps(tmp_path: Path) -> None:
    """The plant's shoulder_pan is mounted 300 steps off centre and the other way round (an uncalibrated servo);
    calibration.toml says so: the board reads it at neutral and moves the real joint to the commanded angle."""
    from firmware_sim.plant.conditions import Conditions

    folder = tmp_path / "arm"
    shutil.copytree(ARM.root, folder, ignore=shutil.ignore_patterns("__pycache__"))
    (folder / "calibration.toml").write_text(
        "[servo.shoulder_pan]\nid = 1\noffset_steps = 300\ndirection = -1\nmin_steps = 0\nmax_steps = 4095\n")
    robot = load_robot(str(folder))
    with plant_thread(robot, conditions=Conditions(offsets={PAN.id: 300}, reversed=frozenset({PAN.id}))) as (
            world, plant, pty, goals):
        w = board(pty, tmp_path, "--robot", str(folder))
        try:
            tel = run_to(w, 40_000)
            assert abs(tel[0].positions[PAN.index]) < 2 * STEP  # neutral, as the plant's joint is
            q = [0.0] * N
            q[PAN.index] = 0.5
            stream(w, q, 40_000, 1_000_000)
            tel = run_to(w, 1_000_000)
            joint = float(world.positions()[PAN.index])
        finally:
            assert w.close() == 130
    assert abs(joint - 0.5) < math.radians(1.5), joint  # the real joint went there
    assert abs(tel[-1].positions[PAN.index] - 0.5) < math.radians(1.5)
    assert goals[-1][PAN.index] == pytest.approx(2048 + 300 - round(0.5 / STEP), abs=1)


def test_the_c_firmware_gets_the_servo_bus_options(tmp_path: Path) -> None:
    """``--firmware c --servo-bus PTY --estop-torque limp``: firmware_sim/cli.py hands port, baud, protocol and
    e-stop flavour to the C launcher (LaunchOptions), whose firmware then drives the plant's servos."""
    with Plant() as plant:
        w = board(f"{plant.pty}:1000000", tmp_path, "--firmware", "c", "--estop-torque", "limp")
        try:
            q = [0.0] * N
            q[PAN.index] = 0.5
            stream(w, q, 0, 600_000)
            tel = run_to(w, 600_000)
        finally:
            assert w.close() == 130
    assert abs(tel[-1].positions[PAN.index] - 0.5) < math.radians(1.5)
    assert "(sts, 1000000 baud)" in (tmp_path / "board.stderr").read_text()
