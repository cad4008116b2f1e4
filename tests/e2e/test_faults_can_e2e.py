"""All 30 paper tasks over CAN (SLCAN adapter on a pty, lockstep) with injected faults both ways.

Each task runs as a user runs it, ``ghostshell run --task N --link can:slcan:pty --lockstep
--faults drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005 --fault-seed N``, two subprocesses at a
time (the machine's two cores; a SLCAN run spends most of its time in python-can's byte-wise
reads). The board's injector works per CAN frame (drop, bit flip in the data field, duplicate,
reorder). Checked from both ends' candump logs and ``summary.json``: every call completes; no
corrupted setpoint is ever applied (every SERVO_FRAME the board reassembled from what reached it
is one the host sent, same sequence and values: the CRC-16 of the CAN SERVO_FRAME drops a flipped
one); the board counted what it could not decode; every lost message is a sequence gap; the
summary reports what was injected and what each end detected.
"""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from host.link.canlog import iter_can_log
from protocol.can import CanDecodeError, CanItem
from protocol.faults import GapDetector
from protocol.messages import MsgType
from robots.coco.tasks import load_tasks

PAPER_FAULTS = "drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005"
TASKS = sorted(t.id for t in load_tasks().values() if t.ground_truth)
WORKERS = 2


@dataclass(frozen=True)
class CliRun:
    out: Path
    returncode: int
    output: str


def _run(tid: int, root: Path) -> CliRun:
    out = root / f"task{tid:02d}"
    cmd = [sys.executable, "-m", "host.cli", "run", "--task", str(tid), "--link", "can:slcan:pty", "--lockstep",
           "--faults", PAPER_FAULTS, "--fault-seed", str(tid), "--out", str(out), "--no-live"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    return CliRun(out, p.returncode, p.stdout + p.stderr)


@pytest.fixture(scope="module")
def can_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[int, CliRun]:
    root = tmp_path_factory.mktemp("can_faults")
    with ThreadPoolExecutor(WORKERS) as pool:
        return dict(zip(TASKS, pool.map(lambda t: _run(t, root), TASKS)))


def _to_board(path: Path) -> tuple[list[CanItem], int]:
    """Host->board messages a log's frames reassemble to, and the decode errors among them."""
    items, errors = [], 0
    for e in iter_can_log(path, dbc=False):
        if e.direction != "h>b":
            continue
        for it in e.items:
            if isinstance(it, CanItem):
                items.append(it)
            elif isinstance(it, CanDecodeError):
                errors += 1
    return items, errors


@pytest.mark.slow  # ~2.5 min for the 30 tasks on two cores
@pytest.mark.parametrize("tid", TASKS)
def test_task_completes_under_paper_faults_over_slcan(tid: int, can_runs: dict[int, CliRun]) -> None:
    run = can_runs[tid]
    assert run.returncode == 0, run.output[-3000:]
    summary = json.loads((run.out / "summary.json").read_text())
    assert summary["outcome"] == "done", run.output[-3000:]
    outcomes = {k: v for k, v in summary["outcomes"].items() if v}
    assert set(outcomes) == {"done"}, outcomes

    sent, _ = _to_board(run.out / "host_frames.log")
    got, board_errors = _to_board(run.out / "board_frames.log")
    host_servo = {(i.seq, i.msg) for i in sent if i.msg_type is MsgType.SERVO_FRAME}
    board_servo = [(i.seq, i.msg) for i in got if i.msg_type is MsgType.SERVO_FRAME]
    assert board_servo and all(s in host_servo for s in board_servo), "a SERVO_FRAME the host never sent was decoded"

    faults = summary["extra"]["faults"]
    injected = {d["direction"]: d["injected"] for d in faults["board"]["injected"]}
    h2b, b2h = injected["host->board"], injected["board->host"]
    assert sum(h2b.values()) + sum(b2h.values()) > 0  # the run really was faulty
    # the board counted every frame it could not decode (its log replays to the same errors)
    assert faults["board"]["board_detected"]["link_errors"] >= board_errors
    if h2b["corrupt"]:
        assert board_errors > 0
    if b2h["corrupt"]:
        assert faults["host_detected"]["decode_errors"] >= 1

    # every lost message (below the last one received) is a counted sequence gap. The host numbers
    # every message it sends with the next sequence number, so the reference is the sequence range:
    # a bulk message whose ISO-TP transfer the host abandoned (its flow control was lost) has no
    # complete copy in the host's own log, yet its number was used and never arrived
    first = min(i.seq for i in sent)
    gaps = GapDetector(window=65536, first=first)  # the log starts after the HELLO
    seen = set()
    for i in got:
        gaps.feed(i.seq)
        seen.add(i.seq)
    lost = {q for q in range(first, max(seen)) if q not in seen}
    assert gaps.lost == len(lost)
    assert {i.seq for i in sent if i.seq < max(seen)} - seen <= lost
    # the board counted the gaps live, from the first message that reached it (a lost HELLO is no gap:
    # the numbering starts with the one that arrives); so did the host
    assert faults["board"]["board_detected"]["seq_gaps"] >= gaps.lost - (min(seen) - first)
    if b2h["drop"] >= 2:
        assert faults["host_detected"]["seq_gaps"] >= 1
