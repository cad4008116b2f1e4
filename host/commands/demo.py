"""``ghostshell demo``: the showcase, one of the robot's tasks end to end on the embedded default.

The emulated board on a pty, MuJoCo headless, the scripted LLM streaming the
task's ground-truth function tokens at 30 tokens/s; prints where the artefacts are
and leaves a video of the run (run.mp4) unless ``--no-video``.
"""

from __future__ import annotations

import argparse

import sys

from host.commands.errors import print_error
from host.commands.run import add_run_options, check_run_args, run_with

def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--task", type=int, default=None, metavar="N",
                        help="the robot's task to show (default: the robot's demo task, robot.toml demo_task)")
    parser.add_argument("--no-video", dest="video", action="store_false",
                        help="skip run.mp4 (rendered after the run by default)")
    add_run_options(parser, clears_out=True)


def main(args: argparse.Namespace) -> int:
    from robots.tasks import get_task

    status = check_run_args(args)
    if status is not None:
        return status
    robot = args.robot_value
    task_id = args.task if args.task is not None else robot.demo_task
    if task_id is None:
        print_error("demo", f"{robot.name} has no tasks to show; run a program with "
              f"ghostshell run --robot {robot.name} --xml '<pose name=\"{robot.start_pose}\"/>'")
        return 2
    try:
        task = get_task(robot.tasks, task_id, robot.name)
    except ValueError as e:
        print_error("demo", str(e))
        return 2
    return run_with(args, program=task.ground_truth, prompt=None, label=f"demo task {task.id}",
                    banner=f"task {task.id} ({task.category}): {task.instruction}\n  {task.ground_truth}\n")
