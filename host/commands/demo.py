"""``ghostshell demo``: the showcase, a paper task end to end on the embedded default.

The emulated board on a pty, MuJoCo headless, the scripted LLM streaming the
task's ground-truth function tokens at 30 tokens/s; prints where the artefacts are
and leaves a video of the run (run.mp4) unless ``--no-video``.
"""

from __future__ import annotations

import argparse

from host.commands.run import add_run_options, check_run_args, run_with

DEFAULT_TASK = 26


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", type=int, default=DEFAULT_TASK,
                        help=f"paper task to show (default {DEFAULT_TASK}: ears, nods and strides under music)")
    parser.add_argument("--no-video", dest="video", action="store_false",
                        help="skip run.mp4 (rendered after the run by default)")
    add_run_options(parser)


def main(args: argparse.Namespace) -> int:
    from robots.coco.tasks import get_task

    try:
        task = get_task(args.task)
    except ValueError as e:
        print(f"ghostshell demo: {e}")
        return 2
    status = check_run_args(args)
    if status is not None:
        return status
    print(f"task {task.id} ({task.category}): {task.instruction}\n  {task.ground_truth}\n")
    return run_with(args, program=task.ground_truth, prompt=None, label=f"demo task {task.id}")
