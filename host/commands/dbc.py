"""``ghostshell dbc --robot NAME [--fd] [--nodes 1,2]``: print a robot's CAN database (DBC) on stdout.

The DBC is generated from the robot's CAN layouts (:func:`protocol.can.layouts.can_layouts` for its
servo count; :mod:`protocol.can.make_dbc`), so it describes exactly the frames host and board send
for that robot: classic CAN by default, CAN FD with ``--fd``; one set of messages per node id in
``--nodes`` (default 1,2). For a built-in robot that checks its DBC in (``robots/NAME/NAME.dbc``,
``NAME_fd.dbc``) the output is that file, byte for byte. Exit status: 0 printed; 2 a robot that
names nothing or is malformed, or bad ``--nodes`` (one line on stderr).
"""

from __future__ import annotations

import argparse
import sys

from host.commands.robotarg import USAGE_STATUS, add_robot_argument, robot_from_args

__all__ = ["configure", "main", "parse_nodes"]


def parse_nodes(text: str) -> tuple[int, ...]:
    """``"1,2"`` -> ``(1, 2)``: node ids 1..127, at least one, no repeats (argparse type)."""
    try:
        nodes = tuple(int(n) for n in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated node ids (1..127), got {text!r}") from None
    if not nodes or len(set(nodes)) != len(nodes) or not all(1 <= n <= 127 for n in nodes):
        raise argparse.ArgumentTypeError(f"node ids must be distinct, each 1..127, got {text!r}")
    return nodes


def configure(parser: argparse.ArgumentParser) -> None:
    add_robot_argument(parser)
    parser.add_argument("--fd", action="store_true", help="the CAN FD database (default: classic CAN)")
    parser.add_argument("--nodes", type=parse_nodes, default=(1, 2), metavar="1,2",
                        help="node ids the database covers, comma-separated (default 1,2)")


def main(args: argparse.Namespace) -> int:
    robot = robot_from_args(args, "dbc")
    if isinstance(robot, int):
        return robot
    from protocol.can.make_dbc import DbcRobot, dbc_text

    try:
        text = dbc_text(bool(args.fd), tuple(args.nodes), robot=DbcRobot(robot.name, robot.title, robot.servo_count))
    except ValueError as e:  # a servo count the wire cannot carry (the loader refuses it first)
        print(f"ghostshell dbc: {robot.name}: {e}", file=sys.stderr)
        return USAGE_STATUS
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:  # e.g. piped into head
        return 0
    return 0
