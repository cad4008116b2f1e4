"""One line on what the link went through during a run, for the end of ``ghostshell run``.

A run can end "done" while the board's watchdog held the servos, frames were refused, or requests had
to be sent again (a slow or lossy link, ``--faults``): summary.json counts all of it, and this line
says so in the terminal. Built from summary.json's ``extra``: ``link`` (what this session's host
counted: the board's watchdog holds in its reports, the NACKs of its servo frames, re-sent requests,
undecodable frames, gaps in the board's sequence numbers) and, with ``--faults``, ``faults.board``
(what the board injected and detected, read from its stderr when it stopped). The board's own
``late``/``dropped`` counters are left out: they count since the board started, so against a board
you started yourself they include earlier runs.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["MAX_BOARD_WARNINGS", "board_warnings", "link_health_line", "timing_health_line"]


def _count(n: object, one: str, many: str) -> str | None:
    return None if not isinstance(n, int) or n <= 0 else f"{n} {one if n == 1 else many}"


def link_health_line(extra: Mapping[str, Any]) -> str | None:
    """``"link: 13 board watchdog trips (servos held), 1 servo frame refused (NACK), 18 requests re-sent;
    faults injected: delay=200±50 (counts in summary.json)"``, or None when the link had nothing to
    report. Counts that are missing (a run that never reached the board) or zero are left out."""
    link = extra.get("link") or {}
    board = (extra.get("faults") or {}).get("board") or {}
    detected = board.get("board_detected") or {}
    parts = [p for p in (
        # the board's own count with --faults; else the WATCHDOG_HOLD edges in the reports the host read
        _count(detected.get("watchdog_trips", link.get("watchdog_holds")), "board watchdog trip (servos held)",
               "board watchdog trips (servos held)"),
        _count(link.get("frame_nacks"), "servo frame refused (NACK)", "servo frames refused (NACK)"),
        _count(link.get("retries"), "request re-sent", "requests re-sent"),
        _count(link.get("decode_errors"), "bad frame from the board", "bad frames from the board"),
        _count(detected.get("link_errors"), "bad frame at the board", "bad frames at the board"),
        _count(link.get("seq_gaps"), "sequence gap at the host (a board message lost)",
               "sequence gaps at the host (board messages lost)"),
        _count(detected.get("seq_gaps"), "sequence gap at the board", "sequence gaps at the board"),
    ) if p is not None]
    spec = board.get("spec")
    if not parts:
        hit = _units_hit(board)
        if not spec or not hit:
            return None
        # faults that cost nothing the host or board counts (reorder=, dup=, a short delay=): the run still
        # went through them, and said nothing
        return (f"link: nothing lost or refused; faults injected: {spec}, {hit} message(s) hit "
                "(counts in summary.json)")
    return "link: " + ", ".join(parts) + (f"; faults injected: {spec}" if spec else "") + " (counts in summary.json)"


def timing_health_line(extra: Mapping[str, Any]) -> str | None:
    """``"timing: control-path lag p50 0.21 ms, p99 1.30 ms, max 9.87 ms (n 2 400); 0 frames late, 0 skipped;
    0 board watchdog trips; 0 recording drops"`` from summary.json's ``extra.timing``
    (:meth:`host.run.robot_session.RobotSession.timing`), or None without it. Unknown counts read ``?``."""
    timing = extra.get("timing")
    if not isinstance(timing, Mapping):
        return None
    lag = timing.get("lag") or {}

    def n(v: object) -> str:
        return f"{v}" if isinstance(v, int) else "?"

    if isinstance(lag.get("p50_ms"), (int, float)):
        samples = f"{lag.get('n', 0):,}".replace(",", " ")
        lag_text = (f"control-path lag p50 {lag['p50_ms']:.2f} ms, p99 {lag['p99_ms']:.2f} ms, max {lag['max_ms']:.2f} ms "
                    f"(n {samples})")
    else:
        lag_text = "control-path lag not measured"
    line = (f"timing: {lag_text}; {n(timing.get('frames_late'))} frames late, {n(timing.get('frames_skipped'))} skipped; "
            f"{n(timing.get('watchdog_trips'))} board watchdog trips; {n(timing.get('recording_dropped'))} recording drops")
    if timing.get("stop_overdue"):
        line += "; the stop's deadline cut the work"
    stalls = timing.get("stalls_injected")
    if isinstance(stalls, Mapping):
        line += f"; {n(stalls.get('count'))} control-path stalls injected ({stalls.get('total_s')} s, GHOSTSHELL_STALLS)"
    return line


def _units_hit(board: Mapping[str, Any]) -> int:
    """How many units (messages or frames) the board's injector changed, both directions together."""
    total = 0
    for direction in board.get("injected") or []:
        for n in ((direction or {}).get("injected") or {}).values():
            if isinstance(n, int) and n > 0:
                total += n
    return total


#: at most this many of the board's warning lines are repeated (the rest stay in board.stderr)
MAX_BOARD_WARNINGS = 5


#: how an emulated board's stderr logs each watchdog hold (firmware_sim/server.py and the C firmware's gs_board.c)
WATCHDOG_HOLD_LINE = "board: watchdog hold at "


def board_watchdog_holds(stderr_path: Path) -> int | None:
    """The watchdog holds an emulated board logged in its stderr file (the run folder's ``board.stderr``),
    None when there is no file. The board's own count: the host sees a hold only as a rising edge of
    WATCHDOG_HOLD in the 50 Hz reports, and two holds in consecutive reports (a 2 ms one after another)
    showed as one."""
    try:
        text = stderr_path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    return sum(line.startswith(WATCHDOG_HOLD_LINE) for line in text.splitlines())


def board_warnings(stderr_path: Path) -> list[str]:
    """The distinct ``board: warning: ...`` lines of an emulated board's stderr (the run folder's
    ``board.stderr``), at most :data:`MAX_BOARD_WARNINGS`, in order; [] when there is none or no file.
    E.g. a ``--baud`` too slow for the telemetry: ``board: warning: telemetry needs ~81500 bit/s, more
    than 80% of 57600 baud; reports will be dropped, SIM_STATE (the base pose and tilt) first, up to all of them (...)``."""
    try:
        text = stderr_path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return []
    seen: list[str] = []
    for line in text.splitlines():
        if line.startswith("board: warning:") and line not in seen:
            seen.append(line)
            if len(seen) == MAX_BOARD_WARNINGS:
                break
    return seen
