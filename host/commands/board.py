"""``ghostshell board ...``: run the emulated board by re-executing ``python -m firmware_sim`` with the arguments.

Every argument after ``board`` (``--help`` included) goes to the board unchanged:
``ghostshell board --link pty --lockstep`` is ``python -m firmware_sim --link pty --lockstep``.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from typing import Any

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("board_args", nargs=argparse.REMAINDER, metavar="ARGS",
                        help="arguments for python -m firmware_sim (its --help lists them; the wire protocol a host "
                             "speaks to the board: docs/wire-protocol.md)")

    # argparse's REMAINDER does not take arguments that start with '-' right after a
    # subcommand, so this subparser hands everything over untouched instead of parsing.
    def parse_known_args(args: Sequence[str] | None = None, namespace: Any = None) -> tuple[Any, list[str]]:
        ns = namespace if namespace is not None else argparse.Namespace()
        for key, value in parser._defaults.items():  # set_defaults(), e.g. the CLI's handler
            setattr(ns, key, value)
        ns.board_args = list(args or [])
        return ns, []

    # setattr: an instance attribute shadows the (overloaded) method, which a plain
    # assignment cannot express to the type checker.
    setattr(parser, "parse_known_args", parse_known_args)


def main(args: argparse.Namespace) -> int:
    argv = list(args.board_args)
    if argv[:1] == ["--"]:
        argv = argv[1:]
    sys.stdout.flush()
    sys.stderr.flush()
    os.environ["GHOSTSHELL_BOARD_PROG"] = "ghostshell board"  # firmware_sim.cli.PROG_ENV: the usage line's name
    os.execv(sys.executable, [sys.executable, "-m", "firmware_sim", *argv])
    return 0  # not reached
