"""The desk arm's tasks under the paper's link fault mix, over serial and over CAN (SLCAN), in lockstep.

The same guarantees as CoCo's (tests/e2e/test_faults_e2e.py, test_faults_can_e2e.py; the checks are
:mod:`support.faults`): every call completes; every SERVO_FRAME the board decoded is one the host
sent (byte-identical on serial; same sequence and values on CAN, whose CRC-16 drops a flipped one),
so no corrupted setpoint is ever applied; every lost message is a counted sequence gap; the summary
reports what was injected and what each end detected. And the cubes still end up where the task
puts them (the board's objects log): lost and duplicated frames do not spoil a pick and place.

By default the demo task over serial and two tasks over SLCAN, a pick and place and a wave scoped by
speech (``GHOSTSHELL_ARM_ALL_TASKS=1``: every task over both).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from e2e.test_arm_tasks_e2e import ALL_TASKS, TASKS, check_cubes, final_objects, selected
from support.faults import PAPER_FAULTS, assert_can_fault_guarantees, assert_serial_fault_guarantees, cli_run

from .conftest import run_e2e

SLCAN_TASKS = selected(7, 15)


def _serial(tid: int, out: Path) -> dict:
    run_e2e(TASKS[tid].ground_truth, out, robot="arm", task_label=f"arm task {tid}", faults=PAPER_FAULTS,
            fault_seed=tid)
    faults = assert_serial_fault_guarantees(out)
    check_cubes(tid, final_objects(out))
    return faults


def test_arm_demo_task_under_paper_faults_over_serial(tmp_path: Path) -> None:
    faults = _serial(12, tmp_path)
    assert sum(sum(d["injected"].values()) for d in faults["board"]["injected"]) > 0


@pytest.mark.slow
@pytest.mark.skipif(not ALL_TASKS, reason="every task under faults over serial: GHOSTSHELL_ARM_ALL_TASKS=1")
@pytest.mark.parametrize("tid", sorted(TASKS))
def test_arm_task_under_paper_faults_over_serial(tid: int, tmp_path: Path) -> None:
    _serial(tid, tmp_path)


@pytest.mark.parametrize("tid", SLCAN_TASKS)
def test_arm_task_under_paper_faults_over_slcan(tid: int, tmp_path: Path) -> None:
    run = cli_run(tid, tmp_path / f"task{tid:02d}", link="can:slcan:pty", robot="arm", faults=PAPER_FAULTS)
    assert run.returncode == 0, run.output[-3000:]
    assert_can_fault_guarantees(run.out)
    check_cubes(tid, final_objects(run.out))
