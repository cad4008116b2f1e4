"""``ghostshell firmware build|targets|check``: build the C firmware for a part, list the parts, check a board is alive.

* ``build --robot NAME --target native|mps2|stm32f4 [--out DIR] [--calibrated]`` and ``targets`` re-execute
  ``python -m firmware_sim.cfirmware`` with the arguments (the host never imports firmware_sim;
  ``ghostshell board`` does the same with ``python -m firmware_sim``): the build writes
  ``gs_firmware.elf``, ``.bin`` and ``.hex`` (native: the executable) and prints the flash and RAM the
  image uses against the part's budget, or refuses a robot that does not fit with one line (exit 1).
* ``check --link SPEC [--robot NAME]`` is the host's: the HELLO/CAPS handshake with the board on the
  link, then one telemetry report; it prints one line per fact (link, firmware, robot, servos, schema
  hash, control and telemetry rate, board time, faults) and exits 0. A board that drives another robot
  than ``--robot``, or speaks another message schema or protocol version, gets the link's one-line
  refusal and exit 1 (the check's answer is "not this board", unlike ``pose``, where another robot is
  a usage error); a link that cannot be opened as given exits 2; no board answering exits 1.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from collections.abc import Sequence
from typing import Any

from host.commands.errors import print_error
from host.commands.inputs import baud_rate, positive_seconds
from host.commands.linkarg import USAGE_STATUS, add_link_argument, refuse_unserved_link

__all__ = ["FIRMWARE_PROG_ENV", "PASSED_THROUGH", "configure", "main"]

#: ``firmware_sim.cfirmware.cli.PROG_ENV`` (not imported: the host never imports firmware_sim)
FIRMWARE_PROG_ENV = "GHOSTSHELL_FIRMWARE_PROG"
#: actions run by ``python -m firmware_sim.cfirmware`` (action -> one-line help); host.cli_reference shows their help
PASSED_THROUGH: dict[str, str] = {
    "build": "build the firmware of a robot for a target (native, mps2, stm32f4) into --out: .elf, .bin, .hex",
    "targets": "list the targets: part, flash and RAM budget, build kind, QEMU machine",
}
CHECK_HELP = "check that a board answers on a link: handshake, then one line per fact (exit 1: another robot or schema)"


def _pass_through(parser: argparse.ArgumentParser, action: str) -> None:
    """Make ``parser`` (an action's) keep every argument for ``python -m firmware_sim.cfirmware``."""

    def parse_known_args(args: Sequence[str] | None = None, namespace: Any = None) -> tuple[Any, list[str]]:
        ns = namespace if namespace is not None else argparse.Namespace()
        for key, value in parser._defaults.items():
            setattr(ns, key, value)
        ns.firmware_args = [action, *(args or [])]
        return ns, []

    setattr(parser, "parse_known_args", parse_known_args)  # as host.commands.board: an instance attribute


def _schema_hash(text: str) -> int:
    try:
        v = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a u32 (e.g. 0xdeadbeef), got {text!r}") from None
    if not 0 <= v <= 0xFFFFFFFF:
        raise argparse.ArgumentTypeError(f"a schema hash is a u32, got {text!r}")
    return v


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="firmware_action", metavar="ACTION", required=True)
    for action, help_text in PASSED_THROUGH.items():
        p = sub.add_parser(action, help=help_text, description=help_text, add_help=False)
        p.add_argument("firmware_args", nargs=argparse.REMAINDER, metavar="ARGS",
                       help="arguments for python -m firmware_sim.cfirmware " + action)
        _pass_through(p, action)
    c = sub.add_parser("check", help=CHECK_HELP, description=CHECK_HELP)
    add_link_argument(c, default=None,
                      help="the board's link: a serial port (/dev/ttyUSB0) / pty path / pyserial URL or "
                           "can:INTERFACE:CHANNEL[?node=N]")
    c.add_argument("--robot", default=None, metavar="NAME",
                   help="the robot the board must drive: a name (ghostshell robots list) or a robot folder "
                        "(default: any)")
    from robots.registry import robots_dir_arg

    c.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg,
                   help="a folder of robots searched before the user robot folder and the built-in robots")
    c.add_argument("--baud", type=baud_rate, default=115200, metavar="N", help="baud rate (default 115200)")
    c.add_argument("--timeout", type=positive_seconds, default=3.0, metavar="S",
                   help="seconds to wait for the board's CAPS, and again for its first report (default 3)")
    c.add_argument("--log", default=None, metavar="FILE", help="frame log of this session")
    # test hook: the hash HELLO carries, pinned (a host of another protocol build)
    c.add_argument("--schema-hash", type=_schema_hash, default=None, help=argparse.SUPPRESS)


def _facts(client: Any, tel: Any, want: Any) -> list[str]:
    """The lines ``check`` prints, from the CAPS and the first TELEMETRY."""
    from protocol.codec import schema_by_hash
    from protocol.messages import FaultFlags

    caps = client.caps
    schema = schema_by_hash(client.schema_hash)
    mask = f"u{schema.mask_bytes * 8} servo mask, robots of up to {schema.max_servos} servos" if schema else "unknown"
    faults = [f.name for f in FaultFlags if f.name and f & tel.faults]
    return [
        f"link: {client.port_name} answers (HELLO -> CAPS)",
        f"firmware: GhostShell protocol v{caps.protocol_version}, {'lockstep' if caps.lockstep else 'realtime'}, "
        f"jitter buffer of {caps.buffer_depth} frames",
        f"robot: {caps.robot or '(unnamed)'}, servo table {caps.servo_table_hash:#010x}"
        + (f" (as --robot {want.name})" if want is not None else ""),
        f"servos: {caps.servo_count}",
        f"schema: {client.schema_hash:#010x} ({mask})",
        f"control rate: {caps.control_rate_hz} Hz",
        f"telemetry rate: {caps.telemetry_rate_hz} Hz",
        f"board time: {caps.board_time_us / 1e6:.6f} s at CAPS, {tel.board_time_us / 1e6:.6f} s at its first report",
        f"faults: {', '.join(faults) if faults else 'none'}",
    ]


async def _check(args: argparse.Namespace, want: Any) -> int:
    from host.link import BoardClient, HandshakeError, LinkConfigError, LinkError, RobotIdentity

    identity = None if want is None else RobotIdentity(want.name, want.servo_count, want.servo_table_hash)
    try:
        client = await BoardClient.connect(args.link, baud=args.baud, log_path=args.log, reconnect=False,
                                           robot=identity, schema_hash=args.schema_hash,
                                           handshake_timeout=args.timeout)
    except LinkConfigError as e:  # the link cannot be opened as given
        print_error("firmware check", str(e))
        return USAGE_STATUS
    except HandshakeError as e:  # a board answered, but not as this host's: another robot, schema or version
        print_error("firmware check", str(e))
        return 1
    except LinkError as e:
        print_error("firmware check", f"no board answered on {args.link}: {e}")
        return 1
    try:
        tel = await client.wait_for(lambda t: True, timeout=args.timeout, nudge=True)
        lines = _facts(client, tel, want)
    except LinkError as e:
        print_error("firmware check", f"the board on {client.port_name} answered HELLO but sent no report: {e}")
        return 1
    finally:
        await client.close()
    print("\n".join(lines))
    return 0


def main(args: argparse.Namespace) -> int:
    if args.firmware_action in PASSED_THROUGH:
        argv = list(args.firmware_args)
        if argv[1:2] == ["--"]:
            del argv[1]
        sys.stdout.flush()
        sys.stderr.flush()
        os.environ[FIRMWARE_PROG_ENV] = "ghostshell firmware"
        os.execv(sys.executable, [sys.executable, "-m", "firmware_sim.cfirmware", *argv])
    status = refuse_unserved_link("firmware check", args.link)
    if status is not None:
        return status
    want = None
    if args.robot is not None:
        from robots.description import RobotDataError
        from robots.registry import load_robot

        try:
            want = load_robot(args.robot, args.robots_dir)
        except RobotDataError as e:
            print_error("firmware check", str(e))
            return USAGE_STATUS
    return asyncio.run(_check(args, want))
