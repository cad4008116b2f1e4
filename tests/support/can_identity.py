"""Lockstep over CAN as a function of the host's input: the board's frames with what says *when* left out.

``can_frames(log) -> {"tx": [...], "rx": [...]}`` reads a board's candump-format frame log into its board->host
(``tx``) and host->board (``rx``) frames, ``"ID#DATA"`` in order, timestamps ignored, and without what depends on
wall-clock time: TIME_SYNC requests and replies and host heartbeats (the host's wall clock), the data of the
HELLO's ISO-TP transfer (its wall-clock stamp), the host's flow controls (its ISO-TP sends them as the board's
First Frames reach it, in between its own frames at wall-clock moments; what the board does next does not depend
on where, which the board->host identity shows), and the end of the run from the board's last First Frame on (the
host may exit before or after answering it). ``assert_same_frames(a, b, what)``: frame for frame up to the shorter
one's end (a board still sent what its host had covered when the host stopped it), short of at most ``TAIL``.
``cpu_hogs(start_when)``: a busy loop per core while the ``with`` block runs (from when ``start_when()``).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import can

from protocol.can.ids import FunctionCode, split_id

__all__ = ["TAIL", "assert_same_frames", "can_frames", "cpu_hogs"]

TAIL = 200  # frames (~6 reports) one run's board may have sent beyond the other's when its host stopped it
#: function codes whose frames carry a wall-clock time (or are sent on a wall-clock timer)
_WALL_CLOCK = {FunctionCode.TIME_SYNC_REQUEST, FunctionCode.TIME_SYNC_REPLY, FunctionCode.HEARTBEAT_HOST}


def can_frames(log: Path) -> dict[str, list[str]]:
    """The frames of a board's candump log, ``"tx"`` (board->host) and ``"rx"`` (host->board), each
    ``"ID#DATA"`` in order, with what depends on wall-clock time left out (see the module docstring)."""
    entries: list[tuple[bool, int, bytes]] = []
    for msg in can.LogReader(str(log)):
        if msg.is_error_frame:
            continue
        entries.append((bool(msg.is_rx), int(msg.arbitration_id), bytes(msg.data or b"")))
    last_ff = max((i for i, (rx, aid, data) in enumerate(entries)
                   if not rx and split_id(aid)[0] == FunctionCode.BULK_TO_HOST and data and data[0] >> 4 == 1),
                  default=len(entries))
    out: dict[str, list[str]] = {"tx": [], "rx": []}
    hello_left: int | None = None  # data bytes of the HELLO transfer still to come (None: not seen yet)
    for rx, aid, data in entries[:last_ff]:
        fn, _ = split_id(aid)
        if fn in _WALL_CLOCK:
            continue
        if rx and fn == FunctionCode.BULK_TO_BOARD and data and data[0] >> 4 == 3:
            continue  # the host's flow control
        text = f"{aid:03X}#{data.hex().upper()}"
        if rx and fn == FunctionCode.BULK_TO_BOARD and data and data[0] >> 4 in (0, 1, 2):
            if hello_left is None:  # the host's first transfer: the HELLO
                kind = data[0] >> 4
                hello_left = (data[0] & 0x0F if kind == 0 else ((data[0] & 0x0F) << 8 | data[1]) - 6)
                text = f"{aid:03X}#HELLO"
            elif hello_left > 0 and data[0] >> 4 == 2:
                hello_left -= 7
                text = f"{aid:03X}#HELLO"
        out["rx" if rx else "tx"].append(text)
    return out


@contextmanager
def cpu_hogs(start_when: Callable[[], bool] | None = None) -> Iterator[int]:
    """A busy loop per core while the block runs, from when ``start_when()`` (polled every 20 ms in a thread;
    None: at once) says so: the load is the disturbance here, not synchronisation. Yields their number."""
    n = os.cpu_count() or 1
    procs: list[subprocess.Popen[bytes]] = []
    done = threading.Event()

    def start() -> None:
        while start_when is not None and not start_when():
            if done.wait(0.02):
                return
        for _ in range(n):
            procs.append(subprocess.Popen([sys.executable, "-c", "while True: pass"]))

    thread = threading.Thread(target=start, daemon=True)
    thread.start()
    try:
        yield n
    finally:
        done.set()
        thread.join()
        for p in procs:
            p.kill()
            p.wait()


def _first_difference(a: list[str], b: list[str]) -> str:
    n = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
    return f"{len(a)} vs {len(b)} frames; first difference at {n}: {a[n:n + 3]} vs {b[n:n + 3]}"


def assert_same_frames(a: list[str], b: list[str], what: str) -> None:
    """``a`` and ``b`` agree frame for frame up to the shorter's end, which lacks at most ``TAIL`` frames."""
    n = min(len(a), len(b))
    assert a[:n] == b[:n] and abs(len(a) - len(b)) <= TAIL, f"{what}: " + _first_difference(a, b)
