"""``ghostshell replay LOG [--out DIR]``: feed a recorded run's host-to-board traffic into a fresh lockstep board."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["configure", "main"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", metavar="LOG", help="a run folder or a frame log of it: serial .jsonl or CAN .log/.asc/.blf, "
                        "the host's or the board's (after a faulted run the board's: what reached it)")
    parser.add_argument("--out", default=None, metavar="DIR", help="artefact folder (default runs/replay)")


def main(args: argparse.Namespace) -> int:
    from host.link.errors import LinkError
    from host.run.replay import replay
    from protocol.framelog import FrameLogError

    out = Path(args.out) if args.out else Path("runs") / "replay"
    try:
        res = replay(args.log, out)
    except (LinkError, FrameLogError, RuntimeError, OSError) as e:
        print(f"ghostshell replay: {e}", file=sys.stderr)
        return 1
    print(f"replayed {res.messages} messages up to board time {res.board_time_s:.3f} s")
    print(f"base ends at {res.base_end} [x m, y m, yaw deg]"
          + (f"; the original ended at {res.original_base_end} ({res.base_end_error_mm} mm apart)"
             if res.original_base_end is not None else ""))
    print(f"artefacts in {out}/: summary.json joints.png board_frames.jsonl host_frames.jsonl")
    return 0
