"""``ghostshell render RUN_DIR``: make run.mp4 for a finished run from its recorded state.

Reads the board's frame log and the timeline in RUN_DIR (see :mod:`host.run.video`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from host.commands.errors import print_error
from host.commands.outarg import out_file, out_file_problem
from host.commands.inputs import whole_number
from robots.registry import robots_dir_arg


#: the file names ``--out`` takes: containers for the H.264 video and AAC sound (ffmpeg picks one by the suffix)
VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".mkv")


def video_file(text: str) -> Path:
    """argparse ``type=`` for ``render --out FILE``: a file :func:`host.commands.outarg.out_file` can write whose
    suffix is one of :data:`VIDEO_SUFFIXES` (any case), else :class:`argparse.ArgumentTypeError` saying so
    (``x.txt``, ``RUN/timeline.json``: ffmpeg found no container for it only after rendering, exit 1)."""
    path = out_file(text)  # a device or a folder is named as such
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise argparse.ArgumentTypeError(f"{text} is not a video file name; give one ending in "
                                         f"{', '.join(VIDEO_SUFFIXES[:-1])} or {VIDEO_SUFFIXES[-1]}")
    return path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run_dir", metavar="RUN_DIR", help="a run's artefact folder (ghostshell run/demo --out)")
    parser.add_argument("--out", type=video_file, default=None, metavar="FILE",
                        help=f"video file ending in {', '.join(VIDEO_SUFFIXES[:-1])} or {VIDEO_SUFFIXES[-1]} (default RUN_DIR/run.mp4)")
    parser.add_argument("--fps", type=int, default=25, choices=range(10, 61), metavar="FPS", help="frames per second (default 25)")
    parser.add_argument("--workers", type=whole_number(1), default=2, metavar="N", help="render processes (default 2: both cores)")
    parser.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg,
                        help="search this folder first for the robot the run drove (its summary.json names it)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar (shown only on a terminal anyway)")


def main(args: argparse.Namespace) -> int:
    import sys
    import time

    from host.progress import bar
    from host.run.video import VideoError, VideoInputError, VideoSettings, render_video

    run_dir = Path(args.run_dir)
    if not run_dir.is_dir():
        what = "is not a folder" if run_dir.exists() else "does not exist"
        print_error("render", f"{run_dir} {what}; give a run's folder (ghostshell run/demo --out)")
        return 2
    if args.out is None:  # the default file, as --out FILE is checked when parsed
        why = out_file_problem(run_dir / "run.mp4")
        if why is not None:
            print_error("render", f"{run_dir / 'run.mp4'} {why}; give another with --out FILE")
            return 2
    t = time.monotonic()
    try:
        with bar("rendering run.mp4", None, quiet=args.quiet, transient=True) as shown:
            path = render_video(Path(args.run_dir), Path(args.out) if args.out else None,
                                VideoSettings(fps=args.fps, workers=max(1, args.workers)), robots_dir=args.robots_dir,
                                progress=lambda done, total: shown.update(completed=done, total=total))
    except VideoInputError as e:  # nothing to render there: bad input
        print_error("render", str(e))
        return 2
    except VideoError as e:
        print_error("render", str(e))
        return 1
    print(f"video: {path} (rendered in {time.monotonic() - t:.1f} s)")
    return 0
