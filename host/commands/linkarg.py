"""The ``--link SPEC`` option shared by ``run``, ``demo``, ``pose``, ``tour`` (``board`` hands it to the board).

Parsing is :func:`protocol.linkspec.parse_link_spec`; a bad spec is an argparse error
(exit status 2) naming the problem and the valid forms.
"""

from __future__ import annotations

import argparse

from protocol.linkspec import LinkSpec, LinkSpecError, parse_link_spec

__all__ = ["LINK_HELP", "add_link_argument", "link_spec_arg"]

LINK_HELP = ("pty (start the emulated board on a new pty), a serial port or pyserial URL, or "
             "can:INTERFACE:CHANNEL[?node=N&fd=1&bitrate=B] (can:socketcan:vcan0, can:slcan:pty, can:virtual:bus0; "
             "'can:' = python-can's configured default)")


def link_spec_arg(text: str) -> LinkSpec:
    """argparse ``type=`` for link specs."""
    try:
        return parse_link_spec(text)
    except LinkSpecError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def add_link_argument(parser: argparse.ArgumentParser, *, default: str | None = "pty", help: str = LINK_HELP,
                      required: bool = True) -> None:
    """Add ``--link SPEC`` parsed to a :class:`LinkSpec` (``default`` None: required, or None when not ``required``)."""
    if default is None:
        parser.add_argument("--link", required=required, type=link_spec_arg, metavar="SPEC", help=help)
    else:
        parser.add_argument("--link", default=parse_link_spec(default), type=link_spec_arg, metavar="SPEC",
                            help=help + f" (default {default})")
