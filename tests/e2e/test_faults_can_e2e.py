"""A paper task over CAN (SLCAN adapter on a pty, lockstep) with injected faults on both directions.

The board's injector works per CAN frame (drop, bit flip in the data field, duplicate, reorder).
Checked from both ends' candump logs and ``summary.json``: every call completes; no corrupted
setpoint is ever applied (every SERVO_FRAME the board reassembled from what reached it is one the
host sent, same sequence and values: the CRC-16 of the CAN SERVO_FRAME drops a flipped one); the
board counted what it could not decode; every lost message is a sequence gap; the summary reports
what was injected and what each end detected.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from host.link.canlog import iter_can_log
from protocol.can import CanDecodeError, CanItem
from protocol.faults import GapDetector
from protocol.messages import MsgType
from robots.coco.tasks import load_tasks

from .conftest import run_e2e

PAPER_FAULTS = "drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005"
TASKS = {t.id: t for t in load_tasks().values() if t.ground_truth}


def _to_board(path: Path) -> tuple[list[CanItem], int]:
    """Host->board messages a log's frames reassemble to, and the decode errors among them."""
    items, errors = [], 0
    for e in iter_can_log(path):
        if e.direction != "h>b":
            continue
        for it in e.items:
            if isinstance(it, CanItem):
                items.append(it)
            elif isinstance(it, CanDecodeError):
                errors += 1
    return items, errors


@pytest.mark.slow  # ~30 s: ISO-TP frames lost to the faults wait out can-isotp's 1 s timeouts in wall time
def test_task_completes_under_paper_faults_over_slcan(tmp_path: Path) -> None:
    run = run_e2e(TASKS[26].ground_truth, tmp_path, task_label="task 26", link="can:slcan:pty",
                  faults=PAPER_FAULTS, fault_seed=5)
    summary = json.loads((tmp_path / "summary.json").read_text())
    outcomes = {c.function: c.outcome for c in run.calls}
    assert summary["outcome"] == "done" and set(outcomes.values()) == {"done"}, outcomes

    sent, _ = _to_board(tmp_path / "host_frames.log")
    got, board_errors = _to_board(tmp_path / "board_frames.log")
    host_servo = {(i.seq, i.msg) for i in sent if i.msg_type is MsgType.SERVO_FRAME}
    board_servo = [(i.seq, i.msg) for i in got if i.msg_type is MsgType.SERVO_FRAME]
    assert board_servo and all(s in host_servo for s in board_servo), "a SERVO_FRAME the host never sent was decoded"

    faults = summary["extra"]["faults"]
    injected = {d["direction"]: d["injected"] for d in faults["board"]["injected"]}
    h2b, b2h = injected["host->board"], injected["board->host"]
    assert h2b["corrupt"] and h2b["drop"] and b2h["drop"]  # the run really was faulty both ways
    # the board counted every frame it could not decode (its log replays to the same errors)
    assert faults["board"]["board_detected"]["link_errors"] >= board_errors > 0
    assert faults["host_detected"]["decode_errors"] >= 1

    # every lost fixed-layout message (below the last one received) is a counted sequence gap
    sent_seqs = {i.seq for i in sent}
    gaps = GapDetector(window=65536, first=min(sent_seqs))  # the log starts after the HELLO
    seen = set()
    for i in got:
        gaps.feed(i.seq)
        seen.add(i.seq)
    assert gaps.lost == len({q for q in sent_seqs - seen if q < max(seen)})
