"""Paper tasks over a serial link with injected faults (emulated board, lockstep, both directions).

Guarantees checked from both ends' frame logs and ``summary.json``: every call completes; no
corrupted setpoint is ever applied (every SERVO_FRAME the board decoded is byte-identical to one the
host sent, so every one it could apply is); every lost frame is a sequence gap the gap detector
counts; the summary says what was injected and what each end detected.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from protocol.faults import GapDetector
from robots.coco.tasks import load_tasks

from .conftest import FIRMWARES, run_e2e

PAPER_FAULTS = "drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005"
TASKS = {t.id: t for t in load_tasks().values() if t.ground_truth}


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _check(tid: int, out: Path, seed: int, firmware: str = "python") -> dict:
    run = run_e2e(TASKS[tid].ground_truth, out, task_label=f"task {tid}", faults=PAPER_FAULTS, fault_seed=seed,
                  firmware=firmware)
    summary = json.loads((out / "summary.json").read_text())
    outcomes = {c.function: c.outcome for c in run.calls}
    assert summary["outcome"] == "done" and set(outcomes.values()) == {"done"}, outcomes
    host_tx = {r["raw"] for r in _records(out / "host_frames.jsonl") if r["dir"] == "tx"}
    board_rx = [r for r in _records(out / "board_frames.jsonl") if r["dir"] == "rx"]
    servo = [r for r in board_rx if r.get("type") == "SERVO_FRAME"]
    assert servo and all(r["raw"] in host_tx for r in servo), "a SERVO_FRAME the host never sent was decoded"
    gaps = GapDetector(window=65536, first=0)  # the host's sequence starts at 0
    got = set()
    for r in board_rx:
        if "seq" in r and r.get("type"):
            gaps.feed(r["seq"])
            got.add(r["seq"])
    sent = {r["seq"] for r in _records(out / "host_frames.jsonl") if r["dir"] == "tx"}
    last = max(got)  # frames lost after the last one received leave no gap (the run ended)
    assert gaps.lost == len({q for q in sent - got if q < last})  # every other lost frame is a counted gap
    faults = summary["extra"]["faults"]
    injected = {d["direction"]: d["injected"] for d in faults["board"]["injected"]}
    h2b, b2h = injected["host->board"], injected["board->host"]
    assert faults["board"]["board_detected"]["link_errors"] >= (1 if h2b["corrupt"] else 0)
    assert faults["host_detected"]["decode_errors"] >= (1 if b2h["corrupt"] else 0)
    assert gaps.lost >= h2b["drop"] - 1  # the very last frame may be dropped unseen
    # each end counted the gaps live, too (the board from its first message on: a lost HELLO is not a gap)
    assert 0 <= gaps.lost - faults["board"]["board_detected"]["seq_gaps"] <= min(got)
    if b2h["drop"] >= 2:
        assert faults["host_detected"]["seq_gaps"] >= 1
    return faults


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_task_completes_under_paper_faults(firmware: str, tmp_path: Path) -> None:
    """Task 26 under the paper's fault rates, on the Python board and on the C firmware (whose UART the
    faults hit on the modelled line between two ptys; its frame log is the raw bytes it decoded)."""
    faults = _check(26, tmp_path, seed=3, firmware=firmware)
    total = sum(sum(d["injected"].values()) for d in faults["board"]["injected"])
    assert total > 0


@pytest.mark.slow
@pytest.mark.parametrize("tid", sorted(TASKS))
def test_all_tasks_complete_under_paper_faults(tid: int, tmp_path: Path) -> None:
    _check(tid, tmp_path, seed=tid)
