"""The session's robot runtime and shell, assembled on a connected link client.

The steps of :meth:`host.run.robot_session.RobotSession.__aenter__` after the link is up
(:func:`host.run.launch.connect_client`), in this order:

1. :func:`first_report`: the link's state settled (a leftover watchdog fault cleared, a board in ESTOP
   refused with :class:`~host.link.errors.BoardFaulted`), then the board's first TELEMETRY.
2. :func:`build_runtime`: the :class:`~host.runtime.robot_runtime.RobotRuntime` on the link's frame path
   (:class:`~host.runtime.link.ClientLink`), starting from the reported positions.
3. :func:`build_shell`: the robot's registry (its vocabulary) and the one :class:`~host.shell.Shell`.
4. :func:`mount_servers`: the MCP servers mounted as shell modules (``--mount-mcp``), if any.

Each runs once per session, before the first frame: nothing here is on the control path.
"""

from __future__ import annotations

import dataclasses
import logging
from contextlib import AbstractAsyncContextManager
from pathlib import Path
from typing import Any

import numpy as np

from host.link import BoardClient
from host.link.faultcheck import clear_leftover_fault
from host.motion.streamer import LOOKAHEAD_US
from host.runtime.binding import robot_registry
from host.runtime.link import ClientLink
from host.runtime.robot_runtime import RobotRuntime
from host.run.launch import LinkPlan
from host.run.options import SessionOptions
from host.shell import Shell
from host.shell.registry import Registry
from protocol.messages import Telemetry
from robots.description import Robot

__all__ = ["build_runtime", "build_shell", "first_report", "mount_servers"]

log = logging.getLogger("host.run")

#: wall seconds the first TELEMETRY may take after the handshake (asked for with a nudge)
FIRST_REPORT_S = 10


async def first_report(client: BoardClient, plan: LinkPlan, *, board_started_here: bool) -> Telemetry:
    """The board's first report on the entered ``client``, after a WATCHDOG_FAULT left over from the previous
    host was cleared (a logged note). Warns when ``--lockstep`` met a board that keeps its own realtime clock.

    Errors: :class:`~host.link.errors.BoardFaulted` for a board in ESTOP
    (:func:`host.link.faultcheck.clear_leftover_fault`); a link error when no report came within
    :data:`FIRST_REPORT_S` wall seconds."""
    if not plan.emulate and plan.lockstep and not client.lockstep:
        # a board you started keeps its own clock: --lockstep here starts no board that would honour it
        log.warning("--lockstep: the board on %s runs in realtime (its CAPS); this run follows the board's "
                    "clock (start the board with `ghostshell board --lockstep`)", plan.spec)
    client.board_started_here = board_started_here  # a fault's line: rerun, not clear a stopped board
    note = await clear_leftover_fault(client)
    if note:
        log.warning("%s", note)
    return await client.wait_for(lambda t: True, timeout=FIRST_REPORT_S, nudge=True)


def build_runtime(robot: Robot, client: BoardClient, plan: LinkPlan, out: Path, tel: Telemetry) -> tuple[RobotRuntime, ClientLink]:
    """The robot runtime for ``robot`` (its run folder ``out``) streaming on ``client`` from the positions of
    ``tel``, on the plan's frame grid with at least three grid periods of lookahead; and its frame link.
    Logs :meth:`LinkPlan.grid_note` when the line stretches the grid."""
    frame_link = ClientLink(client, wire_baud=plan.wire_baud)
    note = plan.grid_note()
    if note is not None:
        log.warning("%s", note)
    runtime = RobotRuntime(robot, frame_link, out, initial=np.asarray(tel.positions),
                           period_us=plan.period_us, lookahead_us=max(LOOKAHEAD_US, 3 * plan.period_us),
                           sparse=frame_link.sparse_frames)
    return runtime, frame_link


def build_shell(robot: Robot, runtime: RobotRuntime, vocabulary: str, opts: SessionOptions) -> Shell:
    """The session's one shell: ``robot``'s ``vocabulary`` bound to ``runtime`` (its registry is
    ``shell.registry``), on the board clock, with the options' mode, strictness, skills and policy."""
    registry = robot_registry(robot, runtime, vocabulary)
    return Shell(registry, mode=opts.mode, strict=opts.strict, clock=runtime.board_now_s,
                 sleep=runtime.sleep, skills=opts.skills, policy=opts.policy)


def mount_servers(opts: SessionOptions, registry: Registry, runtime: RobotRuntime,
                  lockstep: bool) -> AbstractAsyncContextManager[list[Any]]:
    """The MCP servers of ``opts.mcp_mounts`` mounted on ``registry`` while entered (:func:`host.mounts.mounted`:
    a list of :class:`host.mounts.McpMount`; :class:`host.mounts.McpMountError`, one line, when one cannot be
    mounted). On a ``lockstep`` board the virtual clock holds while a server answers (in wall time).
    host.mounts is imported only here (a session without mounts never loads the MCP client)."""
    from host.mounts import MountOptions, mounted

    mount_opts = opts.mount_options or MountOptions()
    if lockstep:  # a server answers in wall time: the virtual board clock waits for it
        mount_opts = dataclasses.replace(mount_opts, around_call=runtime.streamer.hold)
    return mounted(opts.mcp_mounts, registry=registry, options=mount_opts)
