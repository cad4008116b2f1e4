"""The path of one function token to the wire, counted (prints numbers, asserts nothing).

A lockstep session on the emulated board (a real board process on a pty) runs one turn, the reply
``<head_act action="nod"/>`` in one chunk. A profiler (``sys.setprofile``) starts counting when the shell's
parser is fed that chunk (:meth:`host.shell.parser.FunctionTokenParser.feed`: the token's last character
has arrived) and stops at the first SERVO_FRAME handed to the link (:meth:`host.link.core.LinkSession.transmit`)
after the nod's motion was placed on the frame grid (:meth:`host.motion.mixer.Mixer.add`): the
first frame that can carry it.
It counts the project's Python calls in between (functions defined under ``host/``, ``protocol/``,
``robots/``; the standard library, anyio and numpy are not counted), the distinct functions and files
among them, the file changes (consecutive project calls in different files), and prints the project
frames on the stack at the transmit (the synchronous part of the path; the rest goes through the
event loop: the call's task, the streamer's top-up).

Calls made by the session's own tasks started before the turn (the telemetry pump, the silence
watchdog) are not counted as the path, except the transmit that ends it: they are the wire side's
hops, shown by the stack. ``--runs N`` (default 3) prints each run.

Run: ``.venv/bin/python bench/bench_call_path.py [--runs 3] [--robot coco]``
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
from pathlib import Path
from types import FrameType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import anyio  # noqa: E402

from host.link.core import LinkSession  # noqa: E402
from host.motion.mixer import Mixer  # noqa: E402
from host.run.options import SessionOptions  # noqa: E402
from host.run.robot_session import RobotSession  # noqa: E402
from host.shell.parser import FunctionTokenParser  # noqa: E402
from protocol.messages import ServoFrame  # noqa: E402

PROJECT = tuple(str(ROOT / p) + os.sep for p in ("host", "protocol", "robots"))
REPLY = '<head_act action="nod"/>'


class PathCounter:
    """A ``sys.setprofile`` hook: counts project calls from the parser's feed to the first SERVO_FRAME sent."""

    def __init__(self, background: set[asyncio.Task[Any]]) -> None:
        self.background = background
        self.on = False
        self.placed = False  # the motion is on the frame grid
        self.calls_to_place = 0
        self.done = False
        self.calls = 0
        self.functions: set[tuple[str, str]] = set()
        self.files: set[str] = set()
        self.file_changes = 0
        self._last_file: str | None = None
        self.stack: list[str] = []
        self.place_stack: list[str] = []

    def __call__(self, frame: FrameType, event: str, arg: Any) -> None:
        if event != "call" or self.done:
            return
        code = frame.f_code
        if not self.on:
            if code is FunctionTokenParser.feed.__code__:
                self.on = True
            else:
                return
        path = code.co_filename
        if not path.startswith(PROJECT):
            return
        is_transmit = code is LinkSession.transmit.__code__ and isinstance(frame.f_locals.get("msg"), ServoFrame)
        if not is_transmit and _task() in self.background:
            return
        self.calls += 1
        self.functions.add((path, code.co_qualname))
        self.files.add(path)
        if self._last_file is not None and path != self._last_file:
            self.file_changes += 1
        self._last_file = path
        if code is Mixer.add.__code__ and not self.placed:
            self.placed, self.calls_to_place = True, self.calls
            self.place_stack = _project_stack(frame)
        if self.placed and is_transmit:
            self.done = True
            self.stack = _project_stack(frame)


def _project_stack(frame: FrameType | None) -> list[str]:
    """The project's frames on the stack from ``frame`` outwards, as ``path:qualname``."""
    out = []
    while frame is not None:
        if frame.f_code.co_filename.startswith(PROJECT):
            out.append(f"{os.path.relpath(frame.f_code.co_filename, ROOT)}:{frame.f_code.co_qualname}")
        frame = frame.f_back
    return out


def _task() -> asyncio.Task[Any] | None:
    try:
        return asyncio.current_task()
    except RuntimeError:
        return None


async def one_run(robot: str, out: Path) -> PathCounter:
    opts = SessionOptions(out=out, robot=robot, lockstep=True, plots=False, mcap=False)
    async with RobotSession(opts) as s:
        counter = PathCounter(asyncio.all_tasks() - {asyncio.current_task()})  # type: ignore[arg-type]
        sys.setprofile(counter)
        try:
            await s.run_turn(REPLY, write=False, settle_s=0.1)
        finally:
            sys.setprofile(None)
    return counter


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, metavar="N", help="runs (default 3)")
    ap.add_argument("--robot", default="coco", metavar="NAME", help="the robot (default coco)")
    args = ap.parse_args(argv)
    results = []
    for i in range(args.runs):
        with tempfile.TemporaryDirectory(prefix="gs-callpath-") as d:
            c = anyio.run(one_run, args.robot, Path(d))
        if not c.done:
            print(f"run {i + 1}: no SERVO_FRAME was sent after the token (nothing counted)")
            return 1
        results.append(c)
        print(f"run {i + 1}: {c.calls} project calls, {len(c.functions)} functions, {len(c.files)} files, "
              f"{c.file_changes} file changes ({c.calls_to_place} calls to the motion's placement); project frames on the "
              f"stack: {len(c.place_stack)} at the placement (the call's task), {len(c.stack)} at the transmit")
    best = min(results, key=lambda c: c.calls)
    print(f"\n{REPLY} -> first SERVO_FRAME ({args.robot}, lockstep, n = {len(results)}): min {best.calls} calls, "
          f"{len(best.functions)} functions in {len(best.files)} files, {best.file_changes} file changes")
    print("stack at the placement (innermost first; the call's task, from the scheduler's start of it):")
    for line in best.place_stack:
        print(f"  {line}")
    print("stack at the transmit (innermost first; the pump's top-up):")
    for line in best.stack:
        print(f"  {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
