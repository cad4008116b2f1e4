"""Servo tracking error from a board's frame log, and how fast it recovers after a link fault.

The board's own log (``board --log``: ``board_frames.jsonl`` on serial, the candump capture
``board_frames.log`` on CAN) holds both halves of the comparison: every SERVO_FRAME that reached
the board (``rx``; on CAN after the injected faults) and every TELEMETRY it sent (``tx``), which
carries the measured joint angles and ``last_applied_seq``, the sequence number of the last servo
frame the board applied. The *commanded target* of a servo at a report is the target of the last
applied frame that covered it (per mask bit, carried forward); the tracking error is
``|measured - commanded|`` in degrees. While the board holds (WATCHDOG_HOLD) it keeps the command
it had, so the reference stays the last frame applied before the link went silent. Why the applied
frame and not the board's interpolation towards the next one: a position servo lags its command by
about one 10 ms frame, so against the interpolated command a steady walk already reads ~3 deg
(p50 2.9 deg, max 3.6 deg measured) and "back under 3 deg" would mean nothing; against the applied
frame the same walk reads p50 0.5-1.1 deg, max ~2-2.8 deg.

``recovery(trace, after_s, bound_deg)`` is the time from ``after_s`` (the board time a valid
message ended a hold: the board's ``board: watchdog resume at board time T s`` line, see
:func:`resume_times`) until every servo is within ``bound_deg`` of its commanded target *and stays
there* to the end of the trace.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from protocol.framelog import iter_records
from protocol.messages import ServoFrame, Telemetry

__all__ = ["Recovery", "TrackingTrace", "find_board_log", "recovery", "recovery_after_hold", "resume_times",
           "tracking_trace"]

#: the board's stderr line when a valid message ends a watchdog HOLD (firmware_sim.server)
RESUME_LINE = re.compile(r"board: watchdog resume at board time ([0-9.]+) s, a valid message ended the hold "
                         r"after ([0-9.]+) s")


@dataclass(frozen=True)
class TrackingTrace:
    """Per TELEMETRY report (board order): board time ``t`` (s, [n]), tracking error ``err_deg``
    ([n, servos], degrees; NaN until a frame covered the servo) and the report's fault flags
    ``faults`` ([n], :class:`protocol.messages.FaultFlags` bits)."""

    t: np.ndarray
    err_deg: np.ndarray
    faults: np.ndarray

    @property
    def worst_deg(self) -> np.ndarray:
        """Largest error over the servos at each report (degrees, [n]; NaN where none is known)."""
        known = ~np.all(np.isnan(self.err_deg), axis=1)
        out = np.full(len(self.t), np.nan)
        out[known] = np.nanmax(self.err_deg[known], axis=1)
        return out


@dataclass(frozen=True)
class Recovery:
    """``seconds`` from the end of the fault until tracking was back within the bound for good
    (None: never), the worst error seen after the fault (``peak_deg``) and after recovery
    (``after_deg``)."""

    after_s: float
    seconds: float | None
    peak_deg: float
    after_deg: float


def find_board_log(run_dir: Path) -> Path:
    """The board's frame log in a run folder (serial JSON Lines or a CAN capture); FileNotFoundError if none."""
    from host.link.canlog import CAN_LOG_SUFFIXES

    for p in [run_dir / "board_frames.jsonl", *(run_dir / f"board_frames{s}" for s in CAN_LOG_SUFFIXES)]:
        if p.exists():
            return p
    raise FileNotFoundError(f"no board frame log (board_frames.jsonl or a CAN capture) in {run_dir}")


def _events_jsonl(path: Path) -> Iterator[tuple[int, ServoFrame | Telemetry]]:
    from protocol.framelog import LogDecoder
    from protocol.framing import Frame

    dec = LogDecoder()  # the log's own wire schema (its HELLO / CAPS say which)
    with open(path, encoding="utf-8") as f:
        for rec in iter_records(f):
            kind, direction = rec.get("type"), rec.get("dir")
            if kind in ("HELLO", "CAPS"):
                dec.decode(rec["raw"])
            if "error" in rec or (kind, direction) not in (("SERVO_FRAME", "rx"), ("TELEMETRY", "tx")):
                continue
            item = dec.decode(rec["raw"])
            if isinstance(item, Frame) and isinstance(item.msg, (ServoFrame, Telemetry)):
                yield item.seq, item.msg


def _events_can(path: Path) -> Iterator[tuple[int, ServoFrame | Telemetry]]:
    from host.link.canlog import iter_can_log
    from protocol.can import CanItem

    for e in iter_can_log(path):
        want = ServoFrame if e.direction == "h>b" else Telemetry
        for it in e.items:
            if isinstance(it, CanItem) and isinstance(it.msg, want):
                yield it.seq, it.msg


def tracking_trace(log: Path, servos: int | None = None) -> TrackingTrace:
    """The tracking error at every TELEMETRY in a board frame log (``.jsonl`` or a CAN capture).

    ``servos``: how many servos to compare (default: as many as the telemetry reports).
    Raises ``ValueError`` when the log holds no TELEMETRY.
    """
    events = _events_jsonl(log) if log.suffix == ".jsonl" else _events_can(log)
    frames: dict[int, ServoFrame] = {}
    target: np.ndarray | None = None
    applied = -1
    t: list[float] = []
    err: list[np.ndarray] = []
    faults: list[int] = []
    for seq, msg in events:
        if isinstance(msg, ServoFrame):
            frames[seq & 0xFFFF] = msg  # the newest frame of a sequence number (a 16-bit lap later) wins
            continue
        if target is None:
            servos = len(msg.positions) if servos is None else servos
            target = np.full(servos, np.nan)
        assert servos is not None
        if msg.last_applied_seq != applied:
            applied = msg.last_applied_seq
            fr = frames.get(applied)
            if fr is not None:
                idx = [i for i in range(servos) if fr.mask >> i & 1]
                target[idx] = fr.targets[: len(idx)]
        t.append(msg.board_time_us * 1e-6)
        err.append(np.degrees(np.abs(np.asarray(msg.positions[:servos]) - target)))
        faults.append(int(msg.faults))
    if not t:
        raise ValueError(f"{log} holds no TELEMETRY")
    return TrackingTrace(np.asarray(t), np.asarray(err), np.asarray(faults, dtype=np.int64))


def recovery(trace: TrackingTrace, after_s: float, bound_deg: float = 3.0, until_s: float | None = None) -> Recovery:
    """How long after board time ``after_s`` every servo came back within ``bound_deg`` for good.

    ``seconds`` is measured to the first report from which the error stays below the bound up to
    ``until_s`` (default: the end of the trace); reports are 20 ms apart at the default 50 Hz, so
    that is the resolution. None when the error is above the bound at the last report considered.
    """
    end = np.inf if until_s is None else until_s
    sel = (trace.t >= after_s) & (trace.t <= end)
    t, worst = trace.t[sel], trace.worst_deg[sel]
    if not len(t):
        raise ValueError(f"no report between board time {after_s:.3f} s and {end:.3f} s")
    bad = np.flatnonzero(~(worst < bound_deg))  # NaN (nothing commanded yet) counts as not tracking
    peak = float(np.nanmax(worst)) if np.any(~np.isnan(worst)) else float("nan")
    if not len(bad):
        return Recovery(after_s, float(t[0] - after_s), peak, peak)
    last_bad = int(bad[-1])
    if last_bad == len(t) - 1:
        return Recovery(after_s, None, peak, float(worst[-1]))
    rest = worst[last_bad + 1:]
    return Recovery(after_s, float(t[last_bad + 1] - after_s), peak, float(np.max(rest)))


def resume_times(board_stderr: str) -> list[tuple[float, float]]:
    """``(board time s, held s)`` of every HOLD a valid message ended, from the board's stderr."""
    return [(float(m[1]), float(m[2])) for m in RESUME_LINE.finditer(board_stderr)]


def recovery_after_hold(run_dir: Path, bound_deg: float = 3.0, not_before_s: float = 0.0) -> tuple[float, float, Recovery]:
    """For a run folder (``board.stderr`` + the board's frame log): the first watchdog HOLD a message
    ended at board time ``not_before_s`` or later: ``(resumed at s, held s, recovery from then on)``.

    Raises ``ValueError`` when the board never resumed from a hold then, FileNotFoundError without a log.
    """
    resumes = resume_times((run_dir / "board.stderr").read_text(encoding="utf-8", errors="replace"))
    later = [r for r in resumes if r[0] >= not_before_s]
    if not later:
        raise ValueError(f"the board in {run_dir} never resumed from a watchdog hold after board time "
                         f"{not_before_s:g} s (resumes: {resumes})")
    resumed_at, held_s = later[0]
    return resumed_at, held_s, recovery(tracking_trace(find_board_log(run_dir)), resumed_at, bound_deg)
