"""``ghostshell estop``: send ESTOP to a running board, or ESTOP_CLEAR with ``--clear``.

ESTOP makes the board stop where it is and refuse every servo frame (NACK ESTOPPED)
until ESTOP_CLEAR (an emulated board holds; one driving real servos holds, or lets them go limp with
``--estop-torque limp``, and says which on its stderr); ESTOP_CLEAR also releases a latched WATCHDOG_FAULT (a board that
lost its host). Either request is re-sent until the board acknowledges it
(:meth:`host.link.BoardClient.request` retries). ``--clear`` says what it cleared (the
board's report before the request: an ESTOP, a watchdog fault, or nothing was latched).
Exit status: 0 acknowledged (for ``--clear``: and the board reports no fault afterwards), 1 not
acknowledged or refused, or no board answered on the link, 2 bad arguments or a link that cannot
be opened as given.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from host.commands.errors import print_error
from host.commands.outarg import out_file
from host.commands.inputs import baud_rate
from host.commands.linkarg import USAGE_STATUS, add_link_argument, refuse_unserved_link

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    add_link_argument(parser, default=None,
                      help="the running board's link: a serial port / pty path / pyserial URL or "
                           "can:INTERFACE:CHANNEL[?node=N] (docs/concepts/wire.md)")
    parser.add_argument("--clear", action="store_true",
                        help="send ESTOP_CLEAR (release an estop or a latched watchdog fault) instead of ESTOP")
    parser.add_argument("--baud", type=baud_rate, default=115200, metavar="N", help="baud rate (default 115200)")
    parser.add_argument("--log", type=out_file, default=None, metavar="FILE", help="frame log of this session")


async def _run(args: argparse.Namespace) -> int:
    from host.link import BoardClient, LinkConfigError, LinkError
    from host.link.faultcheck import LATCHED, clear_command
    from protocol.messages import FaultFlags

    try:
        client = await BoardClient.connect(args.link, baud=args.baud, log_path=args.log, reconnect=False)
    except LinkConfigError as e:  # the link cannot be opened as given
        print_error("estop", str(e))
        return USAGE_STATUS
    except LinkError as e:
        print_error("estop", f"no board answered on {args.link}: {e}")
        return 1
    try:
        if args.clear:
            before = await client.wait_for(lambda t: True, timeout=5.0, nudge=True)  # what is latched now
            latched = FaultFlags(before.faults & LATCHED)
            await client.estop_clear()
            at = client.board_now_estimate()
            tel = await client.wait_for(lambda t: t.board_time_us > at, timeout=5.0, nudge=True)
            if tel.faults & LATCHED:
                print_error("estop", f"ESTOP_CLEAR acknowledged but the board still reports "
                      f"{_names(FaultFlags(tel.faults & LATCHED))}")
                return 1
            what = (f"cleared its {_names(latched)}; it takes motion again" if latched else
                    "nothing was latched (no estop, no watchdog fault)")
            print(f"board on {client.port_name}: ESTOP_CLEAR acknowledged; {what}")
        else:
            await client.estop()
            # "stops", not "holds": a board driving real servos with --estop-torque limp lets them go limp
            # (its stderr says which); the ACK does not tell, so the line claims only what is true of both
            print(f"board on {client.port_name}: ESTOP acknowledged; it stops and refuses motion until "
                  f"`{clear_command(client.link_spec)}`")
    except LinkError as e:
        what = "ESTOP_CLEAR" if args.clear else "ESTOP"
        print_error("estop", f"{what} not acknowledged by the board on {args.link}: {e}")
        return 1
    finally:
        await client.close()
    return 0


def _names(flags: object) -> str:
    """``ESTOP and WATCHDOG_FAULT`` from latched fault flags."""
    from protocol.messages import FaultFlags

    names = [f.name for f in FaultFlags if f & flags and f.name]  # type: ignore[operator]
    return " and ".join(n.replace("ESTOP", "estop").replace("WATCHDOG_FAULT", "watchdog fault") for n in names)


def main(args: argparse.Namespace) -> int:
    status = refuse_unserved_link("estop", args.link)
    if status is not None:
        return status
    return asyncio.run(_run(args))
