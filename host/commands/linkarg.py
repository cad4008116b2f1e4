"""The ``--link SPEC`` option shared by ``run``, ``demo``, ``pose``, ``tour`` (``board`` hands it to the board).

Parsing is :func:`protocol.linkspec.parse_link_spec`; a bad spec is an argparse error
(exit status 2) naming the problem and the valid forms. Problems found only later are usage errors
too, with the same status in every command: :func:`unreachable_link` (a spec no board process can
serve, refused before anything starts), :func:`preflight_link` (a port or bus that cannot be opened,
found before anything starts without disturbing a device) and :func:`link_exit_status` (a link that
cannot be opened as specified, :class:`host.link.errors.LinkConfigError`, found when it is opened).
"""

from __future__ import annotations

import argparse
import os
import stat
import sys

from host.commands.errors import print_error
from protocol.linkkinds import link_kind
from protocol.linkspec import LinkSpec, LinkSpecError, parse_link_spec

__all__ = ["LINK_HELP", "USAGE_STATUS", "add_link_argument", "link_exit_status", "link_spec_arg", "preflight_link",
           "unreachable_link"]

USAGE_STATUS = 2  # argparse's status for a usage error; also a link spec that cannot be opened or served

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


def unreachable_link(spec: LinkSpec) -> str | None:
    """Why no board process can ever answer on ``spec`` (one line, for the user), or None.

    python-can's ``virtual`` bus exists inside one process: a board in another process (one
    that is already running, or the one ``--emulate-board`` would start) is never on it. It serves
    in-process use only (tests put a board on it with ``firmware_sim.transports.open_board_transport``).
    """
    if not link_kind(spec).cross_process:
        return (f"--link {spec} is python-can's virtual bus, which exists only inside one process: no board "
                "process can be on it (with or without --emulate-board); use can:slcan:pty (the emulated board as "
                "an SLCAN adapter) or can:socketcan:vcan0 --emulate-board (the virtual bus is for in-process use)")
    return None


def preflight_link(spec: LinkSpec, *, emulated: bool = False, can_start_board: bool = True) -> str | None:
    """Why ``spec`` cannot be opened (one line, for the user), found without disturbing a device, or None.

    * a serial device path must exist and be a character device; it is not opened here (opening a
      USB serial port resets many boards), so a character device that is no tty (``/dev/null``) is
      refused when it is opened (:class:`host.link.errors.LinkConfigError`), as is an SLCAN adapter
      that is not there (``cannot open CAN bus ...``);
    * ``can:`` (no interface) must find one in python-can's configuration (read, no bus opened);
    * SocketCAN (``can:socketcan:...``) is opened and closed again: a raw CAN socket has no effect on
      the bus, and this is where a kernel without SocketCAN or a missing interface shows;
    * ``emulated``: the emulated board creates or opens the link and reports its own refusal;
    * ``can_start_board``: False for commands that only talk to a running board (``pose``, ``estop``),
      whose advice then leaves out ``pty`` (which starts one).
    """
    if emulated:
        return None
    check = link_kind(spec).preflight
    path = spec.port if check == "device" and "://" not in spec.port else None
    if path is not None and os.name == "posix":
        try:
            mode = os.stat(path).st_mode
        except FileNotFoundError:
            return (f"--link {spec}: there is no device {path!r}; give the port a running board announced "
                    "(`ghostshell board --link pty` prints /dev/pts/N), a serial device such as /dev/ttyUSB0"
                    + (", a pyserial URL, or pty to start the emulated board" if can_start_board else " or a pyserial URL"))
        except OSError as e:
            return f"--link {spec}: cannot look at {path!r}: {e.strerror or e}"
        if not stat.S_ISCHR(mode):
            kind = "folder" if stat.S_ISDIR(mode) else "regular file" if stat.S_ISREG(mode) else "file"
            return (f"--link {spec}: {path!r} is a {kind}, not a serial device (a character device such as "
                    "/dev/ttyUSB0 or /dev/pts/N)")
        return None
    if spec.kind == "can" and not spec.interface:
        return _configured_can_problem(spec)
    if check == "open":
        from host.link.errors import LinkConfigError
        from host.link.transports.can import open_bus

        try:
            open_bus(spec).shutdown()
        except LinkConfigError as e:
            return str(e)
    return None


def _configured_can_problem(spec: LinkSpec) -> str | None:
    """Why python-can's configuration (``CAN_INTERFACE``, ``~/.canrc``) names no interface for ``can:``, or
    None: read without opening a bus (:func:`can.util.load_config`, which python-can's ``Bus`` calls)."""
    import can

    from protocol.can.bus_errors import describe_bus_open_error

    try:
        can.util.load_config(config={k: v for k, v in (("channel", spec.channel),) if v})
    except Exception as e:  # python-can raises CanInterfaceNotImplementedError (or a config parse error)
        return describe_bus_open_error(spec, e, interfaces=can.VALID_INTERFACES)
    return None


def refuse_unserved_link(command: str, spec: LinkSpec) -> int | None:
    """For commands that talk to a board already running (``pose``, ``estop``): print why ``spec``
    cannot reach one and return :data:`USAGE_STATUS`, or return None when it can."""
    why = unreachable_link(spec)
    if why is None and spec.implies_emulated_board:
        why = (f"--link {spec} names a link the emulated board creates; give the port a running board "
               "announced (ghostshell board --link pty prints it)")
    if why is None:
        why = preflight_link(spec, can_start_board=False)
    if why is None:
        return None
    print_error(command, str(why))
    return USAGE_STATUS


def link_exit_status(error: BaseException) -> int:
    """Exit status for a link failure: :data:`USAGE_STATUS` (2) when the link cannot be opened or served as
    specified (:class:`host.link.errors.LinkConfigError`, :class:`protocol.linkspec.LinkSpecError`) or the
    board drives another robot (:class:`host.link.errors.RobotMismatch`) or a ``--mount-mcp`` server cannot be
    mounted (``host.mounts.McpMountError``), else 1."""
    from host.link.errors import LinkConfigError, RobotMismatch

    if isinstance(error, (LinkConfigError, LinkSpecError, RobotMismatch)):
        return USAGE_STATUS
    if type(error).__name__ == "McpMountError":
        from host.mounts.mcp_mount import McpMountError

        return USAGE_STATUS if isinstance(error, McpMountError) else 1
    return 1
