"""Bus faults on the board's real-servo path: each kind the plant injects ends in the right one line.

Start-up (``--missing``, ``--duplicate``, ``--model``): exit 2, one stderr line naming servo id and name,
torque never on. Running (``--error ID=overload|overheat|voltage@S``, ``--dead-servo ID@S``, ``--corrupt P``):
SERVO_FAULT in telemetry, one unsolicited NACK SERVO_FAULT whose detail names the servo (what
``host.link.faultcheck`` shows), the stderr line ``board: servo 3 (elbow_flex): overload ...``, every servo
holds, frames refused; an overloaded or overheated servo's torque goes off."""

from __future__ import annotations

from pathlib import Path

import pytest

from host.link.faultcheck import refusal_message
from protocol.messages import FaultFlags, Nack, NackReason, ServoFrame, Telemetry
from tests.servobus.helpers import ARM, MASK, N, Plant, board, eventually, plant_thread, run_board, run_to, stream

ELBOW = ARM.servos[2]  # id 3


@pytest.mark.parametrize(("flag", "servo", "why"), [
    ("--missing", ARM.servos[2], "does not answer a ping (missing, unpowered, or another id, baud or protocol)"),
    ("--duplicate", ARM.servos[1], "answers a ping"),
    ("--model", ARM.servos[3], "reports model number 1200, the robot's hardware.toml says 777"),
])
def test_start_up_refuses_a_bad_bus_with_one_line(flag: str, servo: object, why: str) -> None:
    value = f"{servo.id}=1200" if flag == "--model" else str(servo.id)  # type: ignore[attr-defined]
    with Plant(flag, value) as plant:
        proc = run_board(plant.pty)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"board: servo bus {plant.pty}: servo {servo.id} ({servo.name}) ")  # type: ignore[attr-defined]
    assert why in lines[0]
    assert "torque left off" in lines[0]
    assert "listening" not in proc.stdout


def test_start_up_failure_leaves_torque_off(tmp_path: Path) -> None:
    from firmware_sim.plant.conditions import Conditions

    with plant_thread(conditions=Conditions(missing=frozenset({6}))) as (world, plant, pty, goals):
        proc = run_board(pty)
        assert proc.returncode == 2 and "servo 6 (gripper) does not answer" in proc.stderr
        assert eventually(lambda: not any(st.torque for st in world.servos[:5]))
        assert not goals  # not one goal written


@pytest.mark.parametrize(("spec", "what", "torque_off"), [
    ("overload", "overload", True),
    ("overheat", "overheating", True),
    ("voltage", "voltage", False),
])
def test_servo_error_bits_latch_servo_fault(tmp_path: Path, spec: str, what: str, torque_off: bool) -> None:
    _runtime_fault(tmp_path, ["--error", f"{ELBOW.id}={spec}@0.2"], what, torque_off)


def test_a_servo_that_stops_answering_latches_servo_fault(tmp_path: Path) -> None:
    _runtime_fault(tmp_path, ["--dead-servo", f"{ELBOW.id}@0.2"], "not answering on the servo bus", False)


def test_dxl2_overload(tmp_path: Path) -> None:
    _runtime_fault(tmp_path, ["--error", f"{ELBOW.id}=overload@0.2"], "overload", True, protocol="dxl2")


def test_checksum_errors_latch_servo_fault(tmp_path: Path) -> None:
    """A noisy line (a status packet in four garbled): start-up asks again; three garbled answers in a row from
    one servo latch the fault, naming it."""
    with Plant("--corrupt", "0.25", "--seed", "3") as plant:
        w = board(plant.pty, tmp_path)
        try:
            stream(w, [0.0] * N, 0, 1_000_000)
            w.wait(lambda: any(n.reason == NackReason.SERVO_FAULT for n in w.of(Nack)), what="NACK SERVO_FAULT")
        finally:
            assert w.close() == 130
    nack = next(n for n in w.of(Nack) if n.reason == NackReason.SERVO_FAULT)
    assert "garbled answers (checksum errors)" in nack.detail
    err = (tmp_path / "board.stderr").read_text()
    assert "): garbled answers (checksum errors) at board time" in err


def _runtime_fault(tmp_path: Path, plant_args: list[str], what: str, torque_off: bool, protocol: str = "sts") -> None:
    with Plant(*plant_args, protocol=protocol) as plant:
        w = board(plant.pty, tmp_path, "--bus-protocol", protocol)
        try:
            q = ARM.pose(ARM.start_pose)
            stream(w, list(q), 0, 400_000)
            tel = run_to(w, 1_000_000)
            seq = w.send(ServoFrame(1_010_000, MASK, list(q)))
            w.wait(lambda: any(n.ack_seq == seq for n in w.of(Nack)), what="the refusal")
        finally:
            assert w.close() == 130
    detail = f"servo id {ELBOW.id} ({ELBOW.name}) {what}"
    nacks = [n for n in w.of(Nack) if n.reason == NackReason.SERVO_FAULT]
    assert nacks[0].detail.startswith(detail[:64]), nacks[0]
    assert next(n for n in w.of(Nack) if n.ack_seq == seq).reason == NackReason.SERVO_FAULT
    faulted = [t for t in tel if t.faults & FaultFlags.SERVO_FAULT]
    assert faulted and not tel[0].faults & FaultFlags.SERVO_FAULT
    assert 200_000 <= faulted[0].board_time_us <= 200_000 + 4 * 20_000 + 300_000  # lockstep: the plant's time
    held = [t.positions for t in tel if t.board_time_us > faulted[0].board_time_us + 300_000]
    assert len(held) >= 5
    for i in range(N):
        if i != ELBOW.index or not torque_off:
            assert max(p[i] for p in held) - min(p[i] for p in held) < 0.01, i
    line = refusal_message(nacks[0], "pty")
    assert line is not None and detail[:40] in line and "\n" not in line
    err = (tmp_path / "board.stderr").read_text()
    mine = [x for x in err.splitlines() if x.startswith(f"board: servo {ELBOW.id} ({ELBOW.name}): {what}")]
    assert len(mine) == 1, err
    assert ("its torque is off" in mine[0]) == torque_off
