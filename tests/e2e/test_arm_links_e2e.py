"""The desk arm's tasks over CAN: SLCAN (the board as an adapter on a pty, a subprocess) and python-can's
virtual bus (the board in this process), in lockstep.

SLCAN: each task as a user runs it, ``ghostshell run --robot arm --task N --link can:slcan:pty
--lockstep``; where the cubes ended up comes from the board's objects log, cross-checked for the
pick-and-place tasks against an in-process replay of the host's candump capture
(:mod:`support.board_replay`).
Virtual: ``run_program(RunOptions(robot="arm", link="can:virtual:..."))`` against a board served in
this process (:mod:`support.virtual_board`), whose MuJoCo state is read directly at the end.

A few tasks per link by default (``GHOSTSHELL_ARM_ALL_TASKS=1``: all of them): over SLCAN a pick and a
scoped pick and place (each with its replay cross-check); over the virtual bus the stack, a parallel
nod with a release and a wave scoped by speech.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import anyio
import numpy as np
import pytest

from e2e.test_arm_tasks_e2e import MOVES, TASKS, check_cubes, final_objects, selected
from host.run.runner import RunOptions, run_program
from robots.scenes import object_positions
from support.board_replay import replay_in_process
from support.faults import cli_run
from support.virtual_board import serve_virtual

SLCAN_TASKS = selected(2, 14)
VIRTUAL_TASKS = selected(5, 9, 15)
_channels = itertools.count()


def _done(out: Path) -> dict:
    """Every call of the run in ``out`` done. (The link counters are not asserted: on a loaded machine
    an ISO-TP transfer can time out on the wall clock and count a decode error, which the link
    recovers from; the fault tests check what such losses may and may not do.)"""
    summary = json.loads((out / "summary.json").read_text())
    outcomes = {k: v for k, v in summary["outcomes"].items() if v}
    assert summary["outcome"] == "done" and set(outcomes) == {"done"}, outcomes
    return summary


@pytest.mark.parametrize("tid", SLCAN_TASKS)
def test_arm_task_over_slcan(tid: int, tmp_path: Path) -> None:
    run = cli_run(tid, tmp_path / f"task{tid:02d}", link="can:slcan:pty", robot="arm")
    assert run.returncode == 0, run.output[-3000:]
    summary = _done(run.out)
    assert summary["extra"]["robot"] == "arm" and (run.out / "host_frames.log").is_file()
    check_cubes(tid, final_objects(run.out))
    if tid in MOVES:
        rep = replay_in_process(run.out, "arm")
        err, n = rep.max_telemetry_error(run.out)
        assert n > 50 and err < 1e-4, f"the replay is not the run's physics ({n} reports, {err} rad)"
        check_cubes(tid, {k: np.asarray(v) for k, v in rep.objects().items()})


def _virtual(tid: int, out: Path) -> dict[str, np.ndarray]:
    vb = serve_virtual(f"ghostshell-arm-{next(_channels)}", robot="arm", log=str(out / "board_frames.log"))
    try:
        opts = RunOptions(robot="arm", program=TASKS[tid].ground_truth, out=out, lockstep=True, link=vb.spec,
                          task_label=f"arm task {tid} (virtual CAN)")
        report = anyio.run(run_program, opts, backend="asyncio")
    finally:
        vb.stop()
    assert report.summary.outcome == "done" and all(c.outcome == "done" for c in report.calls)
    _done(out)
    board = vb.board  # stopped: its MuJoCo state is the run's final world
    return {k: np.asarray(v) for k, v in object_positions(board.data, board.scene_objects).items()}


@pytest.mark.parametrize("tid", VIRTUAL_TASKS)
def test_arm_task_over_virtual_can(tid: int, tmp_path: Path) -> None:
    check_cubes(tid, _virtual(tid, tmp_path))
