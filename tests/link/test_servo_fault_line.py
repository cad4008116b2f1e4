"""The host's one line for a board that latched SERVO_FAULT (``host.link.faultcheck.servo_fault_line``).

One wording whichever way the host learns of it: servo id, name and cause as the board's NACK SERVO_FAULT
named them (never "stopped answering" from the flag alone), advice by cause, several silent servos pointing
at the adapter, bus power and cable, and the clear command only for a board that outlives the command.
The end-to-end cases run ``ghostshell run --servo-bus`` against the emulated servo bus (lockstep: the plant's
world time is the board's): a fault latched before the host connected, servos that die mid-run, and a board
the user started (``--link``) that outlives the run."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from host.link.board_process import start_board
from host.link.faultcheck import SEVERAL_SILENT, parse_servo_fault, refusal_message, servo_fault_line
from protocol.messages import MsgType, Nack, NackReason
from tests.servobus.helpers import ARM, ROOT, Plant

ELBOW = ARM.servos[2]  # id 3


def _nack(detail: str) -> Nack:
    return Nack(0, MsgType.SERVO_FRAME, NackReason.SERVO_FAULT, detail)


@pytest.mark.parametrize(("detail", "cause", "torque_off"), [
    ("servo id 3 (elbow_flex) overload; torque off", "overload", True),  # the C firmware's first NACK
    ("servo id 3 (elbow_flex) overload; send ESTOP_CLEAR", "overload", False),  # a refused frame
    ("servo id 3 (elbow_flex) overload", "overload", False),  # the Python board's
    ("servo id 1 (shoulder_pan) stopped answering on the servo bus", "not answering on the servo bus", False),
    ("servo id 1 (shoulder_pan) is not answering; send ESTOP_CLEAR", "not answering on the servo bus", False),
    ("servo id 2 (shoulder_lift) input voltage; torque off", "input voltage", True),
])
def test_both_boards_wordings_parse_to_servo_and_cause(detail: str, cause: str, torque_off: bool) -> None:
    f = parse_servo_fault(detail)
    assert f is not None and (f.cause, f.torque_off) == (cause, torque_off)
    assert parse_servo_fault("") is None and parse_servo_fault("a servo failed on the servo bus") is None


@pytest.mark.parametrize(("detail", "advice", "not_advice"), [
    ("servo id 3 (elbow_flex) overload; torque off", "Free the joint", "power"),
    ("servo id 2 (shoulder_lift) overheating", "Let it cool down", "cable"),
    ("servo id 2 (shoulder_lift) voltage", "Check the servo supply's voltage", "cable"),
    ("servo id 4 (wrist_flex) not answering on the servo bus", "power, its cable and its id", "cool"),
    ("servo id 4 (wrist_flex) garbled answers (checksum errors)", "no two servos share an id", "cool"),
])
def test_the_advice_follows_the_cause(detail: str, advice: str, not_advice: str) -> None:
    line = servo_fault_line([_nack(detail)], 480_000, "/dev/pts/2")
    assert line.startswith("board fault at board time 0.480 s: " + detail.split(";")[0].replace(
        "stopped answering", "not answering"))
    assert advice in line and not_advice not in line, line
    assert line.endswith("then clear it with `ghostshell estop --link /dev/pts/2 --clear`") and "\n" not in line


def test_a_board_the_command_started_is_not_cleared_but_rerun() -> None:
    line = servo_fault_line([_nack("servo id 3 (elbow_flex) overload; torque off")], 480_000, None)
    assert "estop" not in line and "--clear" not in line
    assert line.endswith("then run again: this run stopped the board it started, and the fault with it")
    assert "servo id 3 (elbow_flex) overload (its torque is off)" in line


def test_several_silent_servos_point_at_what_they_share() -> None:
    nacks = [_nack(f"servo id {s.id} ({s.name}) not answering on the servo bus") for s in ARM.servos]
    line = servo_fault_line(nacks + nacks[:2], None, None)  # repeated (refused frames) count once
    assert line.startswith("board fault: servo ids 1 (shoulder_pan), 2 (shoulder_lift), 3 (elbow_flex), ")
    assert SEVERAL_SILENT[1:] in line and "that servo" not in line and "\n" not in line


def test_the_flag_alone_invents_no_servo_and_no_cause() -> None:
    """Over CAN a NACK carries the reason code only: the line says the board did not name it."""
    line = servo_fault_line([Nack(0, MsgType.SERVO_FRAME, NackReason.SERVO_FAULT)], 20_000, None)
    assert "stopped answering" not in line and "not answering" not in line and "cable" not in line
    assert "without naming the servo or the cause" in line


def test_a_refused_frame_reads_the_same() -> None:
    nack = _nack("servo id 3 (elbow_flex) overload; send ESTOP_CLEAR")
    assert refusal_message(nack, "SPEC") == servo_fault_line([nack], None, "SPEC")


def _run(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "host.cli", "run", "--robot", "arm", "--lockstep", "--task", "2", "--no-plots",
         "--no-live", "--quiet", "--out", str(tmp_path / "run"), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=300, check=False)


def _last_line(proc: subprocess.CompletedProcess[str]) -> str:
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.startswith("ghostshell run: ")]
    assert lines, proc.stdout + proc.stderr
    return lines[-1]


def test_a_fault_latched_before_the_host_connected_is_named(tmp_path: Path) -> None:
    """The user's report: the overload latched at boot, its unsolicited NACK went to no host; the run asks
    the board (a refused frame names it) instead of saying that a servo stopped answering."""
    with Plant("--error", f"{ELBOW.id}=overload@0") as plant:
        proc = _run(tmp_path, "--servo-bus", plant.pty)
    assert proc.returncode != 0
    line = _last_line(proc)
    assert f"servo id {ELBOW.id} ({ELBOW.name}) overload (its torque is off)" in line, line
    assert "Free the joint" in line and "answering" not in line and "cable" not in line
    assert "--clear" not in line and line.endswith("run again: this run stopped the board it started, and the fault with it")


def test_every_servo_silent_mid_run_names_them_all(tmp_path: Path) -> None:
    dead = [a for s in ARM.servos for a in ("--dead-servo", f"{s.id}@1.0")]
    with Plant(*dead) as plant:
        proc = _run(tmp_path, "--servo-bus", plant.pty)
    assert proc.returncode != 0
    line = _last_line(proc)
    assert "servo ids 1 (shoulder_pan), 2 (shoulder_lift), 3 (elbow_flex), 4 (wrist_flex), 5 (wrist_roll), " \
           "6 (gripper) not answering on the servo bus" in line, line
    assert SEVERAL_SILENT[1:] in line and "--clear" not in line


def test_a_board_the_user_started_outlives_the_run_and_is_cleared(tmp_path: Path) -> None:
    with Plant("--error", f"{ELBOW.id}=overheat@0") as plant:
        board = start_board(["--lockstep", "--robot", "arm", "--servo-bus", plant.pty], tmp_path / "board.stderr")
        try:
            proc = _run(tmp_path, "--link", str(board.spec))
        finally:
            board.stop()
    line = _last_line(proc)
    assert f"servo id {ELBOW.id} ({ELBOW.name}) overheating (its torque is off)" in line, line
    assert "Let it cool down" in line and line.endswith(f"then clear it with `ghostshell estop --link {board.spec} --clear`")
