"""``ghostshell mcp``: serve the shell over the Model Context Protocol (stdio or streamable HTTP).

Every argument is checked before the board starts (exit status 2, one line). Ctrl-C / SIGTERM stop
the server: a running program is interrupted, the robot goes to its rest pose, the board stops,
one line, exit status 130 (see :mod:`host.mcp_server.server`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from host.commands.modearg import add_mode_argument
from host.commands.errors import print_error
from host.commands.inputs import port_number
from host.commands.linkarg import USAGE_STATUS, add_link_argument, preflight_link, unreachable_link
from host.commands.outarg import (EarlierRun, add_no_plots_argument, out_dir, out_dir_problem, session_start_files,
                                  tcp_port_taken)
from host.commands.robotarg import add_robot_argument, robot_from_args


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the mcp options."""
    parser.add_argument("--http", type=port_number, default=None, metavar="PORT",
                        help="streamable HTTP on 127.0.0.1:PORT (path /mcp) instead of stdio")
    clock = parser.add_mutually_exclusive_group()
    clock.add_argument("--lockstep", dest="lockstep", action="store_true", help="virtual-time board")
    clock.add_argument("--realtime", dest="lockstep", action="store_false", help="wall-clock board (default)")
    parser.set_defaults(lockstep=False)
    add_robot_argument(parser)
    from host.commands.run import add_mount_argument

    add_mount_argument(parser)
    parser.add_argument("--vocabulary", default=None, metavar="NAME",
                        help="the robot's vocabulary in the prompt (default: the robot's; ghostshell robots show NAME lists them)")
    add_mode_argument(parser)
    parser.add_argument("--scene", default=None, metavar="NAME",
                        help="objects in the board's world: one of the robot's scenes (default: the robot's)")
    add_link_argument(parser)
    parser.add_argument("--emulate-board", action="store_true",
                        help="start the emulated board on --link first (implied for pty and can:slcan:pty)")
    parser.add_argument("--out", type=out_dir, default=Path("runs/mcp"), metavar="DIR",
                        help="session folder (frame logs, turns; default runs/mcp)")
    add_no_plots_argument(parser, "turn")


def main(args: argparse.Namespace) -> int:
    """Serve until stdin closes (stdio) or the process is stopped (HTTP)."""
    why = unreachable_link(args.link) or preflight_link(
        args.link, emulated=args.emulate_board or args.link.implies_emulated_board)
    if why:
        print_error("mcp", str(why))
        return USAGE_STATUS
    robot = robot_from_args(args, "mcp")
    if isinstance(robot, int):
        return robot
    if args.vocabulary is not None and args.vocabulary not in robot.interface.names:
        print_error("mcp", f"--vocabulary {args.vocabulary!r}: {robot.name} has {', '.join(robot.interface.names)}")
        return 2
    if args.scene is not None and args.scene not in robot.scenes:
        print_error("mcp", f"--scene {args.scene!r}: {robot.name} has {', '.join(robot.scenes)}")
        return 2
    from host.commands.run import mount_problem

    why = mount_problem(args, robot)
    if why is None and args.http is not None:
        why = tcp_port_taken(args.http)
        why = None if why is None else f"--http {args.http}: {why}"
    if why is None and not isinstance(args.out, Path):
        args.out = Path(args.out)
    if why is None:
        problem = out_dir_problem(args.out)  # the default folder (a given --out was checked when parsed)
        why = None if problem is None else f"--out {args.out} {problem}"
    if why:
        print_error("mcp", str(why))
        return USAGE_STATUS
    try:
        from host.mcp_server.server import serve
    except ImportError as err:
        print_error("mcp", f"the MCP SDK is missing ({err}); pip install 'mcp>=2'")
        return 2
    from host.link import LinkError
    from host.run.robot_session import SessionOptions

    opts = SessionOptions(robot=str(robot.root), robots_dir=args.robots_dir, vocabulary=args.vocabulary,
                          mode=args.mode, lockstep=args.lockstep, link=args.link,
                          emulate_board=args.emulate_board or None, out=args.out, task_label="mcp", scene=args.scene,
                          mcp_mounts=tuple(args.mount_mcp), plots=not args.no_plots)
    try:  # the files the session's start overwrites: set aside, and back if the start is refused
        earlier = EarlierRun(args.out, only=session_start_files())
    except OSError as e:
        print_error("mcp", f"{args.out}/ holds an earlier session's files that cannot be moved: {e}")
        return 1
    try:
        try:
            stop = serve(opts, args.http, on_started=earlier.discard)
        except BaseExceptionGroup as group:  # the server's task groups wrap the session's own error
            raise _sole(group) from None
        finally:
            earlier.restore()  # the session never started (a no-op once it did)
    except (LinkError, RuntimeError, OSError) as e:
        from host.commands.linkarg import link_exit_status

        print_error("mcp", str(e))
        return link_exit_status(e)
    if stop is not None:
        print_error("mcp", f"{stop.message}; the server stopped and the board with it; session in {args.out}/")
        return 130
    return 0


def _sole(group: BaseExceptionGroup[BaseException]) -> BaseException:
    """The one exception ``group`` holds, however deeply nested (a session that could not start, raised in
    the MCP SDK's task groups inside ours), or ``group`` itself when it holds several."""
    inner: BaseException = group
    while isinstance(inner, BaseExceptionGroup) and len(inner.exceptions) == 1:
        inner = inner.exceptions[0]
    return inner
