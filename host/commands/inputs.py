"""Input files and values every command refuses the same way: one line, exit status 2, before anything starts.

:func:`read_text_input` reads a text file a command was given (``run --xml-file``, ``chat --turns``
/ ``--replies``, ``eval --replies``, ``dsbc @FILE``, ...): a missing or unreadable file, a folder, a
file that is not UTF-8 text, an empty (or whitespace-only) file and one larger than its cap (a few MiB,
:mod:`host.bounded_read`; ``/dev/zero`` or an endless pipe is refused after cap + 1 bytes) are each an
:class:`InputError` naming the option, the file and what would be right. ``-`` names standard input
(:data:`STDIN`).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

from host.bounded_read import MAX_PROGRAM, MAX_TEXT, InputTooLarge, read_capped, stdin_bytes
from protocol.wiremodel import MAX_BAUD, baud_arg

__all__ = ["MAX_BAUD", "MAX_PROGRAM", "MAX_TEXT", "STDIN", "InputError", "baud_rate", "port_number", "positive_seconds", "read_text_input", "seconds",
           "whole_number"]


#: the file name that means standard input (``run --xml-file -``)
STDIN = "-"


class InputError(ValueError):
    """An input the command cannot use (one line, for the user)."""


def read_text_input(path: str | Path, option: str, *, what: str = "text", allow_empty: bool = False,
                    cap: int = MAX_TEXT) -> str:
    """The UTF-8 text of ``path``, given with ``option`` (e.g. ``"--xml-file"``); :class:`InputError`
    when it is missing, unreadable, not a file, not UTF-8, more than ``cap`` bytes (read no further
    than cap + 1), or (unless ``allow_empty``) holds only whitespace. ``path`` ``-`` reads standard
    input to its end (at most ``cap`` bytes)."""
    try:
        if str(path) == STDIN:
            if sys.stdin is None:
                raise InputError(f"{option} -: there is no standard input to read")
            path = "- (standard input)"
            data = stdin_bytes(cap)
        else:
            data = read_capped(path, cap)
    except InputTooLarge as e:
        raise InputError(f"{option} {path}: {e}; give a smaller file of {what}") from None
    except IsADirectoryError:
        raise InputError(f"{option} {path} is a folder; give a file of {what}") from None
    except OSError as e:
        raise InputError(f"{option} {path}: cannot read it ({e.strerror or e})") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"{option} {path} is not UTF-8 text ({e.reason} at byte {e.start}); "
                         f"give a UTF-8 file of {what}") from None
    if not allow_empty and not text.strip():
        raise InputError(f"{option} {path} is empty: nothing to run; give a file of {what}")
    return text


def port_number(text: str) -> int:
    """argparse ``type=`` for a TCP port: a whole number 1..65535."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a TCP port number 1-65535, got {text!r}") from None
    if not 1 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"a TCP port is 1-65535, got {v}")
    return v


def _number(text: str, what: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def seconds(text: str) -> float:
    """argparse ``type=`` for a duration: a finite number of seconds >= 0."""
    v = _number(text, "a number of seconds")
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0 seconds, got {text}")
    return v


def positive_seconds(text: str) -> float:
    """argparse ``type=`` for a timeout: a finite number of seconds > 0."""
    v = _number(text, "a number of seconds")
    if v <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0 seconds, got {text}")
    return v


def whole_number(lo: int, hi: int | None = None) -> Callable[[str], int]:
    """argparse ``type=`` for a whole number ``>= lo`` (and ``<= hi`` if given), e.g. ``--workers``."""
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
        if v < lo or hi is not None and v > hi:
            raise argparse.ArgumentTypeError(f"must be >= {lo}, got {text}" if hi is None else
                                             f"must be {lo}..{hi}, got {v}")
        return v
    return parse


#: ``--baud``'s parser and bound are shared with the board's command line (protocol.wiremodel)
baud_rate = baud_arg
