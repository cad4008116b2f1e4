"""The paper tasks over CAN (SLCAN adapter on a pty, lockstep) with injected faults both ways.

Each task runs as a user runs it, ``ghostshell run --task N --link can:slcan:pty --lockstep
--faults drop=0.01,corrupt=0.01,dup=0.005,reorder=0.005 --fault-seed N``, two subprocesses at a
time (the machine's two cores; a SLCAN run spends most of its time in python-can's byte-wise
reads). The board's injector works per CAN frame (drop, bit flip in the data field, duplicate,
reorder). Checked from both ends' candump logs and ``summary.json``
(:func:`support.faults.assert_can_fault_guarantees`): every call completes; no corrupted setpoint
is ever applied (every SERVO_FRAME the board reassembled from what reached it is one the host sent,
same sequence and values: the CRC-16 of the CAN SERVO_FRAME drops a flipped one); the board counted
what it could not decode; every lost message is a sequence gap; the summary reports what was
injected and what each end detected.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import pytest

from robots.coco.tasks import load_tasks
from support.faults import PAPER_FAULTS, CliRun, assert_can_fault_guarantees, cli_run

ALL = sorted(t.id for t in load_tasks().values() if t.ground_truth)
#: by default (CI time) two or three tasks per category of the paper, the long speech ones among
#: them (task 8 lost a speech call here when a request had three attempts); test_faults_e2e.py samples
#: the other tasks over serial under the same faults; every task with GHOSTSHELL_ALL_TASKS=1
SAMPLE = [1, 3, 7, 8, 9, 14, 17, 20, 22, 23, 26, 29]
TASKS = ALL if os.environ.get("GHOSTSHELL_ALL_TASKS", "") not in ("", "0") else SAMPLE
WORKERS = 2


@pytest.fixture(scope="module")
def can_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[int, CliRun]:
    root = tmp_path_factory.mktemp("can_faults")
    with ThreadPoolExecutor(WORKERS) as pool:
        return dict(zip(TASKS, pool.map(lambda t: cli_run(t, root / f"task{t:02d}", link="can:slcan:pty",
                                                          faults=PAPER_FAULTS), TASKS)))


@pytest.mark.slow  # ~1 min for the 12 sampled tasks on two cores (~2.5 min for all 30)
@pytest.mark.parametrize("tid", TASKS)
def test_task_completes_under_paper_faults_over_slcan(tid: int, can_runs: dict[int, CliRun]) -> None:
    run = can_runs[tid]
    assert run.returncode == 0, run.output[-3000:]
    assert_can_fault_guarantees(run.out)
