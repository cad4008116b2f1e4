"""Shared helpers for the task benchmarks: task selection, one run per task, percentiles, tables.

Each run is a real end-to-end ``host.run.runner.run_program``: a board subprocess
on a pty (lockstep or realtime), the link client, the robot runtime and the shell
fed by the scripted LLM replaying the task's ground-truth program (``--robot``: whose tasks).
"""

from __future__ import annotations

import argparse
import math
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import anyio
import numpy as np

from host.runtime.binding import signature_registry
from host.run.runner import RunOptions, RunReport, run_program
from host.shell.registry import Registry
from robots.datatypes import RobotDataError
from robots.description import Robot
from robots.registry import DEFAULT_ROBOT, load_robot


def task_arguments(description: str, json_help: str) -> argparse.ArgumentParser:
    """The options every task benchmark takes (the clock switch is added by each script)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--tasks", type=task_ids, default=None,
                    help="task ids, e.g. 1,5,23 or 1-10 (default: all of the robot's)")
    ap.add_argument("--robot", default=DEFAULT_ROBOT, help=f"whose tasks run (default {DEFAULT_ROBOT})")
    ap.add_argument("--tokens-per-s", type=_rate, default=30.0, help="scripted LLM speed (default 30)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="folder for the runs' artefacts (default: a temporary folder)")
    ap.add_argument("--json", default=None, metavar="FILE", help=json_help)
    return ap


def task_programs(parser: argparse.ArgumentParser, ids: Sequence[int] | None = None,
                  robot: Robot | None = None) -> list[tuple[int, str]]:
    """``(id, ground-truth program)`` of the robot's selected tasks (default: every task with ground truth).
    An id without a ground truth is a usage error through ``parser`` (``parser.error``: exit status 2)."""
    tasks = (robot or load_robot()).tasks
    runnable = sorted(i for i, t in tasks.items() if t.ground_truth)
    if not ids:
        return [(i, str(tasks[i].ground_truth)) for i in runnable]
    bad = [i for i in ids if i not in runnable]
    if bad:
        message = (f"--tasks: no ground truth for task(s) {bad}; "
                   + (f"runnable: {runnable[0]}-{runnable[-1]}" if runnable else "this robot has no task with one"))
        parser.error(message)
    return [(i, str(tasks[i].ground_truth)) for i in ids]


def selected_tasks(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[Robot, list[tuple[int, str]]]:
    """The robot of ``--robot`` and the ``(id, program)`` of its ``--tasks``; a robot that cannot be
    loaded or an id without a ground truth is a usage error (``parser.error``: exit status 2)."""
    try:
        robot = load_robot(args.robot)
    except RobotDataError as e:
        parser.error(f"--robot: {e}")
    return robot, task_programs(parser, args.tasks, robot)


def _rate(text: str) -> float:
    """``--tokens-per-s``'s type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected tokens per second, e.g. 30, got {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return v


#: the most task ids ``--tasks`` may name (a range like 1-100000000000 used to fill the memory)
MAX_TASK_IDS = 1000


def task_ids(text: str) -> list[int]:
    """``--tasks``'s type: ``"1,5,23"`` or ``"1-10,23"`` -> ``[1, 5, 23]``, each id once in its first place. Anything else (an empty list, a
    range that runs backwards, a part that is not a number) raises :class:`argparse.ArgumentTypeError`,
    which argparse reports as a usage error (exit status 2)."""
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                lo, hi = int(a), int(b)
                if hi < lo:
                    raise argparse.ArgumentTypeError(f"the range {part!r} runs backwards; expected e.g. 1-10")
                if hi - lo + 1 > MAX_TASK_IDS:
                    raise argparse.ArgumentTypeError(f"the range {part!r} names more than {MAX_TASK_IDS} tasks")
                out.extend(range(lo, hi + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected ids like 1,5,23 or 1-10, got {text!r}") from None
    if len(out) > MAX_TASK_IDS:
        raise argparse.ArgumentTypeError(f"more than {MAX_TASK_IDS} task ids in {text[:40]!r}...")
    if not out:
        raise argparse.ArgumentTypeError(f"no task ids in {text!r}; expected ids like 1,5,23 or 1-10 (leave it out for all)")
    return list(dict.fromkeys(out))  # "1,1" or "1-3,2": each task once (a second run overwrote the first's folder)


def run_task(task_id: int, program: str, *, lockstep: bool, out_root: Path, buffer_response: bool = False,
             tokens_per_s: float = 30.0, seed: int = 0, wire_baud: int | None = None, link: str = "pty",
             robot: str | None = None, servo_bus: tuple[str, ...] = ()) -> RunReport:
    """Run one task end to end (board subprocess on ``link``, a link spec: the board is started
    on it; ``wire_baud``: the board models wire time at that baud rate; ``servo_bus``: the board's
    arguments for a real servo bus, ``SessionOptions.servo_bus``) and return its report."""
    suffix = "buffered" if buffer_response else "streaming"
    opts = RunOptions(program=program, task_label=f"task {task_id}", lockstep=lockstep,
                      out=out_root / f"task{task_id:02d}_{suffix}", tokens_per_s=tokens_per_s, seed=seed,
                      buffer_response=buffer_response, wire_baud=wire_baud, link=link, emulate_board=True,
                      robot=robot or DEFAULT_ROBOT, servo_bus=servo_bus)
    return anyio.run(run_program, opts, backend="asyncio")


def out_root(arg: str | None, prefix: str) -> Path:
    """The folder the runs' artefacts go to (a fresh temporary one unless given). Raises OSError."""
    if arg:
        p = Path(arg)
        p.mkdir(parents=True, exist_ok=True)
        return p
    return Path(tempfile.mkdtemp(prefix=prefix))


def output_folder(parser: argparse.ArgumentParser, args: argparse.Namespace, prefix: str) -> Path:
    """:func:`out_root` of ``--out``, and a ``--json`` whose folder exists, before any run: a folder
    that cannot be made or a missing one is a usage error (``parser.error``), not a traceback at the
    start or after the whole run."""
    if args.json is not None and not Path(args.json).resolve().parent.is_dir():
        parser.error(f"--json: no folder {str(Path(args.json).resolve().parent)!r} to write {args.json!r} into")
    try:
        return out_root(args.out, prefix)
    except OSError as e:
        parser.error(f"--out: cannot make the folder {args.out!r}: {e.strerror or e}")


def home_channels(vocabulary: str | None = None, robot: Robot | None = None) -> Registry:
    """The robot's registry (never called) to look up each function's home channel."""
    return signature_registry(robot or load_robot(), vocabulary)


def stats_ms(xs: Sequence[float]) -> dict[str, Any]:
    """n, min, mean, p50, p99 and max of ``xs`` (milliseconds), rounded; Nones when empty."""
    if not xs:
        return {"n": 0, "min": None, "mean": None, "p50": None, "p99": None, "max": None}
    a = np.asarray(xs, dtype=float)
    return {"n": int(a.size), "min": round(float(a.min()), 1), "mean": round(float(a.mean()), 1),
            "p50": round(float(np.percentile(a, 50)), 1), "p99": round(float(np.percentile(a, 99)), 1),
            "max": round(float(a.max()), 1)}


def fmt(x: float | None, width: int = 7) -> str:
    """A number right-aligned in ``width`` with one decimal, or a dash."""
    return f"{'-':>{width}}" if x is None else f"{x:{width}.1f}"
