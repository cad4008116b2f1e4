"""``ghostshell dbc --robot NAME [--fd] [--nodes 1,2] [--check | --write]``: a robot's CAN database (DBC).

The DBC is generated from the robot's CAN layouts (:func:`protocol.can.layouts.can_layouts` for its
servo count; :mod:`protocol.can.make_dbc`), so it describes exactly the frames host and board send
for that robot: classic CAN by default, CAN FD with ``--fd``; one set of messages per node id in
``--nodes`` (default 1,2). Printed on stdout by default.

A robot may check its DBCs in next to its robot.toml (:func:`dbc_files`: ``NAME.dbc`` and
``NAME_fd.dbc``; the built-in robots do). ``--check`` compares both files with the generated text (exit 1, one line
per file that is missing or differs, on stderr); ``--write`` rewrites both (one ``wrote PATH`` line
each). For a robot that checks its DBC in, plain output is that file, byte for byte.

Exit status: 0 printed / current / written; 1 ``--check`` found a difference; 2 a robot that names
nothing or is malformed, bad ``--nodes``, or ``--fd`` with ``--check``/``--write`` (they handle both
files) (one line on stderr).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from host.commands.errors import print_error
from host.commands.robotarg import USAGE_STATUS, add_robot_argument, robot_from_args

__all__ = ["configure", "dbc_files", "main", "parse_nodes"]


def parse_nodes(text: str) -> tuple[int, ...]:
    """``"1,2"`` -> ``(1, 2)``: node ids 1..127, at least one, no repeats (argparse type)."""
    try:
        nodes = tuple(int(n) for n in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated node ids (1..127), got {text!r}") from None
    if not nodes or len(set(nodes)) != len(nodes) or not all(1 <= n <= 127 for n in nodes):
        raise argparse.ArgumentTypeError(f"node ids must be distinct, each 1..127, got {text!r}")
    return nodes


def dbc_files(folder: Path, name: str) -> tuple[tuple[bool, Path], tuple[bool, Path]]:
    """Where a robot checks its DBCs in: ``(False, folder/NAME.dbc), (True, folder/NAME_fd.dbc)``."""
    return (False, folder / f"{name}.dbc"), (True, folder / f"{name}_fd.dbc")


def configure(parser: argparse.ArgumentParser) -> None:
    add_robot_argument(parser)
    parser.add_argument("--fd", action="store_true", help="the CAN FD database (default: classic CAN)")
    parser.add_argument("--nodes", type=parse_nodes, default=(1, 2), metavar="1,2",
                        help="node ids the database covers, comma-separated (default 1,2)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true",
                      help="compare the robot's checked-in NAME.dbc and NAME_fd.dbc with the generated ones (exit 1 "
                           "on a difference)")
    mode.add_argument("--write", action="store_true", help="rewrite the robot's NAME.dbc and NAME_fd.dbc")


def main(args: argparse.Namespace) -> int:
    if args.fd and (args.check or args.write):
        print_error("dbc", "--check and --write handle both files (classic and FD); drop --fd")
        return USAGE_STATUS
    robot = robot_from_args(args, "dbc")
    if isinstance(robot, int):
        return robot
    from protocol.can.make_dbc import DbcRobot, dbc_text

    who = DbcRobot(robot.name, robot.title, robot.servo_count)
    try:
        if not (args.check or args.write):
            text = dbc_text(bool(args.fd), tuple(args.nodes), robot=who)
        else:
            files = [(path, dbc_text(fd, tuple(args.nodes), robot=who)) for fd, path in dbc_files(robot.root, robot.name)]
    except ValueError as e:  # a servo count the wire cannot carry (the loader refuses it first)
        print_error("dbc", f"{robot.name}: {e}")
        return USAGE_STATUS
    if args.check:
        return _check(files, robot.name)
    if args.write:
        return _write(files)
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:  # e.g. piped into head
        return 0
    return 0


def _check(files: list[tuple[Path, str]], name: str) -> int:
    status = 0
    for path, text in files:
        if not path.is_file():
            why = "is missing"
        elif path.read_text(encoding="utf-8") != text:
            why = "differs from the generated DBC"
        else:
            continue
        print_error("dbc", f"{path} {why} (ghostshell dbc --robot {name} --write)")
        status = 1
    return status


def _write(files: list[tuple[Path, str]]) -> int:
    for path, text in files:
        try:
            path.write_text(text, encoding="utf-8")
        except OSError as e:
            print_error("dbc", f"cannot write {path}: {e.strerror or e}")
            return 1
        print(f"wrote {path}")
    return 0
