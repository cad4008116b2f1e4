"""``ghostshell pose``: drive the board to a named pose and report the largest error."""

from __future__ import annotations

import argparse
import asyncio
import math
import sys

from host.commands.errors import print_error
from host.commands.outarg import out_file
from host.commands.inputs import baud_rate, positive_seconds, seconds
from host.commands.linkarg import USAGE_STATUS, add_link_argument, refuse_unserved_link
from host.commands.robotarg import add_robot_argument, robot_from_args
from robots.description import Robot

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    add_link_argument(parser, default=None,
                      help="the running board's link: a serial port / pty path / pyserial URL or "
                           "can:INTERFACE:CHANNEL[?node=N] (docs/concepts/wire.md)")
    parser.add_argument("--pose", required=True, metavar="NAME", help="one of the robot's named poses "
                        "(ghostshell robots show NAME lists them)")
    add_robot_argument(parser)
    parser.add_argument("--duration", type=seconds, default=1.0, metavar="S",
                        help="move time (stretched to respect servo speed limits; default 1.0)")
    parser.add_argument("--baud", type=baud_rate, default=115200, metavar="N", help="baud rate (default 115200)")
    parser.add_argument("--log", type=out_file, default=None, metavar="FILE", help="frame log (JSON lines) of this session")
    parser.add_argument("--timeout", type=positive_seconds, default=5.0, metavar="S",
                        help="board seconds to settle within 3 deg after the move (default 5)")
    parser.add_argument("--tolerance", type=float, default=3.0, metavar="DEG", help=argparse.SUPPRESS)


async def _run(args: argparse.Namespace, robot: Robot, target: tuple[float, ...]) -> int:
    from host.link import BoardClient, LinkConfigError, LinkError, RobotIdentity, RobotMismatch
    from host.link.faultcheck import clear_leftover_fault
    from host.motion.moves import move_to
    from robots.motion import JointLimits

    names = robot.servos.names
    identity = RobotIdentity(robot.name, robot.servo_count, robot.servo_table_hash)
    try:
        client = await BoardClient.connect(args.link, baud=args.baud, log_path=args.log, reconnect=False,
                                           robot=identity)
    except (LinkConfigError, RobotMismatch) as e:  # the link cannot be opened as given, or another robot
        print_error("pose", str(e))
        return USAGE_STATUS
    except LinkError as e:  # the port opened but no board answered there as one should
        print_error("pose", f"no board answered on {args.link}: {e}")
        return 1
    try:
        note = await clear_leftover_fault(client)
        if note:
            print_error("pose", str(note))
        res = await move_to(client, target, JointLimits.of_robot(robot), duration_s=args.duration, tolerance_deg=args.tolerance,
                            settle_timeout_s=args.timeout, wall_timeout_s=max(30.0, 4 * args.timeout))
    except LinkError as e:
        print_error("pose", f"pose {args.pose!r} not reached: {e}")
        return 1
    finally:
        await client.close()
    print(f"pose {args.pose!r} reached: largest error {res.max_error_deg:.2f} deg "
          f"({names[res.worst_index]}), {res.frames_sent} frames over {res.duration_s:.2f} s")
    return 0


def main(args: argparse.Namespace) -> int:
    status = refuse_unserved_link("pose", args.link)
    if status is not None:
        return status
    robot = robot_from_args(args, "pose")
    if isinstance(robot, int):
        return robot
    poses = robot.poses
    if args.pose not in poses:
        print_error("pose", f"{robot.name} has no pose {args.pose!r}; valid poses: {', '.join(sorted(poses))}")
        return 2
    if not (args.duration >= 0 and math.isfinite(args.duration)) or not args.timeout > 0:
        print_error("pose", "--duration must be >= 0 and --timeout > 0")
        return 2
    return asyncio.run(_run(args, robot, poses[args.pose]))
