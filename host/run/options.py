"""The options of a robot session (:class:`SessionOptions`): which robot, board, link and shell, and the bounds
of its work. A run's options (:class:`host.run.runner.RunOptions`) are these plus what to run.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from host.run.events import EventPolicy, ScriptedEvent
from host.run.progress_guard import PROGRESS_LIMIT_S
from host.run.stops import DEFAULT_MAX_BOARD_S, DEFAULT_MAX_LOG_MB, STOP_GRACE_S
from host.shell.policy import Policy
from host.shell.skills import SkillStore
from protocol.linkspec import LinkSpec
from robots.registry import DEFAULT_ROBOT

__all__ = ["SessionOptions", "servo_bus_args"]


def servo_bus_args(servo_bus: str | None, bus_protocol: str | None, estop_torque: str | None) -> tuple[str, ...]:
    """The board's arguments for a real servo bus (empty without ``servo_bus``)."""
    if servo_bus is None:
        return ()
    out = ["--servo-bus", servo_bus]
    if bus_protocol is not None:
        out += ["--bus-protocol", bus_protocol]
    if estop_torque is not None:
        out += ["--estop-torque", estop_torque]
    return tuple(out)


@dataclass
class SessionOptions:
    """How to bring the robot up (the board/link/shell part of the ``run``/``chat``/``mcp`` flags).

    ``robot``: a robot name on the robot search path or a robot folder (``robots_dir`` is searched
    first); ``vocabulary``, ``start_pose`` and ``scene`` default to the robot's own.
    """

    robot: str = DEFAULT_ROBOT
    robots_dir: str | None = None
    vocabulary: str | None = None
    mode: str = "async-first"
    strict: bool = True
    lockstep: bool = False
    link: str | LinkSpec = "pty"  # a link spec (protocol.linkspec)
    emulate_board: bool | None = None  # start the emulated board on `link` first; None: only where implied (pty, can:slcan:pty)
    baud: int = 115200
    wire_baud: int | None = None  # the board models wire time at this baud rate (its --baud)
    out: Path = Path("runs/latest")
    start_pose: str | None = None  # a pose of the robot's (None: its start_pose)
    skills: SkillStore | None = None  # None: an in-memory store (skills end with the session)
    #: the label of the turns (summary.json ``task``; a run's one turn) and of the recording (run.mcap)
    task_label: str = "session"
    scene: str | None = None  # objects in the board's world (python -m firmware_sim --scene); None: the robot's default
    policy: Policy | None = None  # refuse calls before they reach the link (host.shell.policy)
    faults: str | None = None  # emulated board: inject link faults both ways (protocol.faults spec)
    fault_seed: int = 0
    #: the emulated board's firmware: "python" (firmware_sim), "c" (the C firmware, native), "qemu" (the C
    #: firmware on an emulated Cortex-M3) or "stm32f4" (its STM32F405 image on QEMU's netduinoplus2);
    #: python -m firmware_sim --firmware
    firmware: str = "python"
    #: the board's arguments that put a REAL servo bus under it (``--servo-bus PORT[:BAUD]``, ``--bus-protocol
    #: sts|dxl2``, ``--estop-torque hold|limp``; :func:`servo_bus_args`; docs/guides/hardware.md); () = the plant
    servo_bus: tuple[str, ...] = ()
    mcap: bool = True  # record the session to <out>/run.mcap (host.run.mcap_log)
    #: draw timeline.png and joints.png with each turn's artefacts (matplotlib, ~0.25 s of CPU per turn in
    #: a worker thread, and its import and warm-up once per process); False: neither plot is drawn and
    #: matplotlib is never imported (the other artefacts are written as before)
    plots: bool = True
    foxglove: int | None = None  # serve the live view on this localhost port (host.run.foxglove_live); None: off
    #: MCP servers mounted as shell modules (``--mount-mcp NAME=COMMAND|URL``, :mod:`host.mounts`)
    mcp_mounts: tuple[Any, ...] = ()
    mount_options: Any = None  # host.mounts.MountOptions (None: its defaults)
    #: events (host.run.events): what to do per kind, and scripted ones (``--events FILE``)
    event_policy: EventPolicy | None = None
    events: tuple[ScriptedEvent, ...] = ()
    #: emulated board only: pushes on the robot's base, ``S:FX,FY,FZ[:DURATION]`` (board ``--push``)
    pushes: tuple[str, ...] = ()
    max_board_s: float | None = DEFAULT_MAX_BOARD_S  # board seconds one turn may last (None: no bound)
    max_log_mb: float | None = DEFAULT_MAX_LOG_MB  # megabytes the session's frame logs may reach (None: no bound)
    #: wall seconds the session's work may go without progress before it stops as ``stalled``
    #: (host.run.progress_guard; None: not guarded)
    progress_limit_s: float | None = PROGRESS_LIMIT_S
    #: wall seconds from the first stop until the graceful stop's remaining work is cut (host.run.stops)
    stop_grace_s: float = STOP_GRACE_S
