"""``--robot NAME`` and ``--robots-dir DIR``: the options every command that drives a robot shares.

A robot is a name on the robot search path (:mod:`robots.registry`: ``--robots-dir``,
``$GHOSTSHELL_ROBOTS``, the user robot folder, the built-in robots) or a robot folder. A name that
finds nothing, or a robot package that is malformed (its data, or its interface or behaviours
module failing to import), is a usage error: one line naming what is
wrong (file:line where there is one) and exit status 2, before anything starts.
"""

from __future__ import annotations

import argparse
import sys

from host.commands.errors import print_error
from robots.description import Robot, RobotDataError
from robots.registry import DEFAULT_ROBOT, load_robot, robots_dir_arg

__all__ = ["add_robot_argument", "robot_from_args"]

USAGE_STATUS = 2


def add_robot_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--robot`` (default :data:`robots.registry.DEFAULT_ROBOT`) and ``--robots-dir``."""
    parser.add_argument("--robot", default=DEFAULT_ROBOT, metavar="NAME",
                        help=f"the robot: a name (ghostshell robots list) or a robot folder (default {DEFAULT_ROBOT})")
    parser.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg,
                        help="a folder of robots searched before the user robot folder and the built-in robots")


def robot_from_args(args: argparse.Namespace, command: str) -> Robot | int:
    """The robot ``args`` name, or (after printing one line) the exit status :data:`USAGE_STATUS`."""
    try:
        robot = load_robot(getattr(args, "robot", DEFAULT_ROBOT), getattr(args, "robots_dir", None))
        robot.interface  # imports the package's interface and behaviours modules: their errors now, not mid-run
        return robot
    except RobotDataError as e:
        print_error(command, str(e))
        return USAGE_STATUS
