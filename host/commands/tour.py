"""``ghostshell tour``: start a board (on ``--link``, default a pty), drive it through the named poses, print telemetry, shut down.

With ``--link`` naming a link the emulated board does not create (a serial port, a CAN bus)
the tour drives the board already there, unless ``--emulate-board`` starts one on it first.

The bridge's own end-to-end check (``ghostshell demo`` runs a whole task). The board is a real
subprocess (``python -m firmware_sim --link pty``); the host talks to it with
:class:`host.link.BoardClient` exactly as it would to hardware.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import shutil
import signal
import sys
import time
from pathlib import Path
from typing import Any

from host.commands.errors import print_error
from host.commands.inputs import seconds
from host.commands.linkarg import USAGE_STATUS, add_link_argument, link_exit_status, preflight_link, unreachable_link
from host.commands.outarg import out_dir
from host.commands.robotarg import add_robot_argument, robot_from_args
from host.link.board_process import BoardProcess, dead_board_error, start_board
from protocol.linkspec import LinkSpec
from robots.description import Robot

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--realtime", dest="lockstep", action="store_false", help="board paced to the wall clock (default)")
    mode.add_argument("--lockstep", dest="lockstep", action="store_true", help="board on virtual time, as fast as it goes")
    parser.set_defaults(lockstep=False)
    parser.add_argument("--out", type=out_dir, default=None, metavar="DIR",
                        help="write the frame logs (board.jsonl, host.jsonl), board stderr and summary.json here")
    parser.add_argument("--duration", type=seconds, default=1.0, metavar="S", help="seconds per pose move (default 1.0)")
    add_link_argument(parser)
    parser.add_argument("--emulate-board", action="store_true",
                        help="start the emulated board on --link first (implied for pty and can:slcan:pty)")
    add_robot_argument(parser)


def _deg(v: float) -> str:
    return f"{math.degrees(v):6.1f}" if math.isfinite(v) else "   nan"


async def _printer(client: Any, names: tuple[str, ...], state: dict[str, Any], live: Any) -> None:
    from rich.table import Table

    last = 0.0
    async for t in client.telemetry(maxsize=4):
        now = time.monotonic()
        if now - last < 0.2:
            continue
        last = now
        if live is None:
            print(f"t={t.board_time_us / 1e6:7.3f}s pose={state['pose']:<8} faults={int(t.faults):#04x} "
                  f"buf={t.buffer_fill:3d} q(deg)=[" + " ".join(_deg(v) for v in t.positions) + "]", flush=True)
            continue
        table = Table(title=f"{state['robot']}  board time {t.board_time_us / 1e6:7.3f} s   pose -> {state['pose']}")
        table.add_column("servo")
        table.add_column("pos deg", justify="right")
        table.add_column("vel rad/s", justify="right")
        table.add_column("effort N*m", justify="right")
        for i, name in enumerate(names):
            table.add_row(name, _deg(t.positions[i]), f"{t.velocities[i]:7.2f}", f"{t.efforts[i]:7.3f}")
        table.caption = (f"faults {int(t.faults):#04x}  buffer {t.buffer_fill}  last seq {t.last_applied_seq}  "
                         f"late {t.late_count}  dropped {t.dropped_count}  link errors {t.link_errors}")
        live.update(table)


async def _drive(port: LinkSpec, args: argparse.Namespace, out: Path | None, robot: Robot) -> dict[str, Any]:
    from host.link import BoardClient, RobotIdentity
    from host.link.faultcheck import clear_leftover_fault
    from host.motion.moves import move_to
    from robots.motion import JointLimits

    poses = robot.poses
    names = robot.servos.names
    limits = JointLimits.of_robot(robot)
    identity = RobotIdentity(robot.name, robot.servo_count, robot.servo_table_hash)
    state: dict[str, Any] = {"pose": "-", "robot": robot.title}
    results: list[dict[str, Any]] = []
    live = None
    if sys.stdout.isatty():
        from rich.live import Live

        live = Live(refresh_per_second=8)
        live.start()
    try:
        async with await BoardClient.connect(port, log_path=out / "host.jsonl" if out else None, reconnect=False,
                                             robot=identity) as client:
            note = await clear_leftover_fault(client)
            if note:
                print_error("tour", str(note))
            printer = asyncio.create_task(_printer(client, names, state, live))
            try:
                for name in robot.tour:
                    state["pose"] = name
                    res = await move_to(client, poses[name], limits, duration_s=args.duration)
                    results.append({"pose": name, "max_error_deg": round(res.max_error_deg, 3),
                                    "worst": names[res.worst_index], "board_time_s": res.board_time_us / 1e6})
                    msg = f"reached {name:<8} largest error {res.max_error_deg:.2f} deg ({names[res.worst_index]})"
                    (live.console.print if live else print)(msg)
            finally:
                printer.cancel()
            est = client.clock_estimate
            return {
                "mode": "lockstep" if client.lockstep else "realtime",
                "poses": results,
                "stats": vars(client.stats),
                "clock": None if est is None else {"offset_us": est.offset_us, "drift_ppm": est.drift_ppm,
                                                   "uncertainty_us": est.uncertainty_us},
            }
    finally:
        if live is not None:
            live.stop()


def main(args: argparse.Namespace) -> int:
    from host.link import LinkConfigError, LinkError

    spec: LinkSpec = args.link
    why = unreachable_link(spec) or preflight_link(spec, emulated=args.emulate_board or spec.implies_emulated_board)
    if why:
        print_error("tour", str(why))
        return USAGE_STATUS
    robot = robot_from_args(args, "tour")
    if isinstance(robot, int):
        return robot
    out = Path(args.out) if args.out else None
    created = out is not None and not out.exists()
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    board: BoardProcess | None = None
    if args.emulate_board or spec.implies_emulated_board:
        board_args = ["--lockstep" if args.lockstep else "--realtime", "--robot", str(robot.root)]
        if out is not None:
            board_args += ["--log", str(out / "board.jsonl")]
        try:
            board = start_board(board_args, out / "board.stderr" if out else None, link=spec)
        except (LinkError, RuntimeError, OSError) as e:
            print_error("tour", str(e))
            if created and out is not None:  # refused before anything ran: no folder left
                shutil.rmtree(out, ignore_errors=True)
            return USAGE_STATUS
        print(f"board running on {board.port} ({'lockstep' if args.lockstep else 'realtime'})", flush=True)
        spec = board.spec
    code = 0
    rc = 0
    try:
        summary = asyncio.run(_drive(spec, args, out, robot))
    except LinkError as e:
        dead = dead_board_error(board, e) if isinstance(e, LinkConfigError) else None
        if dead is not None:  # the board it started died first: a lost link (1), not a usage error (2)
            e = dead
        print_error("tour", str(e))
        code = link_exit_status(e)
        summary = None
    finally:
        if board is not None:
            rc = board.stop()
    if summary is None and created and out is not None and code == USAGE_STATUS:
        shutil.rmtree(out, ignore_errors=True)  # the link could not be opened: nothing ran, no folder left
    if rc not in (0, 130, -signal.SIGTERM):  # 130: the board stopped cleanly on the SIGTERM (interrupted)
        print_error("tour", f"board exited with status {rc}")
        code = code or 1
    if summary is not None:
        if out is not None:
            (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
            print(f"logs and summary in {out}")
        print(f"tour done: {len(summary['poses'])} poses, worst error "
              f"{max(p['max_error_deg'] for p in summary['poses']):.2f} deg")
    return code
