"""``ghostshell estop``: send ESTOP to a running board, or ESTOP_CLEAR with ``--clear``.

ESTOP makes the board hold where it is and refuse every servo frame (NACK ESTOPPED)
until ESTOP_CLEAR; ESTOP_CLEAR also releases a latched WATCHDOG_FAULT (a board that
lost its host). Either request is re-sent until the board acknowledges it
(:meth:`host.link.BoardClient.request` retries). Exit status: 0 acknowledged (for
``--clear``: and the board reports no fault afterwards), 1 not acknowledged or
refused, 2 bad arguments or no board on the link.
"""

from __future__ import annotations

import argparse
import asyncio
import sys

from host.commands.linkarg import USAGE_STATUS, add_link_argument, refuse_unserved_link

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    add_link_argument(parser, default=None,
                      help="the running board's link: a serial port / pty path / pyserial URL or "
                           "can:INTERFACE:CHANNEL[?node=N] (see DEVELOPERS.md)")
    parser.add_argument("--clear", action="store_true",
                        help="send ESTOP_CLEAR (release an estop or a latched watchdog fault) instead of ESTOP")
    parser.add_argument("--baud", type=int, default=115200, metavar="N", help="baud rate (default 115200)")
    parser.add_argument("--log", default=None, metavar="FILE", help="frame log of this session")


async def _run(args: argparse.Namespace) -> int:
    from host.link import BoardClient, LinkConfigError, LinkError
    from host.link.faultcheck import LATCHED, clear_command
    from protocol.messages import FaultFlags

    try:
        client = await BoardClient.connect(args.link, baud=args.baud, log_path=args.log, reconnect=False)
    except LinkConfigError as e:  # the link cannot be opened as given
        print(f"ghostshell estop: {e}", file=sys.stderr)
        return USAGE_STATUS
    except LinkError as e:
        print(f"ghostshell estop: no board on {args.link}: {e}", file=sys.stderr)
        return USAGE_STATUS
    try:
        if args.clear:
            await client.estop_clear()
            at = client.board_now_estimate()
            tel = await client.wait_for(lambda t: t.board_time_us > at, timeout=5.0, nudge=True)
            if tel.faults & LATCHED:
                print(f"ghostshell estop: ESTOP_CLEAR acknowledged but the board still reports "
                      f"{FaultFlags(tel.faults & LATCHED)!r}", file=sys.stderr)
                return 1
            print(f"board on {client.port_name}: ESTOP_CLEAR acknowledged; no estop or watchdog fault latched")
        else:
            await client.estop()
            print(f"board on {client.port_name}: ESTOP acknowledged; it holds and refuses motion until "
                  f"`{clear_command(client.link_spec)}`")
    except LinkError as e:
        what = "ESTOP_CLEAR" if args.clear else "ESTOP"
        print(f"ghostshell estop: {what} not acknowledged by the board on {args.link}: {e}", file=sys.stderr)
        return 1
    finally:
        await client.close()
    return 0


def main(args: argparse.Namespace) -> int:
    status = refuse_unserved_link("estop", args.link)
    if status is not None:
        return status
    return asyncio.run(_run(args))
