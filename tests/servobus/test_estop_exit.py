"""E-stop on a real servo bus (hold: torque on, holding; limp: torque off, back on at ESTOP_CLEAR from
where the servos are), torque off on every exit (SIGTERM, SIGINT), and bad command lines: exit 2 with
one line (the board's and ``ghostshell run``'s)."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.messages import Ack, Estop, EstopClear, FaultFlags, MsgType, Nack, NackReason, ServoFrame
from tests.servobus.helpers import (
    ARM, MASK, N, ROOT, STEP, Plant, board, eventually, plant_thread, run_board, run_to, stream,
)

PAN = ARM.servos[0]
LIFT = ARM.servos[1]


def _moving(w: object, until_us: int) -> list[float]:
    q = [0.0] * N
    q[PAN.index] = 1.2
    stream(w, q, 0, until_us)  # type: ignore[arg-type]
    return q


def test_estop_hold_keeps_torque_on_and_holds(tmp_path: Path) -> None:
    with plant_thread() as (world, plant, pty, goals):
        w = board(pty, tmp_path)
        try:
            q = _moving(w, 300_000)  # mid-motion at 0.3 s (1.2 rad needs 0.23 s at 300 deg/s + the plant's lag)
            w.send(Estop())
            tel = run_to(w, 800_000)
            torque = [st.torque for st in world.servos]
            seq = w.send(ServoFrame(810_000, MASK, q))
            w.wait(lambda: any(n.ack_seq == seq for n in w.of(Nack)), what="the refusal")
        finally:
            assert w.close() == 130
        assert all(torque)
        assert eventually(lambda: not any(st.torque for st in world.servos))  # exit: torque off on the whole bus
    assert next(n for n in w.of(Nack) if n.ack_seq == seq).reason == NackReason.ESTOPPED
    err = (tmp_path / "board.stderr").read_text()
    assert err.count("board: ESTOP: every servo holds its position, torque on (--estop-torque hold)") == 1, err
    held = [t for t in tel if t.board_time_us >= 400_000]
    assert held and all(t.faults & FaultFlags.ESTOP for t in held)
    pan = [t.positions[PAN.index] for t in held if t.board_time_us >= 500_000]  # settled after the stop
    assert max(pan) - min(pan) < 3 * STEP


def test_estop_limp_switches_torque_off_and_clear_resumes_from_the_measured_pose(tmp_path: Path) -> None:
    with plant_thread() as (world, plant, pty, goals):
        w = board(pty, tmp_path, "--estop-torque", "limp")
        try:
            _moving(w, 300_000)
            w.send(Estop())
            run_to(w, 1_000_000)
            limp = [st.torque for st in world.servos]
            w.send(EstopClear())
            w.wait(lambda: any(isinstance(a, Ack) and a.msg_type == MsgType.ESTOP_CLEAR for a in w.of(Ack)),
                   what="ESTOP_CLEAR's ack")
            n_before = len(goals)
            present = [st.present_steps for st in world.servos]  # no step since the board's last read
            run_to(w, 1_200_000)
            on = [st.torque for st in world.servos]  # the torque write went out before these goal writes
        finally:
            assert w.close() == 130
    assert not any(limp) and all(on)
    first = goals[n_before]  # the first goal after ESTOP_CLEAR: where each servo was, no jump
    for i in range(N):
        assert abs(first[i] - present[i]) <= 3, (i, first[i], present[i])
    err = (tmp_path / "board.stderr").read_text()
    assert "ESTOP limps" in err
    assert err.count("board: ESTOP: every servo's torque is off (--estop-torque limp): the robot goes limp") == 1


def test_sigint_exits_130_with_torque_off(tmp_path: Path) -> None:
    with plant_thread() as (world, plant, pty, goals):
        w = board(pty, tmp_path)
        try:
            _moving(w, 200_000)
            run_to(w, 200_000)
            assert all(st.torque for st in world.servos)
            w.board.proc.send_signal(signal.SIGINT)
            assert w.board.proc.wait(30) == 130
        finally:
            w.close()
        assert eventually(lambda: not any(st.torque for st in world.servos))
    assert "servo bus torque off" in (tmp_path / "board.stderr").read_text()


@pytest.mark.parametrize(("args", "why"), [
    (["--servo-bus", "/dev/no-such-adapter"], "board: servo bus /dev/no-such-adapter: cannot open it at 1000000 baud"),
    (["--servo-bus", "/dev/null"], "board: servo bus /dev/null: /dev/null is not a serial port"),
    (["--servo-bus", "PLANT:abc"], "--servo-bus: baud 'abc' is not a number"),
    (["--servo-bus", "PLANT:12345"], "does not offer that rate"),
    (["--servo-bus", ":1000000"], "expected PORT[:BAUD]"),
    (["--servo-bus", "PLANT:0"], "the baud rate must be > 0"),
    (["--bus-protocol", "dxl2"], "--bus-protocol and --estop-torque need --servo-bus PORT"),
    (["--servo-bus", "PLANT", "--estop-torque", "sideways"], "invalid choice"),
    (["--servo-bus", "PLANT", "--push", "1:0,0,10"], "with --servo-bus the robot is real"),
    (["--servo-bus", "PLANT", "--firmware", "c", "--dead-servo", "3@1"], "no meaning with --servo-bus"),
])
def test_bad_board_command_lines_exit_2_with_one_line(args: list[str], why: str) -> None:
    with Plant() as plant:
        proc = run_board("", *[a.replace("PLANT", plant.pty) for a in args], timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and why in lines[0], lines


@pytest.mark.parametrize(("args", "why"), [
    (["--estop-torque", "limp"], "--bus-protocol and --estop-torque need --servo-bus PORT"),
    (["--servo-bus", "/dev/ttyUSB9", "--link", "/dev/ttyACM7"], "is a board you started"),
    (["--servo-bus", "/dev/ttyUSB9:-5"], "the baud rate must be > 0"),
    (["--servo-bus", "/dev/pts/0:abc"], "--servo-bus: baud 'abc' is not a number"),
    (["--servo-bus", "/dev/ttyUSB9", "--bus-protocol", "can"], "invalid choice"),
])
def test_bad_run_command_lines_exit_2_with_one_line(args: list[str], why: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "host.cli", "run", "--robot", "arm", "--lockstep", *args, "--task", "1"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120, check=False)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1 and why in lines[0], lines


def test_ghostshell_estop_claims_no_hold_of_a_limp_board(tmp_path: Path) -> None:
    """``ghostshell estop`` to a board whose ESTOP lets the servos go limp: its line says the board stops and
    refuses motion (true of hold and limp alike), never that it holds; the board's stderr says limp."""
    from host.link.board_process import start_board

    with Plant(lockstep=False) as plant:
        b = start_board(["--realtime", "--robot", "arm", "--servo-bus", plant.pty, "--estop-torque", "limp"],
                        tmp_path / "board.stderr", timeout=60)
        try:
            proc = subprocess.run([sys.executable, "-m", "host.cli", "estop", "--link", b.port], cwd=ROOT,
                                  capture_output=True, text=True, timeout=60, check=False)
        finally:
            b.stop()
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "ESTOP acknowledged; it stops and refuses motion until" in proc.stdout and "holds" not in proc.stdout
    assert "board: ESTOP: every servo's torque is off (--estop-torque limp)" in (tmp_path / "board.stderr").read_text()
