"""The fault guarantees of a run under injected link faults, checked from its artefacts (any robot).

``assert_serial_fault_guarantees(out)`` (a serial run: ``host_frames.jsonl``/``board_frames.jsonl``)
and ``assert_can_fault_guarantees(out)`` (a CAN run: candump logs ``host_frames.log``/``board_frames.log``)
check what the paper's fault mix must never break: every call completes; no corrupted setpoint is
ever applied (every SERVO_FRAME the board decoded is one the host sent: byte-identical on serial;
same sequence number and values on CAN, whose CRC-16 drops a flipped frame); every lost message is
a sequence gap the gap detector counts; the summary says what was injected and what each end
detected. ``cli_run`` runs ``ghostshell run`` as a user does (a subprocess), for the CAN runs.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from host.link.canlog import iter_can_log
from protocol.can import CanDecodeError, CanItem
from protocol.faults import GapDetector
from protocol.messages import MsgType

__all__ = ["PAPER_FAULTS", "CliRun", "assert_can_fault_guarantees", "assert_serial_fault_guarantees", "cli_run"]

#: the paper's fault mix (per wire unit, both directions)
PAPER_FAULTS = "drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005"


def _records(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _done(summary: dict[str, Any]) -> None:
    outcomes = {k: v for k, v in summary["outcomes"].items() if v}
    assert summary["outcome"] == "done" and set(outcomes) == {"done"}, outcomes


def assert_serial_fault_guarantees(out: Path) -> dict[str, Any]:
    """Check a finished serial run in ``out`` under injected faults; returns its ``extra.faults``."""
    summary = json.loads((out / "summary.json").read_text())
    _done(summary)
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
    faults: dict[str, Any] = summary["extra"]["faults"]
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


def _to_board(path: Path) -> tuple[list[CanItem], int]:
    """Host->board messages a CAN log's frames reassemble to, and the decode errors among them."""
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


def assert_can_fault_guarantees(out: Path) -> dict[str, Any]:
    """Check a finished CAN run in ``out`` under injected faults; returns its ``extra.faults``."""
    summary = json.loads((out / "summary.json").read_text())
    _done(summary)
    sent, _ = _to_board(out / "host_frames.log")
    got, board_errors = _to_board(out / "board_frames.log")
    host_servo = {(i.seq, i.msg) for i in sent if i.msg_type is MsgType.SERVO_FRAME}
    board_servo = [(i.seq, i.msg) for i in got if i.msg_type is MsgType.SERVO_FRAME]
    assert board_servo and all(s in host_servo for s in board_servo), "a SERVO_FRAME the host never sent was decoded"

    faults: dict[str, Any] = summary["extra"]["faults"]
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
    return faults


@dataclass(frozen=True)
class CliRun:
    """A finished ``ghostshell run`` subprocess: its run folder, exit status and output."""

    out: Path
    returncode: int
    output: str


def cli_run(tid: int, out: Path, *, link: str, robot: str | None = None, faults: str | None = None,
            seed: int | None = None, timeout: float = 240, plots: bool = False) -> CliRun:
    """``ghostshell run --task TID --lockstep --link LINK [--robot R] [--faults F --fault-seed S]``, with
    ``--no-plots`` unless ``plots``: the checks read the logs and summary.json, and matplotlib's import
    and the two plots were ~0.45 of a run's ~2.4 CPU-s (task 8 over SLCAN under faults, 2 runs each way)."""
    cmd = [sys.executable, "-m", "host.cli", "run", "--task", str(tid), "--link", link, "--lockstep",
           "--out", str(out), "--no-live", *(() if plots else ("--no-plots",))]
    if robot is not None:
        cmd += ["--robot", robot]
    if faults is not None:
        cmd += ["--faults", faults, "--fault-seed", str(tid if seed is None else seed)]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    return CliRun(out, p.returncode, p.stdout + p.stderr)
