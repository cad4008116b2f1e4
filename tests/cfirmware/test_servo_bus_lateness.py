"""Realtime under load: a plant that falls behind is lateness, a servo that is gone is still a dead servo.

The native C firmware runs realtime against the servo-bus plant, which lives in the board process
(``python -m firmware_sim --firmware c``: firmware_sim/cfirmware/launcher.py); the firmware is its own
process with its own host pty, so while the board process is stopped (SIGSTOP: what a loaded machine
does to a descheduled emulator, only longer) the firmware keeps ticking and reporting, and the test
waits on its board clock, not on sleeps. Before issue 41 half a second of silence latched SERVO_FAULT
("servo id N stopped answering"); now the silent reads are counted as stalls and the late answers as
late replies (the ``board: realtime lateness {json}`` line), and only a servo that stays silent while
the rest of the bus answers is lost.
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from types import SimpleNamespace

import pytest

from firmware_sim.cfirmware.launcher import LATENESS_PREFIX
from host.link.faultcheck import servo_fault_message
from host.run.realtime_health import realtime_behind
from protocol.messages import FaultFlags, Nack, NackReason, Telemetry
from robots.registry import load_robot

from .wire import Wire

pytestmark = [pytest.mark.timeout(120, method="thread"), pytest.mark.realtime]

ROBOT = load_robot("coco")
DEAD = ROBOT.servos[2]  # id 3
STOP_US = 500_000  # how long the plant is stopped (board clock)


def _lateness(stderr: Path) -> dict[str, int]:
    lines = [ln for ln in stderr.read_text().splitlines() if ln.startswith(LATENESS_PREFIX)]
    assert len(lines) == 1, lines
    rec: dict[str, int] = json.loads(lines[0][len(LATENESS_PREFIX):])
    return rec


def _latest_us(w: Wire) -> int:
    tel = w.of(Telemetry)
    return tel[-1].board_time_us if tel else -1


def test_a_stopped_plant_is_lateness_not_a_dead_servo(tmp_path: Path) -> None:
    w = Wire(["--firmware", "c"], tmp_path / "board.stderr")
    try:
        w.wait(lambda: _latest_us(w) >= 200_000, what="0.2 s of telemetry")
        stopped_at = _latest_us(w)
        os.kill(w.board.proc.pid, signal.SIGSTOP)  # the plant (and the launcher around it) stops
        try:  # the firmware keeps reporting on its own pty meanwhile: wait on its clock
            w.wait(lambda: _latest_us(w) >= stopped_at + STOP_US, what="0.5 s of board time with the plant stopped")
        finally:
            os.kill(w.board.proc.pid, signal.SIGCONT)
        resumed_at = _latest_us(w)
        w.wait(lambda: _latest_us(w) >= resumed_at + 1_000_000, what="1 s of telemetry after the plant resumed")
        tel = w.of(Telemetry)
        assert not [t.board_time_us for t in tel if t.faults & FaultFlags.SERVO_FAULT]
        assert not [n for n in w.of(Nack) if n.reason == NackReason.SERVO_FAULT]
    finally:
        assert w.close() == 130
    err = (tmp_path / "board.stderr").read_text()
    assert "stopped answering" not in err
    rec = _lateness(tmp_path / "board.stderr")
    # the stop was seen and told as lateness: the plant's own lag about as long as it was stopped; the
    # firmware saw reads unanswered or answered late (or, when its bus writes filled the stopped plant's pty
    # and blocked it, fell behind and skipped ticks), and the host's decision calls the run behind
    assert rec["plant_behind_max_ms"] >= 0.8 * STOP_US / 1000, rec
    assert rec["bus_stalls"] + rec["bus_late_replies"] + rec["board_ticks_skipped"] > 0, rec
    behind = realtime_behind({"frames_sent": 0, "late": 0}, rec)
    assert behind is not None and behind["suggest"] == "--lockstep", rec
    # ... and the board says so in one warning line (`ghostshell run` repeats a board's warnings at its end)
    warnings = [ln for ln in err.splitlines() if ln.startswith("board: warning: realtime emulation could not keep up")]
    assert len(warnings) == 1 and "the plant fell up to" in warnings[0] and "--lockstep" in warnings[0], warnings


def test_a_removed_servo_is_still_a_dead_servo(tmp_path: Path) -> None:
    w = Wire(["--firmware", "c", "--dead-servo", f"{DEAD.id}@0.3"], tmp_path / "board.stderr")
    try:
        w.wait(lambda: any(n.reason == NackReason.SERVO_FAULT for n in w.of(Nack)), what="the NACK SERVO_FAULT")
        nack = next(n for n in w.of(Nack) if n.reason == NackReason.SERVO_FAULT)
        assert f"servo id {DEAD.id} ({DEAD.name}) stopped answering" in nack.detail
        w.wait(lambda: any(t.faults & FaultFlags.SERVO_FAULT for t in w.of(Telemetry)), what="SERVO_FAULT reported")
        first = next(t.board_time_us for t in w.of(Telemetry) if t.faults & FaultFlags.SERVO_FAULT)
        # world time (the plant's) and board time both follow the wall clock: found within a few read rounds
        # (5 misses, one per telemetry period) of its death, plus what a loaded machine adds
        assert 300_000 <= first <= 1_500_000, first
        line = servo_fault_message(SimpleNamespace(servo_fault=nack, link_spec="pty"), first)  # type: ignore[arg-type]
        assert f"servo id {DEAD.id} ({DEAD.name})" in line and "\n" not in line
    finally:
        assert w.close() == 130
    err = (tmp_path / "board.stderr").read_text()
    assert f"board: servo id {DEAD.id} ({DEAD.name}) stopped answering on the servo bus" in err


def test_a_servo_dead_at_boot_is_found_at_boot(tmp_path: Path) -> None:
    """Realtime boot pings a silent servo again (a plant still starting answers late) but, while the rest of the
    bus answers, gives up after a few pings: the servo is reported from the first report on, not after the
    10 s a silent bus is given."""
    w = Wire(["--firmware", "c", "--dead-servo", f"{DEAD.id}@0"], tmp_path / "board.stderr")
    try:
        w.wait(lambda: bool(w.of(Telemetry)), what="the first report")
        assert w.of(Telemetry)[0].faults & FaultFlags.SERVO_FAULT
        assert w.of(Telemetry)[0].board_time_us < 2_000_000
    finally:
        assert w.close() == 130
    err = (tmp_path / "board.stderr").read_text()
    assert f"board: servo id {DEAD.id} ({DEAD.name}) stopped answering on the servo bus" in err
    assert "IMU present, ground-truth probe present" in err  # the others were found
