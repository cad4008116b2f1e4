"""``ghostshell replay LOG [--out DIR]``: feed a recorded run's host-to-board traffic into a fresh lockstep board."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from host.commands.errors import print_error
from robots.registry import robots_dir_arg
from host.commands.outarg import out_dir, out_dir_problem

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", help="a run folder or a frame log of it: serial .jsonl, CAN .log/.asc/.blf, or the run's run.mcap; "
                        "the host's or the board's (after a faulted run the board's: what reached it)")
    parser.add_argument("--out", type=out_dir, default=None, metavar="DIR", help="artefact folder (default runs/replay)")
    parser.add_argument("--robot", default=None, metavar="NAME",
                        help="the robot of the recorded run (default: the one its summary.json names)")
    parser.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg, help="search this folder for the robot first")


def main(args: argparse.Namespace) -> int:
    from host.link.errors import LinkError
    from host.run.replay import ReplayInputError, replay
    from protocol.framelog import FrameLogError
    from robots.description import RobotDataError

    out = Path(args.out) if args.out else Path("runs") / "replay"
    why = None if args.out else out_dir_problem(out)  # a given --out was checked when it was parsed
    if why is not None:
        print_error("replay", f"the run folder {out} {why}; give another with --out DIR")
        return 2
    try:
        res = replay(args.log, out, robot=args.robot, robots_dir=args.robots_dir)
    except (RobotDataError, ReplayInputError, FrameLogError) as e:  # bad input (a damaged log too): exit status 2
        print_error("replay", str(e))
        return 2
    except (LinkError, RuntimeError, OSError) as e:
        print_error("replay", str(e))
        return 1
    print(f"replayed {res.messages} messages up to board time {res.board_time_s:.3f} s")
    print(f"base ends at {res.base_end} [x m, y m, yaw deg]"
          + (f"; the original ended at {res.original_base_end} ({res.base_end_error_mm} mm apart)"
             if res.original_base_end is not None else ""))
    print(f"artefacts in {out}/: summary.json joints.png board_frames.jsonl host_frames.jsonl"
          + (" run.mcap" if (out / "run.mcap").exists() else ""))
    return 0
