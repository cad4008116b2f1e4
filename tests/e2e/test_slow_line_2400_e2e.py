"""Paper Task 26 over a 2 400-baud line finishes with the result it has at full rate (issue 46, slow lines).

Before: the frame grid at 2 400 baud was one full-body SERVO_FRAME every 330 ms (162 ms of wire each), and
the board's 200 ms watchdog held the servos and emptied the jitter buffer between every two frames; a
lockstep run never finished (a hold every 330 ms of board time, 0.03x real time for the 50 Hz reports the
line could not carry), a realtime one ran into its board-time bound with 17 holds and 101 frames late.

Now (``host.motion.line_cadence``): the handshake raises the watchdog past the grid (CONFIG WATCHDOG_MS)
and lowers the report rate to what the line carries (TELEMETRY_RATE_HZ 1), the grid frames carry only
the servos that move and come every 210 ms. The checks: every call done, no watchdog hold, the CONFIGs
ACKed in the host's frame log, and the base moved forward as at full rate (within 25 %: the strides are
sampled every 210 ms instead of 10, their 0.7-s gait cycle a little coarser).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from support.realtime_lock import realtime_part_done

from .conftest import TASKS, E2ERun, run_e2e

BAUD = 2_400


def _frames(out: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (out / "host_frames.jsonl").read_text().splitlines()]


def _check(run: E2ERun, out: Path) -> dict[str, Any]:
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "done" and {c.outcome for c in run.calls} == {"done"}, run.table()
    assert len(run.calls) == 11
    link = summary["extra"]["link"]
    assert link["watchdog_holds"] == 0, link
    frames = _frames(out)
    configs = {(f["fields"]["key"], f["fields"]["value"]) for f in frames if f["dir"] == "tx" and f["type"] == "CONFIG"}
    assert ("WATCHDOG_MS", 1220) in configs and ("TELEMETRY_RATE_HZ", 1) in configs, configs
    acked = {f["fields"]["msg_type"] for f in frames if f["dir"] == "rx" and f["type"] == "ACK"}
    assert "CONFIG" in acked
    masks = [f["fields"]["mask"] for f in frames if f["dir"] == "tx" and f["type"] == "SERVO_FRAME"]
    # only the servos that move: most frames carry one or two of the twelve (ears, head, the idle servo 0)
    assert sum(bin(m).count("1") <= 2 for m in masks) > len(masks) / 2, masks
    assert "watchdog hold" not in (out / "board.stderr").read_text()
    return summary


@pytest.mark.parametrize("firmware", ["python", "c"])
def test_task_26_at_2400_baud_lockstep_finishes_as_at_full_rate(tmp_path: Path, task_run: Any, firmware: str) -> None:
    run = run_e2e(TASKS[26].ground_truth, tmp_path, task_label="task 26", wire_baud=BAUD, firmware=firmware)
    summary = _check(run, tmp_path)
    full = json.loads((task_run(26, firmware).out / "summary.json").read_text())
    moved, moved_full = summary["base_end"][0] - summary["base_start"][0], full["base_end"][0] - full["base_start"][0]
    assert moved_full > 0.05 and moved == pytest.approx(moved_full, rel=0.25), (moved, moved_full)
    assert abs(summary["base_end"][1] - full["base_end"][1]) < 0.02
    assert summary["max_tilt_deg"] < 10 and not summary["fell"]


@pytest.mark.realtime  # tests/support/realtime_lock.py
def test_task_26_at_2400_baud_realtime_finishes_without_a_watchdog_hold(tmp_path: Path) -> None:
    """Realtime: ~25 s of wall time (a 7-s connect: eight TIME_SYNC exchanges of ~0.9 s each on this line).
    The board drops every SIM_STATE behind its 483-ms TELEMETRY (firmware_sim.server), so the base pose is
    not known at the host; the calls and the watchdog are."""
    run = run_e2e(TASKS[26].ground_truth, tmp_path, task_label="task 26", wire_baud=BAUD, lockstep=False)
    realtime_part_done()
    summary = _check(run, tmp_path)
    # a motion start's burst (its frame, a FLUSH, the re-sent frames) can make a frame behind it late
    assert summary["extra"]["link"]["frame_nacks"] <= 5, summary["extra"]["link"]
