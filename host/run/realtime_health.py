"""Whether a realtime run kept up with the wall clock, and the one line that says so when it did not.

On a loaded machine an emulated board (the Python board, the native C firmware, QEMU) and its plant
get descheduled: ticks start late or are skipped, the servo bus falls silent for a while, frames
reach the board after their time and are refused as LATE. None of that is the robot's doing, so a
run reports it as lateness (counts), never as a dead servo or a lost link, and when it is
substantial says so in one line that suggests ``--lockstep`` (the board's clock then follows the
host's frames, so the run is the same however slow the machine is).

Inputs (no I/O except :func:`board_lateness`):

* ``link``: summary.json's ``extra["link"]`` (what the host counted): ``frames_sent`` and ``late``
  (the board's LATE count from its last report) are read, missing or None counts are 0;
* ``board``: the C firmware's ``board: realtime lateness {json}`` line at the end of the board's
  stderr (firmware_sim/cfirmware/launcher.py ``lateness_record``), read by :func:`board_lateness`;
  None for a board that writes none (the Python board, a real board).

Thresholds (substantial, any one): at least :data:`LATE_MIN` frames late and at least
:data:`LATE_SHARE` of those sent; the board skipped at least :data:`SKIPPED_MIN_MS` of ticks to catch up;
the servo bus fell silent or the plant fell behind by at least :data:`BEHIND_MIN_MS`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["BEHIND_MIN_MS", "LATENESS_PREFIX", "LATE_MIN", "LATE_SHARE", "SKIPPED_MIN_MS", "add_realtime_behind",
           "board_lateness", "realtime_behind", "realtime_behind_line"]

#: the board's stderr line (firmware_sim.cfirmware.launcher.LATENESS_PREFIX; the host does not import firmware_sim)
LATENESS_PREFIX = "board: realtime lateness "
#: late frames: at least this many ...
LATE_MIN = 3
#: ... and at least this share of the frames sent
LATE_SHARE = 0.02
#: board ticks skipped to catch up, in ms of board time (at 500 Hz: 50 ticks)
SKIPPED_MIN_MS = 100
#: longest silence of the servo bus, or the plant's largest lag behind the wall clock (ms)
BEHIND_MIN_MS = 100
#: control period the skipped-ticks count is converted with when the board's rate is not given (500 Hz)
DEFAULT_TICK_MS = 2.0


def _n(d: Mapping[str, Any] | None, key: str) -> int:
    v = (d or {}).get(key)
    return v if isinstance(v, int) and not isinstance(v, bool) and v > 0 else 0


def board_lateness(stderr_path: Path) -> dict[str, int] | None:
    """The last ``board: realtime lateness {json}`` record in a board's stderr file (the run folder's
    ``board.stderr``) as a dict of ints; None when the file or the line is missing or unreadable."""
    try:
        text = stderr_path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    for line in reversed(text.splitlines()):
        if line.startswith(LATENESS_PREFIX):
            try:
                rec = json.loads(line[len(LATENESS_PREFIX):])
            except ValueError:
                return None
            if not isinstance(rec, dict):
                return None
            return {str(k): v for k, v in rec.items() if isinstance(v, int) and not isinstance(v, bool)}
    return None


def realtime_behind(link: Mapping[str, Any] | None, board: Mapping[str, Any] | None, *, clock: str = "realtime",
                    tick_ms: float = DEFAULT_TICK_MS) -> dict[str, Any] | None:
    """The record for summary.json's ``extra["realtime_behind"]`` when a realtime run could not keep up,
    else None (also always None for ``clock="lockstep"``).

    Shape: ``{"late_frames": int, "frames_sent": int, "board_ticks_skipped": int, "bus_silent_max_ms": int,
    "bus_stalls": int, "bus_late_replies": int, "plant_behind_max_ms": int, "reasons": [str, ...],
    "suggest": "--lockstep"}``; ``reasons`` names what crossed its threshold (short phrases, in the order
    late frames, skipped ticks, bus silence, plant lag). ``tick_ms``: the board's control period (ms).
    """
    if clock == "lockstep":
        return None
    late, sent = _n(link, "late"), _n(link, "frames_sent")
    rec: dict[str, Any] = {
        "late_frames": late, "frames_sent": sent,
        "board_ticks_skipped": _n(board, "board_ticks_skipped"),
        "bus_silent_max_ms": _n(board, "bus_silent_max_ms"), "bus_stalls": _n(board, "bus_stalls"),
        "bus_late_replies": _n(board, "bus_late_replies"), "plant_behind_max_ms": _n(board, "plant_behind_max_ms"),
    }
    reasons: list[str] = []
    if late >= LATE_MIN and late >= LATE_SHARE * max(sent, 1):
        reasons.append(f"{late} of {sent} frames reached the board late" if sent else f"{late} frames reached the board late")
    skipped_ms = rec["board_ticks_skipped"] * tick_ms
    if skipped_ms >= SKIPPED_MIN_MS:
        reasons.append(f"the board skipped {skipped_ms / 1000:.2f} s of ticks to catch up")
    if rec["bus_silent_max_ms"] >= BEHIND_MIN_MS:
        reasons.append(f"the servo bus was silent for up to {rec['bus_silent_max_ms']} ms "
                       f"({rec['bus_stalls']} reads unanswered, {rec['bus_late_replies']} answers late)")
    if rec["plant_behind_max_ms"] >= BEHIND_MIN_MS:
        reasons.append(f"the plant fell up to {rec['plant_behind_max_ms']} ms behind")
    if not reasons:
        return None
    rec["reasons"] = reasons
    rec["suggest"] = "--lockstep"
    return rec


def realtime_behind_line(behind: Mapping[str, Any] | None) -> str | None:
    """The one line for a run :func:`realtime_behind` found behind, e.g. ``"realtime: the emulation could not
    keep up with the wall clock on this machine (12 of 410 frames reached the board late; the servo bus was
    silent for up to 586 ms (...)): told as lateness, not as faults; rerun with --lockstep for timing that does
    not depend on the machine's load"``; None for None."""
    if not behind:
        return None
    return ("realtime: the emulation could not keep up with the wall clock on this machine ("
            + "; ".join(behind.get("reasons") or ["it fell behind"])
            + "): told as lateness, not as faults; rerun with --lockstep for timing that does not depend on "
              "the machine's load")


def add_realtime_behind(extra: dict[str, Any], board_stderr: Path) -> str | None:
    """Put :func:`realtime_behind` of a run's summary ``extra`` (its ``link`` and ``clock``) and the board's
    stderr file into ``extra["realtime_behind"]`` when the run fell behind; returns the one line (None when it
    kept up, nothing added). Call it once the board has stopped (its lateness line is written at exit),
    e.g. where summary.json is written."""
    behind = realtime_behind(extra.get("link"), board_lateness(board_stderr), clock=str(extra.get("clock", "realtime")))
    if behind is None:
        return None
    extra["realtime_behind"] = behind
    return realtime_behind_line(behind)
