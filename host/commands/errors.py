"""The one form of a command's error line: ``ghostshell COMMAND: message``, one line on stderr.

Every command prints its errors (and its one-line notes about a run that ended early) through
:func:`print_error`, so a user or a script reading stderr sees the same prefix whichever command
failed; the exit status is the command's (:data:`host.cli.EXIT_CODES`).
"""

from __future__ import annotations

import argparse
import sys
from typing import IO

__all__ = ["PROG", "command_of", "error_prefix", "print_error"]

PROG = "ghostshell"


def error_prefix(command: str | None) -> str:
    """``"ghostshell COMMAND: "`` (``"ghostshell: "`` when no command is known)."""
    return f"{PROG} {command}: " if command else f"{PROG}: "


def command_of(args: argparse.Namespace, default: str = "run") -> str:
    """The subcommand an argparse namespace was parsed for (``default`` for one built by hand)."""
    return str(getattr(args, "command", None) or default)


def print_error(command: str | None, message: str, *, file: IO[str] | None = None) -> None:
    """Print ``ghostshell COMMAND: message`` on ``file`` (default stderr; any object with ``write``)."""
    out = sys.stderr if file is None else file
    print(error_prefix(command) + message, file=out)
