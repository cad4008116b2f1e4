"""Paper tasks over a serial link with injected faults (emulated board, lockstep, both directions).

Guarantees checked from both ends' frame logs and ``summary.json``
(:func:`support.faults.assert_serial_fault_guarantees`): every call completes; no corrupted setpoint
is ever applied (every SERVO_FRAME the board decoded is byte-identical to one the host sent, so every
one it could apply is); every lost frame is a sequence gap the gap detector counts; the summary says
what was injected and what each end detected.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from robots.coco.tasks import load_tasks
from support.faults import PAPER_FAULTS, assert_serial_fault_guarantees

from .conftest import FIRMWARES, run_e2e

TASKS = {t.id: t for t in load_tasks().values() if t.ground_truth}


def _check(tid: int, out: Path, seed: int, firmware: str = "python") -> dict:
    run_e2e(TASKS[tid].ground_truth, out, task_label=f"task {tid}", faults=PAPER_FAULTS, fault_seed=seed,
            firmware=firmware)
    return assert_serial_fault_guarantees(out)


@pytest.mark.parametrize("firmware", FIRMWARES)
def test_task_completes_under_paper_faults(firmware: str, tmp_path: Path) -> None:
    """Task 26 under the paper's fault rates, on the Python board and on the C firmware (whose UART the
    faults hit on the modelled line between two ptys; its frame log is the raw bytes it decoded)."""
    faults = _check(26, tmp_path, seed=3, firmware=firmware)
    total = sum(sum(d["injected"].values()) for d in faults["board"]["injected"])
    assert total > 0


@pytest.mark.slow
@pytest.mark.parametrize("tid", sorted(TASKS))
def test_all_tasks_complete_under_paper_faults(tid: int, tmp_path: Path) -> None:
    _check(tid, tmp_path, seed=tid)
