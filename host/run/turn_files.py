"""A turn's files: timeline.json and summary.json, then timeline.png and joints.png, written in a worker thread.

:func:`turn_writer` and :func:`turn_plotter` take a snapshot on the event loop (the calls, the summary, the
joint history) and return a call that writes in any thread: a process stopped while plotting still leaves
both JSON files. Before writing, summary.json takes what the board printed to its stderr when it stopped
(:func:`board_fault_report`, :func:`board_servo_bus_report`, its watchdog holds and lateness).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from host.run import artefacts
from host.run.link_health import board_watchdog_holds
from host.run.pump import Recorder
from host.run.realtime_health import add_realtime_behind
from robots.description import Robot

__all__ = ["SERVO_BUS_LINE", "board_fault_report", "board_servo_bus_report", "turn_plotter", "turn_writer"]


def turn_writer(out: Path, calls: list[artefacts.BoardCall], summary: artefacts.Summary, t0: float,
                board_stderr: Path, plot: Callable[[], None] | None) -> Callable[[], None]:
    """The call that writes a turn's timeline.json (``calls``, times from board time ``t0`` s) and
    summary.json into ``out``, then runs ``plot`` (:func:`turn_plotter`; None: no plots). It completes
    ``summary.extra`` from the board's ``board_stderr`` first: ``faults.board`` (with ``faults``), the
    board's own watchdog-hold count, ``servo_bus``, and in realtime how far the board fell behind."""

    def write() -> None:
        out.mkdir(parents=True, exist_ok=True)
        faults = summary.extra.get("faults")
        if isinstance(faults, dict):  # the board reports what it injected and detected when it stops
            faults["board"] = board_fault_report(board_stderr)
        holds = board_watchdog_holds(board_stderr)  # the board's own count beats the host's edges in 50 Hz reports
        if holds:
            for part, key in (("timing", "watchdog_trips"), ("link", "watchdog_holds")):
                counts = summary.extra.get(part)
                if isinstance(counts, dict):
                    counts[key] = max(holds, counts.get(key) or 0)
        bus = board_servo_bus_report(board_stderr)  # real servos were driven: which, and how it went
        if bus is not None:
            summary.extra["servo_bus"] = bus
        if summary.extra.get("clock") == "realtime":  # a board that fell behind says so (lateness, not a dead servo)
            add_realtime_behind(summary.extra, board_stderr)
        artefacts.write_timeline_json(out / "timeline.json", calls, t0=t0)
        artefacts.write_summary_json(out / "summary.json", summary)
        if plot is not None:
            plot()

    return write


def turn_plotter(out: Path, calls: list[artefacts.BoardCall], t0: float, label: str, rec: Recorder,
                 history: Iterable[tuple[int, Any]], robot: Robot) -> Callable[[], None]:
    """Snapshot the joint history a turn's plots need (on the loop): the reported positions in ``rec`` and
    the frames sent (``history``: ``(t_us, targets)``) from board time ``t0`` s on. The returned call draws
    timeline.png (``calls``, titled with ``label``) and joints.png (``robot``'s servos) into ``out``
    (thread-safe)."""
    times = np.asarray(rec.t)
    q = np.asarray(rec.q)
    keep = times >= t0 - 1e-9
    sent = [(t, q_) for t, q_ in history if t * 1e-6 >= t0 - 1e-9]
    names = robot.servos.names

    def plot() -> None:
        artefacts.plot_timeline(out / "timeline.png", calls, title=f"{label}: calls on the board clock")
        if len(times) and keep.any():
            targets = (np.asarray([t for t, _ in sent]) * 1e-6, np.asarray([q_ for _, q_ in sent])) if sent else None
            artefacts.plot_joints(out / "joints.png", times[keep], q[keep], names, targets,
                                  groups=artefacts.joint_groups(robot))

    return plot


def board_fault_report(stderr_path: Path) -> Any:
    """What the board injected and detected: its ``board: faults {json}`` stderr line (None before it stopped)."""
    report: Any = None
    try:
        for line in stderr_path.read_text(encoding="utf-8", errors="replace").splitlines():
            if line.startswith("board: faults "):
                report = json.loads(line[len("board: faults "):])
    except (OSError, ValueError):
        pass
    return report


#: the board's exit line about a real servo bus it drove (firmware_sim.cli): port, protocol, baud, servos,
#: bus period and the bus counters (timeouts, checksum errors, faults)
SERVO_BUS_LINE = "board: servo bus {"


def board_servo_bus_report(stderr_path: Path) -> Any:
    """The board's ``board: servo bus {json}`` exit line as a dict (None without one: no servo bus, or the
    board still running)."""
    report: Any = None
    try:
        for line in stderr_path.read_text(encoding="utf-8", errors="replace").splitlines():
            if line.startswith(SERVO_BUS_LINE):
                report = json.loads(line[len(SERVO_BUS_LINE) - 1:])
    except (OSError, ValueError):
        pass
    return report
