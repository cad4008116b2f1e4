"""``ghostshell pose``: drive the board to a named pose and report the largest error."""

from __future__ import annotations

import argparse
import asyncio
import math
import sys

from host.commands.linkarg import USAGE_STATUS, add_link_argument, refuse_unserved_link

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    add_link_argument(parser, default=None,
                      help="the running board's link: a serial port / pty path / pyserial URL or "
                           "can:INTERFACE:CHANNEL[?node=N] (see DEVELOPERS.md)")
    parser.add_argument("--pose", required=True, metavar="NAME", help="named pose (robots/coco/poses.toml)")
    parser.add_argument("--duration", type=float, default=1.0, metavar="S",
                        help="move time (stretched to respect servo speed limits; default 1.0)")
    parser.add_argument("--baud", type=int, default=115200, metavar="N", help="baud rate (default 115200)")
    parser.add_argument("--log", default=None, metavar="FILE", help="frame log (JSON lines) of this session")
    parser.add_argument("--timeout", type=float, default=5.0, metavar="S",
                        help="board seconds to settle within 3 deg after the move (default 5)")
    parser.add_argument("--tolerance", type=float, default=3.0, metavar="DEG", help=argparse.SUPPRESS)


async def _run(args: argparse.Namespace, target: tuple[float, ...]) -> int:
    from host.link import BoardClient, LinkConfigError, LinkError
    from host.link.faultcheck import clear_leftover_fault
    from host.motion.moves import move_to
    from robots.coco import load_servo_table

    names = load_servo_table().names
    try:
        client = await BoardClient.connect(args.link, baud=args.baud, log_path=args.log, reconnect=False)
    except LinkConfigError as e:  # the link cannot be opened as given
        print(f"ghostshell pose: {e}", file=sys.stderr)
        return USAGE_STATUS
    except LinkError as e:
        print(f"ghostshell pose: no board on {args.link}: {e}", file=sys.stderr)
        return USAGE_STATUS
    try:
        note = await clear_leftover_fault(client)
        if note:
            print(f"ghostshell pose: {note}", file=sys.stderr)
        res = await move_to(client, target, duration_s=args.duration, tolerance_deg=args.tolerance,
                            settle_timeout_s=args.timeout, wall_timeout_s=max(30.0, 4 * args.timeout))
    except LinkError as e:
        print(f"ghostshell pose: pose {args.pose!r} not reached: {e}", file=sys.stderr)
        return 1
    finally:
        await client.close()
    print(f"pose {args.pose!r} reached: largest error {res.max_error_deg:.2f} deg "
          f"({names[res.worst_index]}), {res.frames_sent} frames over {res.duration_s:.2f} s")
    return 0


def main(args: argparse.Namespace) -> int:
    from robots.coco import load_poses

    status = refuse_unserved_link("pose", args.link)
    if status is not None:
        return status

    poses = load_poses()
    if args.pose not in poses:
        print(f"ghostshell pose: unknown pose {args.pose!r}; valid poses: {', '.join(sorted(poses))}", file=sys.stderr)
        return 2
    if not (args.duration >= 0 and math.isfinite(args.duration)) or not args.timeout > 0:
        print("ghostshell pose: --duration must be >= 0 and --timeout > 0", file=sys.stderr)
        return 2
    return asyncio.run(_run(args, poses[args.pose]))
