"""The 30 ground-truth programs of the paper end to end on the C firmware (built natively, its servos
on a Feetech bus the plant emulates), over the same pty and with the same checks as on the Python
board (tests/e2e/task_checks.py); a file of its own so two of the suite's workers run both halves at once."""

from __future__ import annotations

import pytest

from .conftest import TASKS
from .task_checks import check_common, check_task


@pytest.mark.parametrize("tid", sorted(TASKS))
def test_ground_truth_end_to_end_on_the_c_firmware(tid: int, task_run) -> None:
    run = task_run(tid, "c")
    check_common(run, "c")
    check_task(tid, run, "c")
